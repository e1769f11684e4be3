"""Calibration reports (Markdown and HTML) and the document renderer behind them.

See ``docs/architecture.md`` for the layers and what each may import.
"""
