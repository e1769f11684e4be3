"""Least squares: the sequential method, the simultaneous method (Schur-complement
Levenberg-Marquardt on the per-point likelihood) and the floor-plan least squares.

See ``docs/architecture.md`` for the layers and what each may import.
"""
