"""The laser projector: cone (eq. 3), image azimuth (eqs. 4-6), plane (eq. 2), triangulation.

Frame L is frame C shifted by ``(0, 0, -h)``: the cone's apex is at
``(0, 0, -h)`` in C, its axis is the vertical z axis and ``beta`` is its
half-angle from that axis. A point of the cone at horizontal distance
``rho = sqrt(x^2 + y^2)`` from the axis has ``z = rho / tan(beta) - h``
(only the upper nappe, ``z > -h``, is lit).

The laser points are written by their *scene coordinates* ``q = (x, y)``,
the horizontal position where the ray meets the wall; the cone then gives
``z``. This parameterization does not depend on the sensor parameters, which
is what keeps the Bayesian posterior unbiased (``docs/bayes.md``).
"""

from __future__ import annotations

import numpy as np

from .._validation import as_finite_array, as_pixels
from ..errors import InvalidValueError
from .camera import backproject_theta
from .parameters import as_param_array, to_identifiable
from .pose import as_pose_array, cone_point_pose_theta, triangulate_pose_theta

__all__ = [
    "cone_point",
    "cone_point_theta",
    "triangulate",
    "triangulate_theta",
    "triangulate_plane",
    "pixel_azimuth",
    "cone_distance",
    "cone_points_geo",
    "triangulate_geo",
    "cone_height",
]


def cone_point_theta(theta, xy, *, jacobian=False):
    """3D point of the laser cone above the scene position ``xy`` (internal).

    Parameters
    ----------
    theta : ndarray, shape (..., 7)
        Identifiable parameters; only ``h`` (index 5) and ``beta`` (6) are used.
    xy : ndarray, shape (..., 2)
        Horizontal position in frame C, mm.
    jacobian : bool

    Returns
    -------
    points : ndarray, shape (..., 3)
    d_xy : ndarray, shape (..., 3, 2)
        Only with ``jacobian=True``.
    d_theta : ndarray, shape (..., 3, 7)
        Only with ``jacobian=True`` (non-zero in the ``h`` and ``beta`` columns).
    """
    theta = np.asarray(theta, dtype=float)
    h, beta = theta[..., 5], theta[..., 6]
    x, y = xy[..., 0], xy[..., 1]
    rho = np.sqrt(x * x + y * y)
    tb = np.tan(beta)
    z = rho / tb - h
    pts = np.stack(np.broadcast_arrays(x, y, z), axis=-1)
    if not jacobian:
        return pts
    shape = pts.shape[:-1]
    dxy = np.zeros(shape + (3, 2))
    dxy[..., 0, 0] = 1.0
    dxy[..., 1, 1] = 1.0
    with np.errstate(divide="ignore", invalid="ignore"):
        inv = np.where(rho > 0, 1.0 / (rho * tb), 0.0)
    dxy[..., 2, 0] = x * inv
    dxy[..., 2, 1] = y * inv
    dth = np.zeros(shape + (3, 7))
    dth[..., 2, 5] = -1.0
    dth[..., 2, 6] = -rho / np.sin(beta) ** 2
    return pts, dxy, dth


def cone_point(params, xy, *, laser=None):
    """Point of the laser cone above horizontal position(s) ``xy``.

    Parameters
    ----------
    params : SensorParams or ndarray, shape (..., 8)
    xy : array_like, shape (..., 2)
        Horizontal position ``(x, y)`` in frame C, mm.
    laser : LaserPose or array_like, shape (..., 4), optional
        Tilt (rad) and offset (mm) of the cone; None or zero: the aligned cone.

    Returns
    -------
    ndarray, shape (..., 3)
        ``(x, y, rho / tan(beta) - h)`` in mm for the aligned cone; with a pose,
        z on the tilted cone's lit nappe (NaN where the vertical line misses it).

    Examples
    --------
    >>> import numpy as np
    >>> import bayescal as bc
    >>> p = bc.SensorParams.paper()              # h = 200 mm, beta = 60 deg
    >>> np.round(bc.cone_point(p, np.array([1000.0, 0.0])), 3).tolist()
    [1000.0, 0.0, 377.35]
    """
    theta = to_identifiable(as_param_array(params))
    xy = as_finite_array(xy, "xy", last_dim=2)
    pose = None if laser is None else as_pose_array(laser)
    if pose is None or not np.any(pose):
        return cone_point_theta(theta, xy)
    return cone_point_pose_theta(theta, pose, xy)


def triangulate_theta(theta, pixels, *, jacobian=False):
    """Ray/cone intersection (internal, unchecked).

    The ray ``t * d`` (unit ``d``, ``s = sqrt(d_x^2 + d_y^2)``) meets the upper
    nappe at ``t = h tan(beta) / (s - d_z tan(beta))``, valid where the
    denominator is positive.

    Returns
    -------
    points : ndarray, shape (..., 3)
        NaN where the ray misses the cone.
    valid : ndarray of bool, shape (...)
    d_pixels : ndarray, shape (..., 3, 2)
        Only with ``jacobian=True``.
    d_theta : ndarray, shape (..., 3, 7)
        Only with ``jacobian=True``.
    """
    out = backproject_theta(theta, pixels, jacobian=jacobian)
    d = out[0]
    theta = np.asarray(theta, dtype=float)
    h, beta = theta[..., 5], theta[..., 6]
    T = np.tan(beta)
    dx, dy, dz = d[..., 0], d[..., 1], d[..., 2]
    s = np.sqrt(dx * dx + dy * dy)
    g = s - dz * T
    valid = out[1] & (g > 0) & (s > 0)          # s = 0: straight down, only the apex
    with np.errstate(divide="ignore", invalid="ignore"):
        t = np.where(valid, h * T / g, np.nan)
    pts = t[..., None] * d
    if not jacobian:
        return pts, valid
    ddpix, ddth = out[2], out[3]
    with np.errstate(divide="ignore", invalid="ignore"):
        dt_dd = np.stack(np.broadcast_arrays(dx / s, dy / s, -T + 0 * dz), axis=-1)
        dt_dd = (-h * T / g**2)[..., None] * dt_dd          # (..., 3)
    outer = d[..., :, None] * dt_dd[..., None, :]                # (..., 3, 3)
    dP_dd = t[..., None, None] * np.eye(3) + outer
    dpix = dP_dd @ ddpix
    dth = dP_dd @ ddth
    with np.errstate(divide="ignore", invalid="ignore"):
        dt_dh = T / g
        dt_db = h * s * (1.0 + T**2) / g**2
    dth[..., :, 5] += d * dt_dh[..., None]
    dth[..., :, 6] += d * dt_db[..., None]
    return pts, valid, dpix, dth


def triangulate(params, pixels, *, laser=None, return_valid=False):
    """Reconstruct laser pixels as 3D points on the laser cone.

    Each pixel is back-projected to a ray from the mirror focus and
    intersected with the cone of eq. (3).

    Parameters
    ----------
    params : SensorParams or ndarray, shape (..., 8)
    pixels : array_like, shape (..., 2)
        ``(u, v)`` in px.
    laser : LaserPose or array_like, shape (..., 4), optional
        Tilt (rad) and offset (mm) of the cone, ``(tilt_x, tilt_y, offset_x,
        offset_y)`` (:mod:`bayescal.sensor.pose`). None or all zero: the
        paper's aligned cone, computed by its own closed form.
    return_valid : bool, optional
        Also return the mask of pixels whose ray meets the lit nappe of the cone.

    Returns
    -------
    points : ndarray, shape (..., 3)
        mm in frame C; NaN where the ray misses the cone (it points at or
        above the cone's asymptotic direction, or has no back-projection).
    valid : ndarray of bool, shape (...)
        Only with ``return_valid=True``.

    Examples
    --------
    >>> import numpy as np
    >>> import bayescal as bc
    >>> p = bc.SensorParams.paper()
    >>> P = bc.cone_point(p, np.array([[1000.0, 0.0]]))      # a laser point 1 m away
    >>> np.allclose(bc.triangulate(p, bc.project(p, P)), P)
    True
    """
    theta = to_identifiable(as_param_array(params))
    pixels = as_pixels(pixels)
    pose = None if laser is None else as_pose_array(laser)
    if pose is None or not np.any(pose):
        pts, valid = triangulate_theta(theta, pixels)
    else:
        pts, valid = triangulate_pose_theta(theta, pose, pixels)
    return (pts, valid) if return_valid else pts


def triangulate_plane(params, pixels, plane, *, return_valid=False):
    """Reconstruct pixels on the laser plane of eq. (2), ``a x + b y + c z + d = 0``.

    Parameters
    ----------
    params : SensorParams or ndarray, shape (..., 8)
        Only the camera parameters are used.
    pixels : array_like, shape (..., 2)
    plane : array_like, shape (..., 4)
        ``(a, b, c, d)`` in frame C (``d`` in mm when ``(a, b, c)`` is unit).
    return_valid : bool, optional

    Returns
    -------
    points : ndarray, shape (..., 3)
        NaN where the ray is parallel to the plane or meets it behind the focus.
    valid : ndarray of bool, shape (...)
        Only with ``return_valid=True``.

    Examples
    --------
    >>> import numpy as np
    >>> import bayescal as bc
    >>> p = bc.SensorParams.paper()
    >>> pix = bc.project(p, np.array([1000.0, 0.0, -150.0]))
    >>> np.round(bc.triangulate_plane(p, pix, [0.0, 0.0, 1.0, 150.0]), 6) + 0.0   # z = -150
    array([1000.,    0., -150.])
    """
    theta = to_identifiable(as_param_array(params))
    pixels = as_pixels(pixels)
    plane = as_finite_array(plane, "plane", last_dim=4)
    if np.any(np.linalg.norm(plane[..., :3], axis=-1) == 0):
        raise InvalidValueError("plane normal (a, b, c) must be non-zero")
    rays, ok = backproject_theta(theta, pixels)
    denom = np.sum(rays * plane[..., :3], axis=-1)
    with np.errstate(divide="ignore", invalid="ignore"):
        t = -plane[..., 3] / denom
    valid = ok & np.isfinite(t) & (t > 0)
    with np.errstate(invalid="ignore"):
        pts = np.where(valid[..., None], t[..., None] * rays, np.nan)
    return (pts, valid) if return_valid else pts


def pixel_azimuth(params, pixels):
    """Azimuth of the laser ray seen at a pixel, eqs. (4)-(5).

    Parameters
    ----------
    params : SensorParams or ndarray, shape (..., 8)
    pixels : array_like, shape (..., 2)

    Returns
    -------
    ndarray, shape (...)
        Azimuth in radians, ``atan2(y_I, x_I)`` with ``x_I = (u - u0) / alpha_u``
        and ``y_I = (v - v0) / alpha_v``.

    Examples
    --------
    >>> import numpy as np
    >>> import bayescal as bc
    >>> p = bc.SensorParams.paper()
    >>> pix = bc.project(p, bc.cone_point(p, np.array([0.0, 1000.0])))
    >>> float(np.round(np.degrees(bc.pixel_azimuth(p, pix)), 6))
    90.0
    """
    a = as_param_array(params)
    pixels = as_pixels(pixels)
    xI = (pixels[..., 0] - a[..., 4]) / a[..., 2]
    yI = (pixels[..., 1] - a[..., 5]) / a[..., 3]
    return np.arctan2(yI, xI)


def cone_distance(h, beta, points):
    """Signed distance (mm) of points from the cone surface, in their meridian plane.

    ``rho cos(beta) - (z + h) sin(beta)``: positive outside the cone (further
    from the axis than the cone), zero on it. Used to fit ``h`` and ``beta``
    to measured laser points (sequential method).

    Parameters
    ----------
    h : float or ndarray
    beta : float or ndarray
    points : array_like, shape (..., 3)

    Returns
    -------
    ndarray, shape (...)
    """
    points = as_finite_array(points, "points", last_dim=3)
    rho = np.hypot(points[..., 0], points[..., 1])
    return rho * np.cos(beta) - (points[..., 2] + h) * np.sin(beta)


def cone_points_geo(geo, q, *, jacobian=False):
    """Cone points above the scene positions ``q`` for a geometry of 7 or 11 numbers.

    Parameters
    ----------
    geo : ndarray, shape (..., 7) or (..., 11)
        ``theta`` (aligned cone) or ``(theta, pose)``.
    q : ndarray, shape (..., 2)
        Horizontal positions, mm.
    jacobian : bool

    Returns
    -------
    points : ndarray, shape (..., 3)
        mm.
    d_q : ndarray, shape (..., 3, 2)
        Only with ``jacobian=True``.
    d_geo : ndarray, shape (..., 3, 7) or (..., 3, 11)
        Only with ``jacobian=True``.
    """
    geo = np.asarray(geo, dtype=float)
    if geo.shape[-1] == 7:
        return cone_point_theta(geo, q, jacobian=jacobian)
    out = cone_point_pose_theta(geo[..., :7], geo[..., 7:], q, jacobian=jacobian)
    if not jacobian:
        return out
    pts, dq, dth, dpose = out
    return pts, dq, np.concatenate([dth, dpose], axis=-1)


def triangulate_geo(geo, pixels, *, jacobian=False):
    """Triangulate pixels for a geometry of 7 (aligned cone) or 11 numbers (internal).

    Parameters
    ----------
    geo : ndarray, shape (..., 7) or (..., 11)
        ``theta``, or ``(theta, pose)``.
    pixels : ndarray, shape (..., 2)
    jacobian : bool

    Returns
    -------
    points, valid[, d_pixels, d_geo]
        As :func:`triangulate_theta`, with ``d_geo``
        (..., 3, 7) or (..., 3, 11).
    """
    geo = np.asarray(geo, dtype=float)
    if geo.shape[-1] == 7:
        return triangulate_theta(geo, pixels, jacobian=jacobian)
    out = triangulate_pose_theta(geo[..., :7], geo[..., 7:], pixels, jacobian=jacobian)
    if not jacobian:
        return out
    pts, valid, dpix, dth, dpose = out
    return pts, valid, dpix, np.concatenate([dth, dpose], axis=-1)


def cone_height(theta, x, y, *, geometry=False):
    """The laser cone's height above the scene positions ``(x, y)`` and its slopes,
    elementwise (the hot path's form of :func:`cone_points_geo`).

    Parameters
    ----------
    theta : ndarray, shape (..., 7) or (..., 11)
        theta, or theta then the pose ``(tilt_x, tilt_y, offset_x, offset_y)``.
    x, y : ndarray, shape (..., N)
        mm.
    geometry : bool
        Also return the height's derivatives in the geometry.

    Returns
    -------
    z, dz_dx, dz_dy : ndarray, shape (..., N)
        mm and mm/mm; z NaN where the vertical line misses the lit nappe.
    dz_dgeo : list of ndarray, shape (..., N)
        Only with ``geometry=True``: d z / d h, d z / d beta, then (misaligned) d z / d
        tilt_x, tilt_y, offset_x, offset_y (implicit function theorem on the cone's
        equation ``f = T^2 q_z^2 - q_x^2 - q_y^2``, ``q`` in the cone's frame).
    """
    h, T = theta[..., 5, None], np.tan(theta[..., 6, None])
    if theta.shape[-1] == 7:
        rho = np.sqrt(x * x + y * y)
        out = (rho / T - h, x / (rho * T), y / (rho * T))
        sb = np.sin(theta[..., 6, None])
        return out + ([-np.ones_like(rho), -rho / (sb * sb)],) if geometry else out
    tx, ty, ox, oy = (theta[..., k, None] for k in range(7, 11))
    cx, sx, cy, sy = np.cos(tx), np.sin(tx), np.cos(ty), np.sin(ty)
    # R = Ry(ty) Rx(tx) = [[cy, sy sx, sy cx], [0, cx, -sx], [-sy, cy sx, cy cx]];
    # o = R^T (x - ox, y - oy, h), e = R^T e_z (docs/conventions.md)
    wx, wy = x - ox, y - oy
    o0, o1, o2 = cy * wx - sy * h, sy * sx * wx + cx * wy + cy * sx * h, \
        sy * cx * wx - sx * wy + cy * cx * h
    e0, e1, e2 = -sy, cy * sx, cy * cx
    T2 = T * T
    A2 = T2 * e2 * e2 - e0 * e0 - e1 * e1
    B = T2 * o2 * e2 - o0 * e0 - o1 * e1
    C = T2 * o2 * o2 - o0 * o0 - o1 * o1
    with np.errstate(divide="ignore", invalid="ignore"):
        sq = np.sqrt(np.where(B * B - A2 * C >= 0, B * B - A2 * C, np.nan))
        z = np.where(B <= 0, (-B + sq) / A2, C / (-B - sq))
        q0, q1, q2 = o0 + z * e0, o1 + z * e1, o2 + z * e2
        z = np.where((A2 > 0) & (q2 > 0), z, np.nan)
        g0, g1, g2 = -2 * q0, -2 * q1, 2 * T2 * q2                  # grad f in L
        c0 = cy * g0 + sy * sx * g1 + sy * cx * g2                  # R grad f: in C
        c1 = cx * g1 - sx * g2
        c2 = -sy * g0 + cy * sx * g1 + cy * cx * g2
        out = (z, -c0 / c2, -c1 / c2)
        if not geometry:
            return out
        wz = h + z                                                  # W = P - apex
        f_tx = wx * (sy * cx * g1 - sy * sx * g2) - wy * (sx * g1 + cx * g2) \
            + wz * (cy * cx * g1 - cy * sx * g2)                   # W . (dR/dtx) g
        f_ty = wx * (-sy * g0 + cy * sx * g1 + cy * cx * g2) \
            - wz * (cy * g0 + sy * sx * g1 + sy * cx * g2)
        f_b = 2 * T * (1 + T2) * q2 * q2
        return out + ([-np.ones_like(z), -f_b / c2, -f_tx / c2, -f_ty / c2, c0 / c2,
                       c1 / c2],)
