"""Plan view of a floor-plan calibration: nominal walls, estimated walls, points, truth."""

from __future__ import annotations

import numpy as np

from .._validation import resolve_rng

__all__ = ["plot_floor_plan", "plan_figure", "wall_draws"]


def wall_draws(walls, *, covariance=None, samples=None, n_draws=50, rng=None):
    """Draws of the wall lines ``(d_k, a_k)`` for the uncertainty of a plan view.

    Parameters
    ----------
    walls : array_like, shape (W, 2)
        Estimated ``(d_k, a_k)``: mm, rad.
    covariance : array_like, shape (2W, 2W), optional
        Laplace covariance at the MAP, order ``d_0, a_0, d_1, ...``.
    samples : array_like, shape (S, W, 2), optional
        Posterior draws (used when given, evenly thinned to ``n_draws``).
    n_draws : int, optional
    rng : numpy.random.Generator, int or None
        For the draws from the Laplace approximation.

    Returns
    -------
    ndarray, shape (n, W, 2)
        ``n = 0`` without samples or covariance.
    """
    walls = np.asarray(walls, dtype=float)
    if samples is not None:
        s = np.asarray(samples, dtype=float)
        idx = np.unique(np.linspace(0, len(s) - 1, min(int(n_draws), len(s))).round()
                        .astype(int))
        return s[idx]
    if covariance is None:
        return np.zeros((0,) + walls.shape)
    cov = np.asarray(covariance, dtype=float)
    cov = 0.5 * (cov + cov.T)
    e, V = np.linalg.eigh(cov)
    root = V * np.sqrt(np.clip(e, 0, None))
    z = resolve_rng(rng).standard_normal((int(n_draws), len(cov)))
    return walls + (z @ root.T).reshape((int(n_draws),) + walls.shape)


def _polygon(d, a):
    from ..scene.floorplan import corner_points

    c = corner_points(d, a)
    return np.vstack([c, c[:1]])


def _ellipses(ax, points, cov, *, max_ellipses, n_sigma):
    from matplotlib.patches import Ellipse

    every = max(int(np.ceil(len(points) / max(int(max_ellipses), 1))), 1)
    for i in range(0, len(points), every):
        c = cov[i, :2, :2]
        if not np.all(np.isfinite(c)):
            continue
        e, v = np.linalg.eigh(c)
        w, h = 2 * n_sigma * np.sqrt(np.clip(e[::-1], 0, None))
        ax.add_patch(Ellipse(points[i, :2], w, h, angle=np.degrees(np.arctan2(v[1, 1], v[0, 1])),
                             fill=False, lw=0.6, color="tab:blue"))
    return every


def plot_floor_plan(plan, *, walls=None, wall_covariance=None, wall_samples=None, points=None,
                    point_covariance=None, truth_walls=None, truth_points=None, n_draws=50,
                    max_ellipses=60, n_sigma=2.0, rng=0, ax=None):
    """Top view of a floor-plan calibration.

    Draws the plan as given (dashed), the estimated walls (solid) with their
    uncertainty as thin lines of ``n_draws`` draws (posterior draws of the wall
    lines, or draws from the Laplace approximation at the MAP), the points with
    ``n_sigma`` ellipses of their horizontal covariance (at most
    ``max_ellipses``), and the truth when known.

    Parameters
    ----------
    plan : FloorPlan
        The rough plan the calibration started from.
    walls : array_like, shape (W, 2), optional
        Estimated ``(d_k, a_k)``, mm and rad (MAP or posterior mean).
    wall_covariance : array_like, shape (2W, 2W), optional
    wall_samples : array_like, shape (S, W, 2), optional
    points : array_like, shape (N, 3), optional
        Estimated laser points, mm.
    point_covariance : array_like, shape (N, 3, 3), optional
        mm^2.
    truth_walls : array_like, shape (W', 2, 2), optional
        True wall segments, mm.
    truth_points : array_like, shape (N, 3), optional
    n_draws, max_ellipses : int, optional
    n_sigma : float, optional
    rng : numpy.random.Generator, int or None
    ax : matplotlib.axes.Axes, optional

    Returns
    -------
    matplotlib.figure.Figure
    """
    import matplotlib.pyplot as plt

    if ax is None:
        fig, ax = plt.subplots(figsize=(6.5, 6))
    else:
        fig = ax.figure
    nom = np.vstack([plan.segments[:, 0], plan.segments[:1, 0]])
    ax.plot(nom[:, 0], nom[:, 1], "--", color="0.45", lw=1.2, label="plan as given", zorder=2)
    if walls is not None:
        for k, dr in enumerate(wall_draws(walls, covariance=wall_covariance,
                                          samples=wall_samples, n_draws=n_draws, rng=rng)):
            p = _polygon(dr[:, 0], dr[:, 1])
            ax.plot(p[:, 0], p[:, 1], "-", color="tab:orange", lw=0.5, alpha=0.25, zorder=1,
                    label="wall draws" if k == 0 else None)
        w = np.asarray(walls, float)
        p = _polygon(w[:, 0], w[:, 1])
        ax.plot(p[:, 0], p[:, 1], "-", color="tab:orange", lw=1.6, label="estimated walls",
                zorder=3)
    if truth_walls is not None:
        tw = np.asarray(truth_walls, float)
        tp = np.vstack([tw[:, 0], tw[:1, 0]])
        ax.plot(tp[:, 0], tp[:, 1], "-", color="tab:red", lw=0.9, label="true walls", zorder=4)
    title = "Floor plan"
    if points is not None:
        pts = np.asarray(points, float)
        if point_covariance is not None:
            every = _ellipses(ax, pts, np.asarray(point_covariance, float),
                              max_ellipses=max_ellipses, n_sigma=n_sigma)
            title += f": {n_sigma:g}-sigma ellipses of the points (one in {every})"
        ax.scatter(pts[:, 0], pts[:, 1], s=2, c="tab:blue", label="points", zorder=5)
    if truth_points is not None:
        t = np.asarray(truth_points, float)
        ax.scatter(t[:, 0], t[:, 1], s=2, c="tab:red", marker="x", lw=0.5, label="true points",
                   zorder=6)
    ax.plot(0, 0, "k^", label="sensor axis")
    ax.set_aspect("equal")
    ax.set_xlabel("x (mm)")
    ax.set_ylabel("y (mm)")
    ax.set_title(title, fontsize=9)
    ax.legend(loc="upper right", fontsize="x-small")
    return fig


def plan_figure(result, plan, *, recon, truth):
    """The plan view of a floor-plan run (:func:`plot_floor_plan` of a result)."""
    samples = getattr(result, "wall_samples", None)
    if samples is not None:
        walls, cov = np.mean(samples, axis=0), None
    else:
        walls = result.extras.get("walls")
        cov = result.extras.get("wall_covariance")
    pts, pcov = recon if recon is not None else (result.points, None)
    tw = None if truth is None or truth.get("walls") is None else truth["walls"]
    tp = None if truth is None or truth.get("points") is None else truth["points"]
    return plot_floor_plan(plan, walls=walls, wall_covariance=cov, wall_samples=samples,
                           points=pts, point_covariance=pcov, truth_walls=tw, truth_points=tp)
