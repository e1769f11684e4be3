"""Where is a shallow corner? A two-line split of the laser points around it.

At a corner where two walls meet at a shallow angle (nearly collinear walls), a
small error of the plan moves the corner far along the walls: ``Δd / sin(Δa)``,
0.6-0.8 rad of azimuth for a 5 % distance error at a 12° corner in the 5000 mm
room. The least squares started from such a plan keeps the points between the
plan's corner and the true one on the wrong wall: a local minimum that its
Gauss-Newton steps cannot leave (no single step moves a whole run of points to
the other wall), and whose wall and pixel chi-squares look normal
(``docs/floorplan.md`` section 9).

The data say where the corner is: the laser points, triangulated on the cone
with the current sensor, lie on two lines that meet at the corner.
:func:`best_split` finds the split of the points (sorted by azimuth) that the
two straight lines fit best (total least squares, all splits at once from
cumulative moments); :func:`bayescal.fit.floorplan` restarts from the walls fitted
on each side and keeps the restart only if its collapsed cost is lower.
"""

from __future__ import annotations

import numpy as np

from .floorplan import wrap_angle

__all__ = ["shallow_corners", "best_split", "line_fit", "candidate_walls"]

#: corners whose walls' normals differ by less than this (rad) are searched
SHALLOW = np.radians(30.0)


def shallow_corners(walls, *, limit=SHALLOW):
    """Indices j of the corners (walls j and j + 1) whose walls meet at a shallow angle.

    Parameters
    ----------
    walls : ndarray, shape (W, 2)
        ``(d_k, a_k)`` per wall.
    limit : float
        Largest difference of the two walls' normal angles, rad.
    """
    a = walls[:, 1]
    da = np.abs(wrap_angle(np.roll(a, -1) - a))
    return np.flatnonzero(da < limit)


def line_fit(xy, through=None):
    """Total-least-squares line ``n(a) . (x, y) = d`` of points xy (n, 2): (d, a).

    Through their centroid, or through the point ``through`` (2,) if given. The
    normal is oriented away from the axis (``d > 0``).
    """
    m = xy.mean(axis=0) if through is None else np.asarray(through, float)
    _, _, vt = np.linalg.svd(xy - m, full_matrices=False)
    n = vt[-1]
    d = float(n @ m)
    if d < 0:
        n, d = -n, -d
    return d, float(np.arctan2(n[1], n[0]))


def _tls_costs(xy):
    """TLS cost of the points' prefixes: smallest eigenvalue x count of each prefix's
    scatter, shape (n + 1,) (prefix k = the first k points; NaN below 3 points)."""
    n = len(xy)
    ones = np.arange(n + 1, dtype=float)
    c = np.vstack([np.zeros((1, 5)), np.cumsum(np.column_stack(
        [xy[:, 0], xy[:, 1], xy[:, 0] ** 2, xy[:, 0] * xy[:, 1], xy[:, 1] ** 2]), axis=0)])
    with np.errstate(invalid="ignore", divide="ignore"):
        mx, my = c[:, 0] / ones, c[:, 1] / ones
        sxx = c[:, 2] - ones * mx * mx
        sxy = c[:, 3] - ones * mx * my
        syy = c[:, 4] - ones * my * my
        tr, det = sxx + syy, sxx * syy - sxy * sxy
        lam = 0.5 * tr - np.sqrt(np.maximum(0.25 * tr * tr - det, 0.0))
    lam[:3] = np.nan
    return lam


def best_split(xy, *, min_side=5):
    """Split of points (sorted along the walls) into two runs best fitted by two lines.

    Parameters
    ----------
    xy : ndarray, shape (n, 2)
        Points, ordered by azimuth across the corner, mm.
    min_side : int
        Fewest points on either side.

    Returns
    -------
    k : int or None
        The first ``k`` points on the first wall, the rest on the second; None when
        there are fewer than ``2 min_side`` points.
    cost : ndarray, shape (n + 1,)
        Total TLS cost (mm^2) of each split (NaN where a side is too small).
    """
    n = len(xy)
    if n < 2 * min_side:
        return None, np.full(n + 1, np.nan)
    left = _tls_costs(xy)
    right = _tls_costs(xy[::-1])[::-1]
    cost = left + right
    cost[:min_side] = np.nan
    cost[n - min_side + 1:] = np.nan
    return int(np.nanargmin(cost)), cost


def candidate_walls(xy, current, *, n_grid=3, min_side=5):
    """Starting walls for the two sides of a corner, one pair per candidate split.

    Candidates, when the best two-line split (:func:`best_split`) disagrees with
    ``current``: that split and ``n_grid`` splits at evenly spaced quantiles. Each
    pair of lines passes through the corner point (the mean of the points next to
    the split), so the start's corner lies at the split: two lines fitted freely to
    points with ~100 mm of range noise can meet far from it.

    Parameters
    ----------
    xy : ndarray, shape (n, 2)
        Points ordered by azimuth across the corner, mm.
    current : int
        The split of the fit being checked (points before its corner). No
        candidates when the best two-line split lies within ``max(5, 5 %)`` of the
        points of it (the common case: the restarts then cost nothing).

    Returns
    -------
    list of (k, (d, a), (d, a))
        Split index and the walls before and after it.
    """
    n = len(xy)
    best, _ = best_split(xy, min_side=min_side)
    if best is None or abs(best - current) <= max(5, 0.05 * n):
        return []                       # the points' own kink agrees with the fit's corner
    grid = np.linspace(0, n, n_grid + 2)[1:-1].astype(int)
    ks = sorted({best, *(int(k) for k in np.clip(grid, min_side, n - min_side))})
    out = []
    for k in ks:
        corner = xy[max(k - 2, 0):k + 2].mean(axis=0)
        out.append((k, line_fit(xy[:k], corner), line_fit(xy[k:], corner)))
    return out
