"""A calibration board seen through eq. (1): a rigid pose, then the camera's projection.

A view of a board has its own pose: a rotation vector ``w`` (axis times angle, rad)
and a translation ``t`` (mm) that take board-frame points ``p`` to frame C,
``P = R(w) p + t`` with ``R(w) = exp([w]_x)`` (Rodrigues). ``P`` then images by
eq. (1) with the five camera intrinsics ``k = (xi, gamma_u, gamma_v, u0, v0)``
(:data:`CAMERA_NAMES`).

OpenCV's omnidirectional model (``cv2.omnidir.projectPoints``, zero distortion,
zero skew) is the same projection seen from a frame whose z points the other way:
with ``P_cv = diag(1, 1, -1) P``, ``u = fx x_s / (z_s + xi) + cx`` equals eq. (1)
with ``fx = gamma_u``, ``fy = gamma_v``, ``cx = u0``, ``cy = v0`` and the same xi.
For a planar board (z = 0 in its frame) ``diag(1, 1, -1) R diag(1, 1, -1)`` is again a
rotation, so a pose of either model is a pose of the other (see ``docs/camera.md``).
"""

from __future__ import annotations

import numpy as np

from .camera import project_theta
from .parameters import CAMERA_NAMES

__all__ = ["CAMERA_NAMES", "POSE6_NAMES", "rotation_from_vector", "vector_from_rotation",
           "project_board", "project_board_local", "log_det_left_jacobian"]

#: a view's pose: rotation vector (rad) then translation (mm), board frame -> frame C
POSE6_NAMES = ("w_x", "w_y", "w_z", "t_x", "t_y", "t_z")


def _skew(v):
    x, y, z = np.moveaxis(v, -1, 0)
    o = np.zeros_like(x)
    return np.stack([np.stack([o, -z, y], -1), np.stack([z, o, -x], -1),
                     np.stack([-y, x, o], -1)], -2)


def rotation_from_vector(w, *, jacobian=False):
    """Rodrigues' formula: the rotation of a rotation vector, and its derivative.

    Parameters
    ----------
    w : array_like, shape (..., 3)
        Axis times angle, rad.
    jacobian : bool
        Also return ``dR/dw_i``.

    Returns
    -------
    R : ndarray, shape (..., 3, 3)
    dR : ndarray, shape (..., 3, 3, 3)
        Only with ``jacobian=True``: ``dR[..., i]`` is ``dR/dw_i`` (Gallego and Yezzi's
        closed form, ``(w_i [w]_x + [w x (I - R) e_i]_x) R / |w|^2``; the series
        ``[e_i]_x`` at ``w = 0``).
    """
    w = np.asarray(w, dtype=float)
    th2 = np.sum(w * w, axis=-1)
    th = np.sqrt(th2)
    small = th2 < 1e-16
    ths = np.where(small, 1.0, th)
    a = np.where(small, 1.0 - th2 / 6.0, np.sin(ths) / ths)
    b = np.where(small, 0.5 - th2 / 24.0, (1.0 - np.cos(ths)) / np.where(small, 1.0, th2))
    if not jacobian:
        # I + a [w]_x + b [w]_x^2 = (1 - b th^2) I + a [w]_x + b w w^T, entry by entry
        R = (b[..., None] * w)[..., :, None] * w[..., None, :]
        i = np.arange(3)
        R[..., i, i] += (1.0 - b * th2)[..., None]
        aw = a[..., None] * w
        for (r, c), j in (((2, 1), 0), ((0, 2), 1), ((1, 0), 2)):
            R[..., r, c] += aw[..., j]
            R[..., c, r] -= aw[..., j]
        return R
    K = _skew(w)
    eye = np.eye(3)
    R = eye + a[..., None, None] * K + b[..., None, None] * (K @ K)
    dR = np.empty(R.shape + (3,))
    th2s = np.where(small, 1.0, th2)[..., None, None]
    for i in range(3):
        e = eye[i]
        v = np.cross(w, np.einsum("...jk,k->...j", eye - R, e))
        gy = (w[..., i, None, None] * K + _skew(v)) @ R / th2s
        dR[..., i] = np.where(small[..., None, None], _skew(np.broadcast_to(e, w.shape)), gy)
    return R, dR


def vector_from_rotation(R):
    """The rotation vector of a rotation matrix (inverse of :func:`rotation_from_vector`).

    Parameters
    ----------
    R : array_like, shape (3, 3)

    Returns
    -------
    ndarray, shape (3,)
        Axis times angle, angle in ``[0, pi]``.
    """
    R = np.asarray(R, dtype=float)
    c = np.clip((np.trace(R) - 1.0) / 2.0, -1.0, 1.0)
    th = np.arccos(c)
    axis = np.array([R[2, 1] - R[1, 2], R[0, 2] - R[2, 0], R[1, 0] - R[0, 1]])
    if th < 1e-8:
        return 0.5 * axis
    if np.pi - th > 1e-6:
        return th * axis / (2.0 * np.sin(th))
    # near pi: the axis from the symmetric part
    M = (R + np.eye(3)) / 2.0
    k = int(np.argmax(np.diag(M)))
    v = M[:, k] / np.sqrt(max(M[k, k], 1e-300))
    if axis @ v < 0:
        v = -v
    return th * v / np.linalg.norm(v)


def project_board(intrinsics, pose, points, *, jacobian=False):
    """Pixels of board points through a pose and eq. (1).

    Parameters
    ----------
    intrinsics : array_like, shape (..., 5)
        ``(xi, gamma_u, gamma_v, u0, v0)`` (px for the last four); broadcasts over the
        leading axes (walkers, views).
    pose : array_like, shape (..., 6)
        Rotation vector (rad) and translation (mm), board frame -> frame C.
    points : array_like, shape (..., M, 3)
        Board-frame points, mm.
    jacobian : bool
        Also return derivatives.

    Returns
    -------
    uv : ndarray, shape (..., M, 2)
        Pixels; NaN where the point is outside eq. (1)'s domain.
    valid : ndarray of bool, shape (..., M)
    d_intrinsics : ndarray, shape (..., M, 2, 5)
        Only with ``jacobian=True``.
    d_pose : ndarray, shape (..., M, 2, 6)
        Only with ``jacobian=True``.
    """
    k = np.asarray(intrinsics, dtype=float)
    pose = np.asarray(pose, dtype=float)
    p = np.asarray(points, dtype=float)
    theta = np.concatenate([k, np.zeros(k.shape[:-1] + (2,))], axis=-1)[..., None, :]
    pT = np.swapaxes(p, -1, -2)                                       # (..., 3, M)
    if not jacobian:
        R = rotation_from_vector(pose[..., :3])
        P = np.swapaxes(R @ pT, -1, -2) + pose[..., None, 3:]
        return project_theta(theta, P)
    R, dR = rotation_from_vector(pose[..., :3], jacobian=True)
    P = np.swapaxes(R @ pT, -1, -2) + pose[..., None, 3:]
    uv, valid, dP, dth = project_theta(theta, P, jacobian=True)
    # dP/dw_k = dR[..., k] p: (..., i, k, j) @ (3, M) -> (..., M, i, k)
    sh = dR.shape[:-3]
    dRp = np.swapaxes(dR, -1, -2).reshape(sh + (9, 3)) @ pT
    dPdw = np.moveaxis(dRp.reshape(sh + (3, 3, dRp.shape[-1])), -1, -3)
    d_pose = np.concatenate([dP @ dPdw, dP], axis=-1)
    return uv, valid, dth[..., :5], d_pose


def log_det_left_jacobian(w):
    """``log det J_l(w)`` of SO(3): ``log(2 (1 - cos |w|) / |w|^2)``.

    ``J_l(w)`` maps a change of the rotation vector to the left perturbation it causes,
    ``R(w + dw) = exp([J_l(w) dw]_x) R(w)`` (to first order), so a pose Hessian in the
    left-perturbation coordinates of :func:`project_board_local` is ``J_l^-T H_w J_l^-1``
    in ``w``: ``log det H_w = log det H_local + 2 log det J_l(w)``.

    Parameters
    ----------
    w : array_like, shape (..., 3)
        Rotation vectors, rad.

    Returns
    -------
    ndarray, shape (...)
    """
    th2 = np.sum(np.asarray(w, float) ** 2, axis=-1)
    small = th2 < 1e-8
    th2s = np.where(small, 1.0, th2)
    # 2 (1 - cos th) / th^2 = (sin(th/2) / (th/2))^2; series 1 - th^2/12 near 0
    half = np.sqrt(th2s) / 2.0
    return np.where(small, -th2 / 12.0, 2.0 * np.log(np.abs(np.sin(half)) / half))


def local_rows(intrinsics, pose, points):
    """Local-coordinate derivatives and pixels of board points, component-major (internal).

    Returns
    -------
    ndarray, shape (..., 7, 2, M)
        ``[..., :6, :, m]`` is ``d(u, v) / d(d, t)`` of point ``m``
        (:func:`project_board_local`), ``[..., 6, :, m]`` its pixel ``(u, v)``; NaN outside
        eq. (1)'s domain. Each ``(..., M)`` block is contiguous.
    """
    k = np.asarray(intrinsics, dtype=float)
    pose = np.asarray(pose, dtype=float)
    R = rotation_from_vector(pose[..., :3])
    q = np.asarray(points, dtype=float) @ np.swapaxes(R, -1, -2)       # R p: (..., M, 3)
    qx, qy, qz = q[..., 0], q[..., 1], q[..., 2]
    x, y, z = (qx + pose[..., 3, None], qy + pose[..., 4, None], qz + pose[..., 5, None])
    xi, gu, gv, u0, v0 = (k[..., i, None] for i in range(5))
    r = np.sqrt(x * x + y * y + z * z)
    D = xi * r - z
    with np.errstate(divide="ignore", invalid="ignore"):
        Dinv = 1.0 / np.where(D > 0, D, np.nan)
        c = xi / r
    cx, cy, cz = c * x, c * y, c * z - 1.0
    out = np.empty(x.shape[:-1] + (7, 2, x.shape[-1]))
    # d(u, v)/dP = gamma D^-1 (e_x - m dD/dP), dD/dP = xi P / r - e_z; d/dd = (q x a)
    for row, (f, m, g0) in enumerate(((gu * Dinv, x * Dinv, u0), (gv * Dinv, y * Dinv, v0))):
        o = out[..., row, :]
        sm = f * m
        np.multiply(-sm, cx, out=o[..., 3, :])
        np.multiply(-sm, cy, out=o[..., 4, :])
        np.multiply(-sm, cz, out=o[..., 5, :])
        o[..., 3 + row, :] += f
        ax, ay, az = o[..., 3, :], o[..., 4, :], o[..., 5, :]
        o[..., 0, :] = qy * az - qz * ay
        o[..., 1, :] = qz * ax - qx * az
        o[..., 2, :] = qx * ay - qy * ax
        o[..., 6, :] = (gu if row == 0 else gv) * m + g0
    return out


def project_board_local(intrinsics, pose, points):
    """Pixels of board points and their derivatives in a pose's local coordinates.

    The derivative is taken with respect to a left perturbation of the rotation,
    ``R -> exp([d]_x) R``, and the translation: ``dP/dd = -[R p]_x``, which needs no
    derivative of Rodrigues' formula (cheaper than :func:`project_board`'s ``d_pose``, equal
    to it times ``J_l(w)^-1``, :func:`log_det_left_jacobian`).

    Parameters
    ----------
    intrinsics : array_like, shape (..., 5)
    pose : array_like, shape (..., 6)
        Rotation vector (rad) and translation (mm).
    points : array_like, shape (..., M, 3)
        Board-frame points, mm.

    Returns
    -------
    uv : ndarray, shape (..., M, 2)
        Pixels; NaN outside eq. (1)'s domain.
    d_local : ndarray, shape (..., M, 2, 6)
        ``d(u, v) / d(d, t)``.
    """
    out = np.moveaxis(local_rows(intrinsics, pose, points), -1, -3)     # (..., M, 7, 2)
    return out[..., 6, :], np.swapaxes(out[..., :6, :], -1, -2)
