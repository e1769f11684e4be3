"""Likelihoods of laser pixels given the sensor and the scene: per-point
approximate points (``points``), a floor plan (``floorplan``), the outlier
mixture, the priors, and the per-point Laplace algebra, blocks and draws.

See ``docs/architecture.md`` for the layers and what each may import.
"""
