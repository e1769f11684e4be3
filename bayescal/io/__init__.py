"""Files: CSV tables, JSON, floor-plan files, run records and output folders
written atomically.

See ``docs/architecture.md`` for the layers and what each may import.
"""
