"""A start for the camera fit that uses every view and any camera size.

Design values come from the image: the centre at the image centre, ``xi = 1`` (a
parabola) and ``|gamma|`` scanned over a geometric grid from 5 % to 100 % of the
image's half diagonal. For each candidate, every view's pose comes from its
corners' rays by a linear fit of the board's homography (``ray x H p = 0``, planar
boards) and a few Gauss-Newton steps; the candidate with the smallest total cost
wins. No view is rejected: a view whose pose cannot be found at any candidate is an
error naming it. OpenCV's linear start (per-view gamma from image lines, keep views
under 100 px error) is what this replaces: it drops boards seen small near the centre.
"""

from __future__ import annotations

import numpy as np

from ..errors import DegenerateInputError
from ..sensor.board import vector_from_rotation
from ..sensor.camera import backproject_theta

__all__ = ["design_intrinsics", "pose_from_rays", "start_camera"]


def design_intrinsics(image_size, *, gamma=None, signs=(1.0, -1.0)):
    """Design values ``(xi, gamma_u, gamma_v, u0, v0)`` from the image size.

    Parameters
    ----------
    image_size : tuple of int
        ``(width, height)``, px.
    gamma : float, optional
        ``|gamma|`` (default: a third of the smaller side).
    signs : tuple of float
        Signs of ``gamma_u`` and ``gamma_v``.
    """
    w, h = (float(s) for s in image_size)
    g = min(w, h) / 3.0 if gamma is None else float(gamma)
    return np.array([1.0, signs[0] * g, signs[1] * g, (w - 1) / 2.0, (h - 1) / 2.0])


def pose_from_rays(rays, points):
    """Pose ``(w, t)`` of a planar board from unit rays to its corners (linear, DLT).

    Parameters
    ----------
    rays : ndarray, shape (M, 3)
        Unit rays in frame C.
    points : ndarray, shape (M, 3)
        Board-frame corners, mm, with z = 0.

    Returns
    -------
    ndarray, shape (6,)
        Rotation vector and translation; NaN when the fit is degenerate.
    """
    x, y = points[:, 0], points[:, 1]
    o, z = np.ones_like(x), np.zeros((len(x), 3))
    ph = np.stack([x, y, o], -1)                     # homogeneous board points
    d = rays
    # d x (H ph) = 0: rows for the x and y components of the cross product
    r1 = np.concatenate([z, -d[:, 2:3] * ph, d[:, 1:2] * ph], axis=1)
    r2 = np.concatenate([d[:, 2:3] * ph, z, -d[:, 0:1] * ph], axis=1)
    r3 = np.concatenate([-d[:, 1:2] * ph, d[:, 0:1] * ph, z], axis=1)
    A = np.concatenate([r1, r2, r3])
    if not np.all(np.isfinite(A)):
        return np.full(6, np.nan)
    H = np.linalg.svd(A, full_matrices=False)[2][-1].reshape(3, 3)
    if np.sum(d * (ph @ H.T)) < 0:                   # the corners in front of the focus
        H = -H
    s = 2.0 / (np.linalg.norm(H[:, 0]) + np.linalg.norm(H[:, 1]))
    H = H * s
    R0 = np.stack([H[:, 0], H[:, 1], np.cross(H[:, 0], H[:, 1])], axis=1)
    U, _, Vt = np.linalg.svd(R0)
    R = U @ np.diag([1.0, 1.0, np.linalg.det(U @ Vt)]) @ Vt
    return np.concatenate([vector_from_rotation(R), H[:, 2]])


def _cost_at(lik, k, poses, n_steps):
    """Per-view least-squares cost after ``n_steps`` Gauss-Newton pose steps (unit noise)."""
    s2 = np.ones(lik.K)
    for _ in range(n_steps):
        with np.errstate(all="ignore"):
            lm, poses = lik.pose_laplace(k, poses, s2, 0.0, n_steps=1)
    r = lik.residuals(k, poses)
    return np.sum(r * r, axis=-1), poses


def start_camera(lik, image_size, *, signs=(1.0, -1.0), n_grid=16, n_steps=3, fixed=None):
    """Start values for the intrinsics and every view's pose.

    Parameters
    ----------
    lik : BoardLikelihood
    image_size : tuple of int
    signs : tuple of float
        Signs of ``gamma_u``, ``gamma_v``.
    fixed : array_like, shape (5,), optional
        Start intrinsics given by the user: only the poses are found.

    Returns
    -------
    intrinsics : ndarray, shape (5,)
    poses : ndarray, shape (K, 6)

    Raises
    ------
    DegenerateInputError
        A view gives no finite pose at any candidate (named).
    """
    half_diag = 0.5 * np.hypot(*image_size)
    best, found = None, np.zeros(lik.K, bool)
    if fixed is not None:
        candidates = [np.asarray(fixed, float)]
    else:
        candidates = [design_intrinsics(image_size, gamma=g, signs=signs)
                      for g in np.geomspace(0.05, 1.0, n_grid) * half_diag]
    for k in candidates:
        theta = np.concatenate([k, [0.0, 0.0]])
        poses = np.empty((lik.K, 6))
        for j, v in enumerate(lik.views):
            rays, _ = backproject_theta(theta, v.pixels)
            poses[j] = pose_from_rays(rays, v.points)
        ok = np.all(np.isfinite(poses), axis=1)
        poses[~ok] = 0.0
        cost, poses = _cost_at(lik, k, poses, n_steps)
        ok &= np.isfinite(cost)
        found |= ok
        total = np.sum(np.where(ok, cost, np.inf))
        if ok.all() and (best is None or total < best[0]):
            best = (total, k, poses)
    if best is None:
        bad = [lik.names[j] for j in np.flatnonzero(~found)] or lik.names
        raise DegenerateInputError(
            f"no pose fits view(s) {', '.join(bad)} at any start: check their corners "
            "(order, board size) and the image size")
    return best[1], best[2]
