"""A rough floor plan: vertical walls around the sensor, each with an uncertain position.

A user who knows a room from a tape or a drawing writes its walls as segments
``(W, 2, 2)`` of end points ``(x, y)`` in mm, frame C (origin on the sensor
axis), counterclockwise around the sensor. Wall ``k`` is the vertical plane::

    n(a_k) . (x, y) = d_k,     n(a) = (cos a, sin a)

with ``d_k > 0`` its perpendicular distance from the axis and ``a_k`` the
azimuth of its outward normal. The plan gives the prior of each wall,
``d_k ~ N(plan d_k, distance_sd_k)`` and ``a_k ~ N(plan a_k, angle_sd_k)``.

The plan is a list of *planar surfaces*, each with its own small parameter
vector (a wall: ``(d, a)``), nominal values and standard deviations; the
likelihood (:mod:`bayescal.likelihood.floorplan`) sees only the flattened parameter vector
and, per surface kind, the range function ``rho(t)`` of the laser point at
azimuth ``t``. A horizontal ceiling ``z = c`` would be one more kind with one
parameter and ``rho(t) = tan(beta) (c + h)`` (``docs/floorplan.md``).

Geometry helpers here are vectorized over leading axes (walkers) and carry
analytic derivatives (tested against finite differences).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .._validation import as_finite_array
from ..errors import InvalidTypeError, InvalidValueError
from ..sensor.laser import cone_height

__all__ = ["FloorPlan", "Wall", "wall_range", "corner_points", "corner_azimuths",
           "plan_point", "wrap_angle"]


def wrap_angle(x):
    """Angles wrapped to ``[-pi, pi)``, same shape."""
    return (np.asarray(x) + np.pi) % (2 * np.pi) - np.pi


@dataclass(frozen=True)
class Wall:
    """One vertical wall: the plane ``cos(a) x + sin(a) y = d`` with its prior.

    Attributes
    ----------
    distance : float
        ``d``, perpendicular distance from the sensor axis, mm (> 0).
    angle : float
        ``a``, azimuth of the outward normal, rad.
    distance_sd : float
        Prior sd of ``d``, mm.
    angle_sd : float
        Prior sd of ``a``, rad.
    segment : ndarray, shape (2, 2)
        The end points as given, mm (used for plots and the corner check only).
    """

    distance: float
    angle: float
    distance_sd: float
    angle_sd: float
    segment: np.ndarray

    kind = "wall"
    param_names = ("d", "a")

    @property
    def nominal(self):
        """Plan values of the parameters, shape (2,): ``(d, a)``."""
        return np.array([self.distance, self.angle])

    @property
    def sd(self):
        """Prior sds of the parameters, shape (2,)."""
        return np.array([self.distance_sd, self.angle_sd])


def _per_wall_sd(value, name, n):
    try:
        s = np.asarray(value, dtype=float)
    except (TypeError, ValueError):
        raise InvalidTypeError(f"{name} must be a float or an array of shape ({n},), got "
                               f"{type(value).__name__}") from None
    if s.ndim > 1 or (s.ndim == 1 and s.shape != (n,)):
        raise InvalidValueError(f"{name} must be a float or have shape ({n},) (one per wall), "
                                f"got shape {s.shape}")
    s = np.broadcast_to(s, (n,)).astype(float)
    bad = ~(np.isfinite(s) & (s > 0))
    if np.any(bad):
        k = int(np.argmax(bad))
        raise InvalidValueError(f"{name} must be finite and positive for every wall, got {s[k]!r} "
                                f"for wall {k}")
    return s


class FloorPlan:
    """A rough floor plan: closed polygon of vertical walls around the sensor.

    Parameters
    ----------
    walls : array_like, shape (W, 2, 2)
        Wall segments ``[[x0, y0], [x1, y1]]`` in mm, frame C, in
        counterclockwise order around the sensor axis; wall ``k`` ends where
        wall ``k + 1`` starts (the last one where the first starts).
    distance_sd : float or array_like, shape (W,)
        Prior sd of each wall's perpendicular distance ``d_k``, mm.
    angle_sd : float or array_like, shape (W,)
        Prior sd of each wall's orientation ``a_k``, rad.
    corner_tol : float, optional
        Largest gap (mm) allowed between the end of one wall and the start of
        the next; default 5 % of the median wall length (plans are rough; the
        model uses each wall's *line*, corners are the lines' intersections).

    Attributes
    ----------
    surfaces : tuple of Wall
        The planar surfaces, in order.
    n_walls : int
    distances, angles : ndarray, shape (W,)
        Plan values ``d_k`` (mm) and ``a_k`` (rad).
    param_nominal, param_sd : ndarray, shape (2W,)
        Flattened ``(d_0, a_0, d_1, a_1, ...)`` and their prior sds.
    param_names : tuple of str
        ``("d_0", "a_0", "d_1", ...)``.

    Examples
    --------
    >>> import bayescal as bc
    >>> plan = bc.FloorPlan(bc.room_walls(1000), distance_sd=20.0, angle_sd=0.01)
    >>> plan.n_walls, plan.param_nominal.shape
    (7, (14,))
    """

    def __init__(self, walls, *, distance_sd, angle_sd, corner_tol=None):
        w = as_finite_array(walls, "walls")
        if w.ndim != 3 or w.shape[1:] != (2, 2) or w.shape[0] < 3:
            raise InvalidValueError(f"walls must have shape (W, 2, 2) with W >= 3 (segments of end "
                                    f"points (x, y)), got shape {w.shape}")
        n = w.shape[0]
        lengths = np.linalg.norm(w[:, 1] - w[:, 0], axis=-1)
        if np.any(lengths <= 0):
            k = int(np.argmin(lengths))
            raise InvalidValueError(f"walls: wall {k} has zero length (end points {w[k].tolist()})")
        tol = 0.05 * float(np.median(lengths)) if corner_tol is None else float(corner_tol)
        if not (np.isfinite(tol) and tol >= 0):
            raise InvalidValueError(
                f"corner_tol must be a finite non-negative number, got {corner_tol!r}")
        gaps = np.linalg.norm(w[:, 1] - np.roll(w[:, 0], -1, axis=0), axis=-1)
        if np.any(gaps > tol):
            k = int(np.argmax(gaps))
            raise InvalidValueError(
                f"walls: the plan must be a closed polygon; wall {k} ends at "
                f"{w[k, 1].tolist()} but wall {(k + 1) % n} starts at "
                f"{w[(k + 1) % n, 0].tolist()} ({gaps[k]:.4g} mm apart, corner_tol "
                f"{tol:.4g} mm)")
        # around the sensor: each wall spans a positive azimuth interval seen from the
        # axis (counterclockwise) and the spans add up to one turn (star-shaped polygon)
        az0 = np.arctan2(w[:, 0, 1], w[:, 0, 0])
        az1 = np.arctan2(w[:, 1, 1], w[:, 1, 0])
        span = (az1 - az0) % (2 * np.pi)
        jump = wrap_angle(np.roll(az0, -1) - az1)          # small gaps between rough corners
        cross = w[:, 0, 0] * w[:, 1, 1] - w[:, 0, 1] * w[:, 1, 0]
        if np.any(cross <= 0) or abs(span.sum() + jump.sum() - 2 * np.pi) > 1e-6:
            k = int(np.argmin(cross))
            raise InvalidValueError(
                f"walls must enclose the sensor axis (origin) and be given "
                f"counterclockwise, each wall seen from the axis at increasing "
                f"azimuth; wall {k} ({w[k].tolist()}) is not (reverse the order "
                f"of a clockwise plan)")
        e = w[:, 1] - w[:, 0]
        normal = np.stack([e[:, 1], -e[:, 0]], axis=-1) / lengths[:, None]   # outward (CCW)
        self.distances = np.einsum("ki,ki->k", normal, w[:, 0])
        self.angles = np.arctan2(normal[:, 1], normal[:, 0])
        self.distance_sd = _per_wall_sd(distance_sd, "distance_sd", n)
        self.angle_sd = _per_wall_sd(angle_sd, "angle_sd", n)
        self.segments = w
        self.n_walls = n
        self.surfaces = tuple(Wall(float(self.distances[k]), float(self.angles[k]),
                                   float(self.distance_sd[k]), float(self.angle_sd[k]),
                                   w[k].copy()) for k in range(n))

    @classmethod
    def from_lines(cls, distances, angles, *, distance_sd, angle_sd):
        """Build a plan from wall lines ``(d_k, a_k)`` in counterclockwise order.

        The segments are the consecutive lines' intersections (the corners).

        Parameters
        ----------
        distances : array_like, shape (W,)
            mm, positive.
        angles : array_like, shape (W,)
            rad.
        distance_sd, angle_sd : float or array_like, shape (W,)
        """
        d = as_finite_array(distances, "distances")
        a = as_finite_array(angles, "angles")
        if d.ndim != 1 or a.shape != d.shape:
            raise InvalidValueError(
                f"distances and angles must both have shape (W,), got {d.shape} "
                f"and {a.shape}")
        if np.any(d <= 0):
            raise InvalidValueError(f"distances must be positive, got min {d.min()!r}")
        c = corner_points(d, a)                             # corner k: walls k and k+1
        seg = np.stack([np.roll(c, 1, axis=0), c], axis=1)
        return cls(seg, distance_sd=distance_sd, angle_sd=angle_sd)

    @property
    def walls(self):
        """The wall segments as given, shape (W, 2, 2), mm (same as :attr:`segments`)."""
        return self.segments

    @property
    def param_nominal(self):
        return np.concatenate([s.nominal for s in self.surfaces])

    @property
    def param_sd(self):
        return np.concatenate([s.sd for s in self.surfaces])

    @property
    def param_names(self):
        return tuple(f"{p}_{k}" for k, s in enumerate(self.surfaces) for p in s.param_names)

    def to_arrays(self):
        """The plan as plain arrays (for ``.npz`` files): ``segments`` (W, 2, 2),
        ``distance_sd`` (W,), ``angle_sd`` (W,), ``corner_tol`` ()."""
        gaps = np.linalg.norm(self.segments[:, 1] - np.roll(self.segments[:, 0], -1, axis=0),
                              axis=-1)
        return {"segments": self.segments.copy(), "distance_sd": self.distance_sd.copy(),
                "angle_sd": self.angle_sd.copy(), "corner_tol": np.array(float(gaps.max()))}

    @classmethod
    def from_arrays(cls, arrays):
        """Inverse of :meth:`to_arrays` (``arrays``: a mapping with its keys)."""
        try:
            return cls(arrays["segments"], distance_sd=arrays["distance_sd"],
                       angle_sd=arrays["angle_sd"], corner_tol=float(arrays["corner_tol"]))
        except KeyError as e:
            raise InvalidValueError(f"floor-plan arrays lack the key {e.args[0]!r} (need segments, "
                                    f"distance_sd, angle_sd, corner_tol)") from None

    def corner_azimuths(self):
        """Azimuths (rad) of the plan's corners, shape (W,): corner k joins walls k and k+1."""
        return corner_azimuths(self.distances, self.angles)

    def __repr__(self):
        return (f"FloorPlan({self.n_walls} walls, d = {np.round(self.distances, 1).tolist()} mm, "
                f"distance_sd = {np.round(self.distance_sd, 3).tolist()} mm, "
                f"angle_sd = {np.round(self.angle_sd, 4).tolist()} rad)")


def corner_points(d, a):
    """Intersection of wall lines k and k+1 (cyclic), shape (..., W, 2), mm.

    Parameters
    ----------
    d, a : ndarray, shape (..., W)
    """
    d2, a2 = np.roll(d, -1, axis=-1), np.roll(a, -1, axis=-1)
    det = np.sin(a2 - a)
    with np.errstate(divide="ignore", invalid="ignore"):
        x = (d * np.sin(a2) - d2 * np.sin(a)) / det
        y = (d2 * np.cos(a) - d * np.cos(a2)) / det
    return np.stack([x, y], axis=-1)


def corner_azimuths(d, a):
    """Azimuth (rad) of the intersection of wall lines k and k+1, shape (..., W)."""
    c = corner_points(d, a)
    return np.arctan2(c[..., 1], c[..., 0])


def wall_range(t, d, a):
    """Horizontal range of wall ``(d, a)`` along azimuth ``t`` and its derivatives.

    ``rho = d / cos(t - a)``; NaN where ``cos(t - a) <= 0`` (the ray misses).

    Returns
    -------
    rho, drho_dt, drho_dd, drho_da : ndarray
        Broadcast shape of the inputs; mm, mm/rad, 1, mm/rad.
    """
    c = np.cos(t - a)
    with np.errstate(divide="ignore", invalid="ignore"):
        ic = np.where(c > 0, 1.0 / c, np.nan)
    rho = d * ic
    tn = np.tan(t - a)
    return rho, rho * tn, ic, -rho * tn


def plan_point(theta, t, d, a, *, jacobian=False):
    """Laser point at azimuth ``t`` on wall ``(d, a)``: on the wall and on the cone.

    ``P = (rho cos t, rho sin t, z)`` with ``rho = d / cos(t - a)`` and ``z = rho /
    tan(beta) - h`` (aligned cone), or with the laser pose, ``z`` the tilted and offset
    cone's height above ``(x, y)`` (:func:`~bayescal.sensor.laser.cone_height`).

    Parameters
    ----------
    theta : ndarray, shape (..., 7) or (..., 11)
        Identifiable parameters (only ``h`` and ``beta`` enter), then optionally the
        laser pose ``(tilt_x, tilt_y, offset_x, offset_y)`` (rad, rad, mm, mm).
    t, d, a : ndarray, shape (...)
        Azimuth (rad), wall distance (mm) and normal azimuth (rad).
    jacobian : bool

    Returns
    -------
    P : ndarray, shape (..., 3)
        mm; NaN where the ray at ``t`` misses the wall (or the point the cone).
    dP_dt : ndarray, shape (..., 3)
        Only with ``jacobian=True``.
    dP_dtheta : ndarray, shape (..., 3, 7) or (..., 3, 11)
        Only with ``jacobian=True`` (``h``, ``beta`` and the pose's columns).
    dP_dwall : ndarray, shape (..., 3, 2)
        Only with ``jacobian=True``: d P / d (d, a).
    """
    theta = np.asarray(theta, dtype=float)
    if theta.shape[-1] == 11:
        return _plan_point_pose(theta, t, d, a, jacobian)
    h, beta = theta[..., 5], theta[..., 6]
    rho, r_t, r_d, r_a = wall_range(t, d, a)
    ct, st, it = np.cos(t), np.sin(t), 1.0 / np.tan(beta)
    P = np.stack(np.broadcast_arrays(rho * ct, rho * st, rho * it - h), axis=-1)
    if not jacobian:
        return P
    g = np.stack(np.broadcast_arrays(ct, st, it + 0 * rho), axis=-1)       # dP / drho
    dP_dt = g * r_t[..., None]
    dP_dt[..., 0] -= rho * st
    dP_dt[..., 1] += rho * ct
    dth = np.zeros(P.shape[:-1] + (3, 7))
    dth[..., 2, 5] = -1.0
    dth[..., 2, 6] = -rho / np.sin(beta) ** 2
    dwall = np.stack([g * r_d[..., None], g * r_a[..., None]], axis=-1)
    return P, dP_dt, dth, dwall


def _plan_point_pose(theta, t, d, a, jacobian):
    """:func:`plan_point` on a tilted and offset cone (``theta`` (..., 11)): ``(x, y)`` from
    the wall, ``z`` and its slopes from :func:`~bayescal.sensor.laser.cone_height` (a
    trailing axis of length 1 lets theta's leading axes broadcast with ``t``'s)."""
    rho, r_t, r_d, r_a = wall_range(t, d, a)
    ct, st = np.cos(t), np.sin(t)
    x, y = rho * ct, rho * st
    out = cone_height(theta, x[..., None], y[..., None], geometry=jacobian)
    z, zx, zy = (o[..., 0] for o in out[:3])
    P = np.stack(np.broadcast_arrays(x, y, z), axis=-1)
    if not jacobian:
        return P
    gx, gy = np.broadcast_arrays(ct, st, z)[:2]

    def lift(dx, dy):                       # (dx, dy) of (x, y) -> (dx, dy, dz) on the cone
        return np.stack(np.broadcast_arrays(dx, dy, zx * dx + zy * dy), axis=-1)

    dP_dt = lift(r_t * ct - y, r_t * st + x)
    dth = np.zeros(P.shape[:-1] + (3, 11))
    for col, dz in zip((5, 6, 7, 8, 9, 10), out[3], strict=True):
        dth[..., 2, col] = dz[..., 0]
    dwall = np.stack([lift(gx * r_d, gy * r_d), lift(gx * r_a, gy * r_a)], axis=-1)
    return P, dP_dt, dth, dwall
