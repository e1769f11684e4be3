"""Statistical validation: coverage over noise replications, simulation-based
calibration, and the executors that run trials inline, in processes or on Dask.

See ``docs/architecture.md`` for the layers and what each may import.
"""
