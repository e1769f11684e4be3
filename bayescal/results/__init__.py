"""Result objects: ``CalibrationResult`` (least squares), ``Posterior`` (MCMC),
the floor-plan result, reconstructions of new pixels and error metrics.

See ``docs/architecture.md`` for the layers and what each may import.
"""
