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

__all__ = ["CAMERA_NAMES", "POSE6_NAMES", "rotation_from_vector", "vector_from_rotation",
           "project_board"]

#: the five camera intrinsics a board calibrates, in this order
CAMERA_NAMES = ("xi", "gamma_u", "gamma_v", "u0", "v0")
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
    K = _skew(w)
    eye = np.eye(3)
    R = eye + a[..., None, None] * K + b[..., None, None] * (K @ K)
    if not jacobian:
        return R
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
