"""The pose of the laser cone in frame C: tilt and lateral offset (a misaligned cone).

The paper's cone has its apex at ``(0, 0, -h)`` and its axis along z. A hand
assembled sensor has the cone's axis tilted and its apex shifted sideways. The
pose is four numbers ``(tilt_x, tilt_y, offset_x, offset_y)``:

* apex ``A = (offset_x, offset_y, -h)`` in frame C, mm;
* frame L's axes in C are the columns of ``R = Ry(tilt_y) @ Rx(tilt_x)`` (right-handed
  rotations, rad), so the cone's axis is
  ``a = R @ (0, 0, 1) = (cos tx sin ty, -sin tx, cos tx cos ty)``;
* a point ``P`` of C has L coordinates ``Q = R.T @ (P - A)``, and lies on the lit
  nappe when ``|Q_xy| = Q_z tan(beta)`` with ``Q_z > 0``.

All four zero is the paper's model: :func:`bayescal.triangulate` then uses the
aligned closed form of :mod:`bayescal.sensor.laser` (bit for bit the paper's
model), and the general formula here agrees with it to rounding (1e-13
relative, checked in the tests).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..errors import InvalidTypeError, InvalidValueError
from .camera import backproject_theta

__all__ = [
    "LaserPose",
    "POSE_NAMES",
    "as_pose_array",
    "pose_rotation",
    "triangulate_pose_theta",
    "cone_point_pose_theta",
    "cone_distance_pose",
]

POSE_NAMES = ("tilt_x", "tilt_y", "offset_x", "offset_y")


@dataclass(frozen=True)
class LaserPose:
    """Tilt and offset of the laser cone in frame C.

    Parameters
    ----------
    tilt_x, tilt_y : float
        Rotations of the cone's axis about x then y, rad (``R = Ry(tilt_y) Rx(tilt_x)``).
    offset_x, offset_y : float
        Lateral position of the apex in frame C, mm.
    h : float or None, optional
        Depth of the apex below the mirror focus, mm; needed only by :attr:`apex`.

    Examples
    --------
    >>> import numpy as np
    >>> import bayescal as bc
    >>> pose = bc.LaserPose(tilt_y=np.radians(1.0), offset_x=5.0, h=200.0)
    >>> (np.round(pose.axis, 4) + 0.0).tolist(), pose.apex.tolist()
    ([0.0175, 0.0, 0.9998], [5.0, 0.0, -200.0])
    """

    tilt_x: float = 0.0
    tilt_y: float = 0.0
    offset_x: float = 0.0
    offset_y: float = 0.0
    h: float | None = None

    def __post_init__(self):
        for name in POSE_NAMES:
            value = getattr(self, name)
            if isinstance(value, bool) or not isinstance(value, (int, float, np.floating,
                                                                 np.integer)):
                raise InvalidTypeError(f"{name} must be a real number, got {value!r}")
            if not np.isfinite(value):
                raise InvalidValueError(f"{name} must be finite, got {value!r}")
            object.__setattr__(self, name, float(value))

    @classmethod
    def from_array(cls, a, *, h=None):
        """Pose from ``(tilt_x, tilt_y, offset_x, offset_y)``, shape (4,)."""
        a = np.asarray(a, dtype=float)
        if a.shape != (4,):
            raise InvalidValueError(f"pose array must have shape (4,), got {a.shape}")
        return cls(*map(float, a), h=h)

    def to_array(self):
        """``(tilt_x, tilt_y, offset_x, offset_y)`` as ndarray, shape (4,)."""
        return np.array([self.tilt_x, self.tilt_y, self.offset_x, self.offset_y])

    @property
    def rotation(self):
        """ndarray, shape (3, 3): frame L's axes (columns) in frame C."""
        return pose_rotation(self.to_array())

    @property
    def axis(self):
        """ndarray, shape (3,): the cone's unit axis in frame C."""
        return self.rotation[:, 2]

    @property
    def apex(self):
        """ndarray, shape (3,): the cone's apex in frame C, mm (needs ``h``)."""
        if self.h is None:
            raise InvalidValueError("LaserPose.apex needs h (the apex depth, mm); got h=None")
        return np.array([self.offset_x, self.offset_y, -float(self.h)])

    @property
    def is_aligned(self):
        """bool: all four are exactly zero (the paper's model)."""
        return not np.any(self.to_array())


def as_pose_array(laser, name="laser"):
    """A :class:`LaserPose` or array ``(..., 4)`` as a float array ``(..., 4)``.

    Raises
    ------
    TypeError, ValueError
        Naming ``name`` when ``laser`` is not a pose, has the wrong last axis or
        is not finite.
    """
    if isinstance(laser, LaserPose):
        return laser.to_array()
    try:
        a = np.asarray(laser, dtype=float)
    except (TypeError, ValueError):
        raise InvalidTypeError(f"{name} must be a LaserPose or an array (..., 4) of "
                               f"(tilt_x, tilt_y, offset_x, offset_y), got {laser!r}") from None
    if a.ndim == 0 or a.shape[-1] != 4:
        raise InvalidValueError(f"{name} must have shape (..., 4) (tilt_x, tilt_y, offset_x, "
                                f"offset_y), got shape {a.shape}")
    if not np.all(np.isfinite(a)):
        raise InvalidValueError(f"{name} must be finite, got {a}")
    return a


def pose_rotation(pose, *, jacobian=False):
    """Rotation ``R = Ry(tilt_y) @ Rx(tilt_x)`` of frame L in C.

    Parameters
    ----------
    pose : ndarray, shape (..., 4)
        ``(tilt_x, tilt_y, offset_x, offset_y)``; rad, rad, mm, mm.
    jacobian : bool

    Returns
    -------
    R : ndarray, shape (..., 3, 3)
    dR : ndarray, shape (..., 2, 3, 3)
        Only with ``jacobian=True``: dR/dtilt_x, dR/dtilt_y.
    """
    pose = np.asarray(pose, dtype=float)
    cx, sx = np.cos(pose[..., 0]), np.sin(pose[..., 0])
    cy, sy = np.cos(pose[..., 1]), np.sin(pose[..., 1])
    z = np.zeros_like(cx)
    R = np.stack([np.stack([cy, sy * sx, sy * cx], -1),
                  np.stack([z, cx, -sx], -1),
                  np.stack([-sy, cy * sx, cy * cx], -1)], -2)
    if not jacobian:
        return R
    dRx = np.stack([np.stack([z, sy * cx, -sy * sx], -1),
                    np.stack([z, -sx, -cx], -1),
                    np.stack([z, cy * cx, -cy * sx], -1)], -2)
    dRy = np.stack([np.stack([-sy, cy * sx, cy * cx], -1),
                    np.stack([z, z, z], -1),
                    np.stack([-cy, -sy * sx, -sy * cx], -1)], -2)
    return R, np.stack([dRx, dRy], -3)


def _first_root(A2, B, C):
    """Smallest positive root of ``A2 t^2 + 2 B t + C = 0`` when ``C > 0`` (stable form)."""
    disc = B * B - A2 * C
    sq = np.sqrt(np.where(disc >= 0, disc, np.nan))
    with np.errstate(divide="ignore", invalid="ignore"):
        return np.where(B <= 0, C / (-B + sq), (-B - sq) / A2)


def triangulate_pose_theta(theta, pose, pixels, *, jacobian=False):
    """Ray/cone intersection with a tilted, offset cone (internal, unchecked).

    The ray ``t d`` from the focus has L coordinates ``Q(t) = o + t e`` with
    ``o = -R.T A``, ``e = R.T d``; ``f(t) = T^2 Q_z^2 - Q_x^2 - Q_y^2``
    (``T = tan beta``) is ``A2 t^2 + 2 B t + C``. The focus lies inside the lit
    nappe (``C > 0``, ``o_z > 0``), so the first positive root is where the ray
    leaves the solid cone, through the lit nappe; it is taken in the form that
    does not cancel.

    Parameters
    ----------
    theta : ndarray, shape (..., 7)
        Identifiable parameters.
    pose : ndarray, shape (..., 4)
        ``(tilt_x, tilt_y, offset_x, offset_y)``.
    pixels : ndarray, shape (..., 2)
    jacobian : bool

    Returns
    -------
    points : ndarray, shape (..., 3)
        mm in frame C; NaN where the ray misses the lit nappe.
    valid : ndarray of bool, shape (...)
    d_pixels, d_theta, d_pose : ndarray, shapes (..., 3, 2), (..., 3, 7), (..., 3, 4)
        Only with ``jacobian=True``.
    """
    theta = np.asarray(theta, dtype=float)
    pose = np.asarray(pose, dtype=float)
    out = backproject_theta(theta, pixels, jacobian=jacobian)
    d = out[0]
    h, T = theta[..., 5], np.tan(theta[..., 6])
    A = np.stack(np.broadcast_arrays(pose[..., 2], pose[..., 3], -h), -1)
    rot = pose_rotation(pose, jacobian=jacobian)
    R = rot[0] if jacobian else rot
    RT = np.swapaxes(R, -1, -2)
    o = -(RT @ A[..., None])[..., 0]
    e = (RT @ d[..., None])[..., 0]
    T2 = T * T
    A2 = T2 * e[..., 2] ** 2 - e[..., 0] ** 2 - e[..., 1] ** 2
    B = T2 * o[..., 2] * e[..., 2] - o[..., 0] * e[..., 0] - o[..., 1] * e[..., 1]
    C = T2 * o[..., 2] ** 2 - o[..., 0] ** 2 - o[..., 1] ** 2
    t = _first_root(A2, B, C)
    Q = o + t[..., None] * e
    with np.errstate(invalid="ignore"):
        valid = out[1] & (C > 0) & (o[..., 2] > 0) & np.isfinite(t) & (t > 0) & (Q[..., 2] > 0)
    t = np.where(valid, t, np.nan)
    pts = t[..., None] * d
    if not jacobian:
        return pts, valid
    return (pts, valid) + _pose_jacobians(out, t, d, Q, R, rot[1], T, A)


def _pose_jacobians(out, t, d, Q, R, dR, T, A):
    """Implicit-function derivatives of ``P = t d`` (see :func:`triangulate_pose_theta`)."""
    gQ = np.stack([-2 * Q[..., 0], -2 * Q[..., 1], 2 * T * T * Q[..., 2]], -1)
    gC = (R @ gQ[..., None])[..., 0]                 # df/dP in C: f depends on P - A
    dfdt = np.sum(gC * d, -1)
    with np.errstate(divide="ignore", invalid="ignore"):
        inv = -1.0 / dfdt
    # dt/dd (d enters through P = t d), then P = t d
    dt_dd = (inv * t)[..., None] * gC
    dP_dd = t[..., None, None] * np.eye(3) + d[..., :, None] * dt_dd[..., None, :]
    dpix = dP_dd @ out[2]
    dth = dP_dd @ out[3]
    # h and beta: A_z = -h, so df/dh = -gC . dA/dh = gC_z; df/dT = 2 T Q_z^2
    dt_dh = inv * gC[..., 2]
    beta_T = 1.0 + T * T                              # dT/dbeta
    dt_db = inv * 2 * T * Q[..., 2] ** 2 * beta_T
    dth[..., :, 5] += d * dt_dh[..., None]
    dth[..., :, 6] += d * dt_db[..., None]
    # pose: Q = R^T (P - A); df/dtilt = gQ . dR^T/dtilt (P - A); df/doffset = -gC_{x,y}
    W = t[..., None] * d - A
    dfdtilt = np.stack([np.sum(gQ * (np.swapaxes(dR[..., k, :, :], -1, -2)
                                     @ W[..., None])[..., 0], -1) for k in range(2)], -1)
    dfdpose = np.concatenate([dfdtilt, -gC[..., :2]], -1)
    dpose = d[..., :, None] * (inv[..., None] * dfdpose)[..., None, :]
    return dpix, dth, dpose


def cone_point_pose_theta(theta, pose, xy, *, jacobian=False):
    """Point of the tilted cone's lit nappe above the scene position ``xy`` (internal).

    The vertical line through ``(x, y)`` meets the double cone twice; the lit
    nappe is the upper crossing, the larger root of ``A2 z^2 + 2 B z + C = 0``
    (``o = R.T ((x, y, 0) - A)``, ``e = R.T (0, 0, 1)``), taken in the form that
    does not cancel. With the pose zero this is ``rho / tan(beta) - h``.

    Parameters
    ----------
    theta : ndarray, shape (..., 7)
        Identifiable parameters; only ``h`` and ``beta`` are used.
    pose : ndarray, shape (..., 4)
    xy : ndarray, shape (..., 2)
        Horizontal position in frame C, mm.
    jacobian : bool

    Returns
    -------
    points : ndarray, shape (..., 3)
        mm; z is NaN where the line misses the lit nappe.
    d_xy, d_theta, d_pose : ndarray, shapes (..., 3, 2), (..., 3, 7), (..., 3, 4)
        Only with ``jacobian=True`` (only row 2, z, is non-zero beyond d_xy's identity).
    """
    theta = np.asarray(theta, dtype=float)
    pose = np.asarray(pose, dtype=float)
    xy = np.asarray(xy, dtype=float)
    h, T = theta[..., 5], np.tan(theta[..., 6])
    x, y = xy[..., 0], xy[..., 1]
    W0 = np.stack(np.broadcast_arrays(x - pose[..., 2], y - pose[..., 3], h), -1)
    rot = pose_rotation(pose, jacobian=jacobian)
    R = rot[0] if jacobian else rot
    o = (W0[..., None, :] @ R)[..., 0, :]                # R.T @ W0
    e = R[..., 2, :]                                      # R.T @ (0, 0, 1)
    T2 = T * T
    A2 = T2 * e[..., 2] ** 2 - e[..., 0] ** 2 - e[..., 1] ** 2
    B = T2 * o[..., 2] * e[..., 2] - o[..., 0] * e[..., 0] - o[..., 1] * e[..., 1]
    C = T2 * o[..., 2] ** 2 - o[..., 0] ** 2 - o[..., 1] ** 2
    disc = B * B - A2 * C
    sq = np.sqrt(np.where(disc >= 0, disc, np.nan))
    with np.errstate(divide="ignore", invalid="ignore"):
        z = np.where(B <= 0, (-B + sq) / A2, C / (-B - sq))
        Qz = o[..., 2] + z * e[..., 2]
        z = np.where((A2 > 0) & (Qz > 0), z, np.nan)
    pts = np.stack(np.broadcast_arrays(x, y, z), -1)
    if not jacobian:
        return pts
    return (pts,) + _cone_point_jacobians(pts, o + z[..., None] * e, R, rot[1], T, W0, z)


def _cone_point_jacobians(pts, Q, R, dR, T, W0, z):
    """Implicit-function derivatives of z in :func:`cone_point_pose_theta`."""
    gQ = np.stack([-2 * Q[..., 0], -2 * Q[..., 1], 2 * T * T * Q[..., 2]], -1)
    gC = (R @ gQ[..., None])[..., 0]
    with np.errstate(divide="ignore", invalid="ignore"):
        inv = -1.0 / gC[..., 2]
    shape = pts.shape[:-1]
    dxy = np.zeros(shape + (3, 2))
    dxy[..., 0, 0] = 1.0
    dxy[..., 1, 1] = 1.0
    dxy[..., 2, :] = inv[..., None] * gC[..., :2]
    dth = np.zeros(shape + (3, 7))
    dth[..., 2, 5] = inv * gC[..., 2]
    dth[..., 2, 6] = inv * 2 * T * Q[..., 2] ** 2 * (1.0 + T * T)
    W = W0.copy()
    W[..., 2] = W0[..., 2] + z                          # P - A
    dfdtilt = np.stack([np.sum(gQ * (np.swapaxes(dR[..., k, :, :], -1, -2)
                                     @ W[..., None])[..., 0], -1) for k in range(2)], -1)
    dpose = np.zeros(shape + (3, 4))
    dpose[..., 2, :2] = inv[..., None] * dfdtilt
    dpose[..., 2, 2:] = -inv[..., None] * gC[..., :2]
    return dxy, dth, dpose


def cone_distance_pose(params, points, *, jacobian=False):
    """Signed distance of points from a tilted, offset laser cone (sequential stage 2).

    With apex ``A = (offset_x, offset_y, -h)``, unit axis ``a`` (the convention of
    :class:`LaserPose`) and ``d = P - A``: ``r = |d - (d . a) a| cos(beta) - (d . a)
    sin(beta)``, the distance from the cone's surface near its lit nappe, positive
    outside the cone (zero pose: :func:`~bayescal.sensor.laser.cone_distance`).

    Parameters
    ----------
    params : array_like, shape (6,)
        ``(h, beta, tilt_x, tilt_y, offset_x, offset_y)`` (mm, rad, rad, rad, mm, mm).
    points : ndarray, shape (K, 3)
        Points in frame C, mm.
    jacobian : bool

    Returns
    -------
    r : ndarray, shape (K,)
        mm.
    d_params : ndarray, shape (K, 6)
        Only with ``jacobian=True``.
    d_points : ndarray, shape (K, 3)
        Only with ``jacobian=True``.
    """
    h, b, tx, ty, ox, oy = np.asarray(params, dtype=float)
    a = np.array([np.cos(tx) * np.sin(ty), -np.sin(tx), np.cos(tx) * np.cos(ty)])
    d = np.asarray(points, dtype=float) - np.array([ox, oy, -h])
    za = d @ a
    perp = d - za[:, None] * a
    rp = np.linalg.norm(perp, axis=1)
    r = rp * np.cos(b) - za * np.sin(b)
    if not jacobian:
        return r
    with np.errstate(divide="ignore", invalid="ignore"):
        dP = np.cos(b) * perp / rp[:, None] - np.sin(b) * a
        dr_da = -(np.cos(b) * za / rp + np.sin(b))[:, None] * d
    da_dtx = np.array([-np.sin(tx) * np.sin(ty), -np.cos(tx), -np.sin(tx) * np.cos(ty)])
    da_dty = np.array([np.cos(tx) * np.cos(ty), 0.0, -np.cos(tx) * np.sin(ty)])
    dpar = np.column_stack([dP[:, 2], -rp * np.sin(b) - za * np.cos(b), dr_da @ da_dtx,
                            dr_da @ da_dty, -dP[:, 0], -dP[:, 1]])
    return r, dpar, dP
