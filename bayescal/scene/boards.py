"""Simulated chessboard views of a catadioptric camera, with the noise real views show.

:func:`simulate_views` places a board in front of the mirror ``n_views`` times (at
random, visible, inside the image) and returns the corners it images, with noise of
a chosen structure. The defaults are the real camera of ``docs/camera.md``
(1280 x 1024 px, xi 1.134, |gamma| 318, centre (642.5, 522.9), 8 x 6 corners of
42 mm) and its measured residual structure:

* ``sigma``: per-view noise sd, px: a number (the same for every view) or a
  ``(low, high)`` range drawn uniformly per view (measured 0.16-0.35);
* ``correlation``: ``(rho_x, rho_y)``, the correlation of neighbouring corners along
  the board's x (columns) and y (rows) (measured +0.20 and +0.43): separable AR(1);
* ``column_error``: sd (mm) of a per-column error of the board itself, the same in
  every view (a printed board's columns off by up to ~0.5 mm: ±0.2 px);
* ``view_field``: rms (px) of a per-view smooth displacement field (quadratic in the
  board coordinates), the systematic term of the noise model.
"""

from __future__ import annotations

import numpy as np

from .._validation import resolve_rng
from ..errors import FitError
from ..image.views import BoardView, board_points
from ..sensor.board import project_board, vector_from_rotation

__all__ = ["simulate_views", "REAL_CAMERA", "MEASURED_NOISE"]

#: the real paracatadioptric camera of docs/camera.md (xi, gamma_u, gamma_v, u0, v0)
REAL_CAMERA = {"xi": 1.134, "gamma_u": 317.8, "gamma_v": -318.0, "u0": 642.5, "v0": 522.9}
#: the residual structure measured on its views
MEASURED_NOISE = {"sigma": (0.16, 0.35), "correlation": (0.20, 0.43), "column_error": 0.25,
                  "view_field": 0.0}


def _ar_factor(n, rho):
    """Cholesky factor of the AR(1) correlation rho^|i-j| of n corners."""
    i = np.arange(n)
    return np.linalg.cholesky(rho ** np.abs(i[:, None] - i[None, :]) + 1e-12 * np.eye(n))


def _random_pose(rng, pts, k, image_size, radius, distance):
    """A pose whose board images whole, inside the image, at a radius in ``radius``."""
    w, h = image_size
    for _ in range(1000):
        rad = rng.uniform(*radius)
        az = rng.uniform(-np.pi, np.pi)
        # the ray of that pixel
        mx, my = rad * np.cos(az) / abs(k[1]), rad * np.sin(az) / abs(k[2])
        rho2 = mx * mx + my * my
        f = (k[0] + np.sqrt(max(1.0 + (1.0 - k[0] ** 2) * rho2, 0.0))) / (1.0 + rho2)
        d = np.array([f * mx, f * my, k[0] - f])
        centre = d / np.linalg.norm(d) * rng.uniform(*distance)
        # board normal towards the focus, tilted at random, random in-plane rotation
        n = -centre / np.linalg.norm(centre) + rng.normal(scale=0.35, size=3)
        n /= np.linalg.norm(n)
        a = np.cross(n, rng.normal(size=3))
        a /= np.linalg.norm(a)
        R = np.stack([a, np.cross(n, a), n], axis=1)
        t = centre - R @ pts.mean(axis=0)
        pose = np.concatenate([vector_from_rotation(R), t])
        uv, ok = project_board(k, pose, pts)
        if ok.all() and np.all((uv > 5) & (uv < np.array([w, h]) - 5)):
            return pose, uv
    raise FitError("could not place a visible board: check the intrinsics and image size")


def _view_noise(rng, board, sd, correlation, view_field, pts):
    nx, ny = board
    Lx, Ly = _ar_factor(nx, correlation[0]), _ar_factor(ny, correlation[1])
    z = rng.standard_normal((2, ny, nx))
    e = np.einsum("ij,cjk,lk->cil", Ly, z, Lx) * sd           # (2, ny, nx)
    e = e.reshape(2, -1).T
    if view_field > 0:
        xy = (pts[:, :2] - pts[:, :2].mean(0)) / (np.ptp(pts[:, :2], 0) / 2)
        F = np.stack([np.ones(len(xy)), xy[:, 0], xy[:, 1], xy[:, 0] ** 2,
                      xy[:, 0] * xy[:, 1], xy[:, 1] ** 2], -1)
        F /= np.sqrt(np.mean(F * F, 0))
        e += F @ rng.normal(scale=view_field, size=(6, 2))
    return e


def simulate_views(intrinsics=None, *, n_views=10, board=(8, 6), square=42.0,
                   image_size=(1280, 1024), sigma=MEASURED_NOISE["sigma"],
                   correlation=MEASURED_NOISE["correlation"],
                   column_error=MEASURED_NOISE["column_error"], view_field=0.0,
                   radius=(130.0, 300.0), distance=(350.0, 700.0), rng=None):
    """Simulated board views with known truth and the measured noise structure.

    Parameters
    ----------
    intrinsics : dict or array_like, optional
        ``xi, gamma_u, gamma_v, u0, v0`` (default :data:`REAL_CAMERA`).
    n_views : int
    board : tuple of int
        Inner corners ``(columns, rows)``.
    square : float
        mm.
    image_size : tuple of int
        ``(width, height)``, px.
    sigma : float or tuple of float
        Per-view noise sd (px), or a range drawn uniformly per view.
    correlation : tuple of float
        Neighbour correlation along the board's x and y; ``(0, 0)`` is white noise.
    column_error : float
        sd of the board's per-column error, mm (common to all views; 0: a perfect board).
    view_field : float
        rms of a per-view quadratic displacement field, px.
    radius : tuple of float
        Image radii (px from the centre) of the boards' centres.
    distance : tuple of float
        Distances of the boards from the focus, mm.
    rng : Generator, int or None

    Returns
    -------
    views : list of BoardView
        Nominal board points, noisy pixels; named ``sim_00`` ...
    truth : dict
        ``intrinsics`` (5,), ``poses`` (K, 6), ``sigma`` (K,), ``points`` (the true board, mm).
    """
    rng = resolve_rng(rng)
    names = ("xi", "gamma_u", "gamma_v", "u0", "v0")
    src = REAL_CAMERA if intrinsics is None else intrinsics
    k = np.array([src[n] for n in names] if isinstance(src, dict) else src, float)
    pts = board_points(board, square)
    true_pts = pts.copy()
    if column_error > 0:
        true_pts[:, 0] += rng.normal(scale=column_error, size=board[0])[np.arange(len(pts))
                                                                         % board[0]]
    lo, hi = (sigma, sigma) if np.isscalar(sigma) else sigma
    views, poses, sds = [], [], []
    for i in range(int(n_views)):
        pose, _ = _random_pose(rng, pts, k, image_size, radius, distance)
        uv, _ = project_board(k, pose, true_pts)
        sd = rng.uniform(lo, hi)
        uv = uv + _view_noise(rng, board, sd, correlation, view_field, pts)
        views.append(BoardView(uv, pts, name=f"sim_{i:02d}", image_size=image_size))
        poses.append(pose)
        sds.append(sd)
    return views, {"intrinsics": k, "poses": np.array(poses), "sigma": np.array(sds),
                   "points": true_pts}

