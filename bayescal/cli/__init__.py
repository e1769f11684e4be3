"""The ``bayescal`` command line: the argparse parser, typed jobs, runs, the demo
and the study runner.

See ``docs/architecture.md`` for the layers and what each may import.
"""
