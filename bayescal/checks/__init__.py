"""Checks on input and fits: degenerate input, noise collapse, the posterior
predictive check, residuals, and messages naming a data file's lines.

See ``docs/architecture.md`` for the layers and what each may import.
"""
