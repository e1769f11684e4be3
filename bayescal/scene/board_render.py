"""Rendered chessboard images through the catadioptric camera: the truth of the detector.

:func:`render_board` traces every pixel back through eq. (1) to the plane of a board
held in a known pose (rotation vector and translation, board frame -> frame C, the
convention of :func:`bayescal.sensor.board.project_board`), paints the printed squares and
a white margin, averages ``supersample^2`` rays per pixel (anti-aliasing), blurs with the
lens and adds noise. The exact corners come back as a :class:`~bayescal.BoardView`, so
that detection and calibration can be tested on images whose answer is known.
"""

from __future__ import annotations

import numpy as np
from scipy.ndimage import gaussian_filter

from .._validation import check_positive, resolve_rng
from ..errors import InvalidValueError
from ..image.views import BoardView, board_points
from ..sensor.board import CAMERA_NAMES, project_board, rotation_from_vector
from ..sensor.camera import backproject_theta

__all__ = ["render_board"]


def _intrinsics(intrinsics):
    if hasattr(intrinsics, "keys"):
        missing = [n for n in CAMERA_NAMES if n not in intrinsics]
        if missing:
            raise InvalidValueError(f"intrinsics lack {missing}; expected the names {CAMERA_NAMES}")
        k = np.array([float(intrinsics[n]) for n in CAMERA_NAMES])
    else:
        k = np.asarray(intrinsics, dtype=float)
    if k.shape != (5,) or not np.all(np.isfinite(k)):
        raise InvalidValueError(
            f"intrinsics must be 5 finite numbers {CAMERA_NAMES}, got {intrinsics!r}")
    return k


def _outline(nx, ny, square, border, n=64):
    """Points along the outer edge of the printed board and its margin, board frame, mm."""
    lo = -(1.0 + border) * square
    hx, hy = (nx + border) * square, (ny + border) * square
    s = np.linspace(0.0, 1.0, n)
    xs, ys = lo + (hx - lo) * s, lo + (hy - lo) * s
    edges = [np.stack([xs, np.full(n, lo)], -1), np.stack([xs, np.full(n, hy)], -1),
             np.stack([np.full(n, lo), ys], -1), np.stack([np.full(n, hx), ys], -1)]
    xy = np.concatenate(edges)
    return np.column_stack([xy, np.zeros(len(xy))])


def _albedo(xy, nx, ny, square, border, levels):
    """Reflectance of the board plane at board coordinates ``xy`` (mm); NaN off the board."""
    dark, light, _ = levels
    i = np.floor(xy[:, 0] / square)
    j = np.floor(xy[:, 1] / square)
    on_squares = (i >= -1) & (i <= nx - 1) & (j >= -1) & (j <= ny - 1)
    lo = -(1.0 + border) * square
    on_board = ((xy[:, 0] >= lo) & (xy[:, 0] <= (nx + border) * square)
                & (xy[:, 1] >= lo) & (xy[:, 1] <= (ny + border) * square))
    value = np.where(on_squares & ((i + j) % 2 == 0), dark, light)
    return np.where(on_board, value, np.nan)


def _trace(k, R, t, pix, nx, ny, square, border, levels):
    """Reflectance seen along the rays of pixels ``pix`` (N, 2)."""
    theta = np.concatenate([k, [0.0, 0.0]])
    rays, valid = backproject_theta(theta, pix)
    n = R[:, 2]
    with np.errstate(divide="ignore", invalid="ignore"):
        s = (n @ t) / (rays @ n)
        P = s[:, None] * rays - t
    xy = (P @ R)[:, :2]
    alb = _albedo(xy, nx, ny, square, border, levels)
    hit = valid & (s > 0) & np.isfinite(alb)
    return np.where(hit, alb, np.where(valid, levels[2], 0.0))


def _check_visible(k, R, t, points, uv):
    """Refuse boards seen edge-on or beyond the mirror's rim (eq. (1) folds them back)."""
    n = R[:, 2]
    if abs(n @ t) < 0.05 * np.linalg.norm(t):
        raise InvalidValueError(f"the board is seen edge-on in pose t = {np.round(t, 1).tolist()} "
                                "(its plane passes within 3 degrees of the focus)")
    P = points @ R.T + t
    rays, ok = backproject_theta(np.concatenate([k, [0.0, 0.0]]), uv)
    cosang = np.sum(rays * P, axis=1) / np.linalg.norm(P, axis=1)
    if not np.all(ok & (cosang > 1.0 - 1e-9)):
        raise InvalidValueError(f"the board in pose t = {np.round(t, 1).tolist()} is beyond the "
                                "mirror's field of view (eq. (1) does not image it)")


def _backdrop(k, w, h, level):
    """The scene around the board: ``level`` where eq. (1) inverts (the mirror), else 0."""
    xi, gu, gv, u0, v0 = k
    mx = (np.arange(w) - u0) / gu
    my = (np.arange(h) - v0) / gv
    rho2 = my[:, None] ** 2 + mx[None, :] ** 2
    return np.where(1.0 + (1.0 - xi * xi) * rho2 >= 0, float(level), 0.0)


def _box(k, pose, nx, ny, square, border, size):
    """Pixel bounding box (u0, u1, v0, v1) of the board and margin, clipped to the image."""
    uv, valid = project_board(k, pose, _outline(nx, ny, square, border))
    if not np.all(valid):
        raise InvalidValueError("the board (with its margin) is not wholly in front of the camera "
                                f"in pose {np.round(pose, 3).tolist()}")
    w, h = size
    lo = np.floor(uv.min(axis=0)).astype(int) - 2
    hi = np.ceil(uv.max(axis=0)).astype(int) + 3
    return max(lo[0], 0), min(hi[0], w), max(lo[1], 0), min(hi[1], h)


def render_board(intrinsics, pose, *, board=(8, 6), square=42.0, image_size=(1280, 1024),
                 border=0.6, supersample=4, psf_px=0.5, noise=2.0, levels=(30.0, 220.0, 100.0),
                 rng=None, name="rendered"):
    """Render a chessboard seen through the unified camera model.

    Parameters
    ----------
    intrinsics : mapping or array_like, shape (5,)
        ``xi, gamma_u, gamma_v, u0, v0`` (names or that order; px for the last four).
    pose : array_like, shape (6,)
        Rotation vector (rad) and translation (mm), board frame -> frame C:
        ``P = R(w) p + t``.
    board : tuple of int, optional
        ``(columns, rows)`` of inner corners.
    square : float, optional
        Side of a square, mm.
    image_size : tuple of int, optional
        ``(width, height)``, px.
    border : float, optional
        White margin around the outer squares, in squares.
    supersample : int, optional
        Rays per pixel along each axis (anti-aliasing).
    psf_px : float, optional
        Standard deviation of the lens blur, px (0: none).
    noise : float, optional
        Standard deviation of the additive Gaussian noise, grey levels.
    levels : tuple of float, optional
        Grey levels of the dark squares, the light squares and margin, and the scene
        around the board (0-255); outside the mirror's image (rays eq. (1) cannot
        invert) the image is black.
    rng : numpy.random.Generator, int or None, optional
        Noise.
    name : str, optional
        Name of the returned view.

    Returns
    -------
    image : ndarray of uint8, shape (height, width)
    truth : BoardView
        The exact inner corners (:func:`bayescal.board_points` order), px, and their
        board-frame points, mm.

    Raises
    ------
    ValueError
        If the board is not wholly in front of the camera or not inside the image.
    """
    k = _intrinsics(intrinsics)
    pose = np.asarray(pose, dtype=float)
    if pose.shape != (6,) or not np.all(np.isfinite(pose)):
        raise InvalidValueError(f"pose must be 6 finite numbers (rotation vector, translation), "
                                f"got {pose!r}")
    w, h = (int(s) for s in image_size)
    nx, ny = (int(b) for b in board)
    check_positive(square, "square")
    check_positive(noise, "noise", allow_zero=True)
    check_positive(psf_px, "psf_px", allow_zero=True)
    ss = int(supersample)
    if ss < 1:
        raise InvalidValueError(f"supersample must be >= 1, got {supersample!r}")
    rng = resolve_rng(rng)
    points = board_points((nx, ny), square)
    uv, valid = project_board(k, pose, points)
    R = rotation_from_vector(pose[:3])
    _check_visible(k, R, pose[3:], points, uv)
    inside = np.all((uv >= 0) & (uv <= [w - 1, h - 1]), axis=1)
    if not np.all(valid & inside):
        raise InvalidValueError(f"the board's corners are not all inside the {w}x{h} image "
                                f"in pose {np.round(pose, 3).tolist()}")
    u0, u1, v0, v1 = _box(k, pose, nx, ny, square, border, (w, h))
    image = _backdrop(k, w, h, levels[2])
    off = (np.arange(ss) + 0.5) / ss - 0.5
    by, bx = np.mgrid[v0:v1, u0:u1]
    oy, ox = np.meshgrid(off, off, indexing="ij")
    sub = np.stack([(bx[..., None] + ox.ravel()).ravel(),
                    (by[..., None] + oy.ravel()).ravel()], axis=-1)
    vals = _trace(k, R, pose[3:], sub, nx, ny, square, border, levels)
    image[v0:v1, u0:u1] = vals.reshape(v1 - v0, u1 - u0, ss * ss).mean(axis=-1)
    if psf_px > 0:
        image = gaussian_filter(image, psf_px)
    image = image + noise * rng.standard_normal(image.shape)
    out = np.clip(np.rint(image), 0, 255).astype(np.uint8)
    return out, BoardView(uv, points, name=name, image_size=(w, h))
