"""Helpers shared by tests in several folders (``tests/`` is on ``sys.path`` through
``conftest.py``, so test modules import this as ``helpers``)."""

import numpy as np


def gross_plan_pixels(ds, i, kind):
    """Pixels of ``ds`` with point ``i`` grossly wrong: its pixel moved 30 px, or the laser
    point 40 % beyond its wall (same azimuth, its pixel's noise kept)."""
    from bayescal.scene.floorplan import plan_point
    from bayescal.sensor.camera import project_theta

    pix = ds.pixels.copy()
    if kind == "pixel":
        pix[i, 1] += 30.0
        return pix
    theta, P = ds.params.to_identifiable(), ds.points[i]
    t, rho = np.arctan2(P[1], P[0]), np.hypot(P[0], P[1])
    Q = plan_point(theta, np.array([t]), np.array([1.4 * rho]), np.array([t]))
    pix[i] = project_theta(theta, Q)[0][0] + ds.pixels[i] - project_theta(theta, P[None])[0][0]
    return pix
