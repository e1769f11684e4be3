"""The scale of an inferred scene error: ``sigma_scene_i = kappa * rho_i``."""

from __future__ import annotations

import numpy as np

from ..errors import InvalidValueError

__all__ = ["scene_range", "RHO_FLOOR"]

#: an approximate point's range in ``kappa * rho`` is at least this fraction of the median
RHO_FLOOR = 0.25


def scene_range(approx_points):
    """The range ``rho_i`` (mm) that scales an inferred relative scene error, shape (N,).

    The horizontal distance of each approximate point from the axis, floored at
    ``RHO_FLOOR`` times the median: a point typed in the wrong unit (metres for mm)
    lands near the axis, and its relative sd would otherwise shrink with it and give
    one bad row the weight of hundreds.
    """
    rho = np.hypot(approx_points[..., 0], approx_points[..., 1])
    if np.any(rho <= 0):
        raise InvalidValueError("approx_points on the axis (x = y = 0) cannot carry a relative "
                                "scene error; give sigma_scene explicitly")
    return np.maximum(rho, RHO_FLOOR * np.median(rho))
