"""Synthetic rooms: laser points on walls, their pixels, and calibration patterns.

The room follows the paper's Fig. 6: ``n_walls`` vertical walls forming a
closed irregular polygon around the sensor; the laser cone meets the walls in
a closed curve sampled at ``n_points`` evenly spaced azimuths. For the
sequential method, four calibration planes enclose the sensor (a square of
half-side ``calib_distance_mm``) carrying a grid of pattern points and the
laser curve.

Approximate 3D points (the paper's Fig. 9 protocol) are what a user would
write down without measuring: see :func:`simulate_room` for the models.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from .._validation import check_positive, resolve_rng
from ..errors import InvalidTypeError, InvalidValueError
from ..sensor.camera import project_theta
from ..sensor.parameters import SensorParams, to_identifiable
from ..sensor.pose import LaserPose, cone_point_pose_theta
from .floorplan import FloorPlan

__all__ = ["Dataset", "CalibrationData", "simulate_room", "room_walls", "rotation_matrix",
           "APPROX_MODELS", "SIGMA_SCENE_FLOOR_MM"]

#: smallest sd (mm) written for an approximate coordinate by ``bayescal simulate``. The
#: paper's Fig. 9 protocol makes each coordinate's sd proportional to the coordinate, so a
#: point on an axis gets an sd of ~0 (3.3e-15 mm was written for x ~ 1e-13 mm), which no
#: measurement has and which makes each point's whitened design singular. 1 mm is below
#: every other sd in these rooms (5 % of a 1000 mm range is 50 mm; at 5 % the floor
#: touches only coordinates within 20 mm of zero) and is the floor the studies use.
SIGMA_SCENE_FLOOR_MM = 1.0

APPROX_MODELS = ("fig9", "wall", "gaussian")


def rotation_matrix(angles):
    """Rotation ``Rz(c) @ Ry(b) @ Rx(a)`` from angles ``(a, b, c)`` in radians, shape (..., 3)."""
    a, b, c = np.moveaxis(np.asarray(angles, dtype=float), -1, 0)
    ca, sa, cb, sb, cc, sc = np.cos(a), np.sin(a), np.cos(b), np.sin(b), np.cos(c), np.sin(c)
    R = np.empty(np.shape(a) + (3, 3))
    R[..., 0, 0] = cc * cb
    R[..., 0, 1] = cc * sb * sa - sc * ca
    R[..., 0, 2] = cc * sb * ca + sc * sa
    R[..., 1, 0] = sc * cb
    R[..., 1, 1] = sc * sb * sa + cc * ca
    R[..., 1, 2] = sc * sb * ca - cc * sa
    R[..., 2, 0] = -sb
    R[..., 2, 1] = cb * sa
    R[..., 2, 2] = cb * ca
    return R


@dataclass(frozen=True)
class CalibrationData:
    """What the sequential method needs: four calibration planes with patterns.

    World frame W is the frame the patterns are measured in; a point maps to
    the camera frame C as ``P_C = R @ P_W + t`` (``R = rotation_matrix(angles)``).

    Attributes
    ----------
    angles : ndarray, shape (3,)
        True rotation angles (rad) of the pose W -> C.
    translation : ndarray, shape (3,)
        True translation (mm) of the pose W -> C.
    grid_points_true : ndarray, shape (M, 3)
        Pattern points in W, mm.
    grid_points : ndarray, shape (M, 3)
        Pattern points as measured/approximated (what the method is given), mm.
    grid_pixels : ndarray, shape (M, 2)
        Their noisy pixels.
    grid_plane : ndarray of int, shape (M,)
        Index (0-3) of the plane each pattern point lies on.
    laser_pixels : ndarray, shape (K, 2)
        Noisy pixels of the laser curve on the calibration planes.
    laser_points_true : ndarray, shape (K, 3)
        True 3D laser points on the calibration planes, in C, mm.
    laser_plane : ndarray of int, shape (K,)
        Index of the plane each laser pixel falls on.

    Examples
    --------
    >>> import bayescal as bc
    >>> cal = bc.simulate_room(range_mm=1000, n_points=50, sigma_px=0.2, rng=0).calibration
    >>> cal.grid_pixels.shape[-1], cal.laser_pixels.shape[-1]
    (2, 2)
    """

    angles: np.ndarray
    translation: np.ndarray
    grid_points_true: np.ndarray
    grid_points: np.ndarray
    grid_pixels: np.ndarray
    grid_plane: np.ndarray
    laser_pixels: np.ndarray
    laser_points_true: np.ndarray
    laser_plane: np.ndarray


@dataclass(frozen=True)
class Dataset:
    """A simulated room: laser pixels, true and approximate 3D points, calibration data.

    Attributes
    ----------
    params : SensorParams
        True sensor parameters.
    pixels : ndarray, shape (N, 2)
        Noisy laser pixels (px).
    pixels_true : ndarray, shape (N, 2)
        Noise-free laser pixels (px).
    points : ndarray, shape (N, 3)
        True laser points in frame C (mm).
    approx_points : ndarray, shape (N, 3)
        Approximate laser points given to the calibrations (mm).
    sigma_scene : ndarray, shape (N, 3)
        Standard deviation (mm) of ``approx_points - points`` under the chosen
        approximation model, per point and axis; ``inf`` where the axis carries
        no independent information (z in the ``fig9`` and ``wall`` models, which
        derive it from x and y).
    walls : ndarray, shape (n_walls, 2, 2)
        Wall segments: horizontal end points ``(x, y)`` in mm.
    calibration : CalibrationData
    sigma_px, sigma_3d, approx_error, range_mm : float
        Settings used.
    approx_model : str
    floor_plan : FloorPlan or None
        The room's walls measured roughly: each wall's distance off by one
        draw of ``distance_sd = max(approx_error, 0.001) * d_k`` (for the
        ``"wall"`` model: the very errors of the approximate points, the same
        rough measurement), each orientation off by one draw of
        ``plan_angle_sd``; those sds are the plan's.
    laser : LaserPose
        The true pose of the laser cone (zero: the paper's aligned cone).

    Examples
    --------
    >>> import bayescal as bc
    >>> ds = bc.simulate_room(range_mm=1000, n_points=50, sigma_px=0.2, rng=0)
    >>> ds.pixels.shape, ds.points.shape, ds.n_points
    ((50, 2), (50, 3), 50)
    """

    params: SensorParams
    pixels: np.ndarray
    pixels_true: np.ndarray
    points: np.ndarray
    approx_points: np.ndarray
    sigma_scene: np.ndarray
    walls: np.ndarray
    calibration: CalibrationData
    sigma_px: float
    sigma_3d: float
    approx_error: float
    range_mm: float
    approx_model: str
    nominal: SensorParams = field(default_factory=SensorParams.paper)
    floor_plan: FloorPlan | None = None
    laser: LaserPose = field(default_factory=LaserPose)

    @property
    def n_points(self):
        """Number of laser points N."""
        return self.points.shape[0]


def room_walls(range_mm, n_walls=7):
    """Horizontal wall segments of the default irregular room.

    The vertices of an irregular convex-ish polygon lie at distances between
    0.7 and 1.0 times ``range_mm`` from the sensor axis. The geometry is fixed
    (no randomness) so that noise replications share one scene.

    Returns
    -------
    ndarray, shape (n_walls, 2, 2)

    Examples
    --------
    >>> import bayescal as bc
    >>> bc.room_walls(1000).shape                # 7 walls, each two (x, y) end points
    (7, 2, 2)
    """
    range_mm = check_positive(range_mm, "range_mm")
    if int(n_walls) != n_walls or n_walls < 3:
        raise InvalidValueError(f"n_walls must be an integer >= 3, got {n_walls!r}")
    n_walls = int(n_walls)
    k = np.arange(n_walls)
    ang = 2 * np.pi * k / n_walls + 0.25 * np.sin(2.7 * k + 0.4) * (np.pi / n_walls)
    rad = range_mm * (0.85 + 0.15 * np.cos(2.3 * k + 1.0))
    verts = np.stack([rad * np.cos(ang), rad * np.sin(ang)], axis=-1)
    return np.stack([verts, np.roll(verts, -1, axis=0)], axis=1)


def _ray_polygon_distance(azimuth, walls):
    """Horizontal distance from the axis along ``azimuth`` to the first wall hit."""
    d = np.stack([np.cos(azimuth), np.sin(azimuth)], axis=-1)[:, None, :]   # (N,1,2)
    a, b = walls[None, :, 0, :], walls[None, :, 1, :]                          # (1,W,2)
    e = b - a
    # Solve t d = a + s e  ->  [d, -e] [t, s]^T = a
    det = d[..., 0] * (-e[..., 1]) - d[..., 1] * (-e[..., 0])
    with np.errstate(divide="ignore", invalid="ignore"):
        t = (a[..., 0] * (-e[..., 1]) - a[..., 1] * (-e[..., 0])) / det
        s = (d[..., 0] * a[..., 1] - d[..., 1] * a[..., 0]) / det
    ok = (t > 0) & (s >= 0) & (s <= 1)
    t = np.where(ok, t, np.inf)
    return t.min(axis=1), t.argmin(axis=1)


def _cone_z(rho, params):
    return rho / np.tan(params.beta) - params.h


def _calibration(params, *, calib_distance, sigma_px, sigma_3d, approx_error,
                 n_grid, n_laser, rng, laser=None):
    """Four planes x = +-d, y = +-d (in W) with grid points and the laser curve."""
    angles = np.array([0.01, -0.015, 0.02])
    translation = np.array([5.0, -8.0, 12.0])
    R = rotation_matrix(angles)
    theta = to_identifiable(params.to_array())
    d = calib_distance
    s = np.linspace(-0.8 * d, 0.8 * d, n_grid)
    zs = np.linspace(-0.3 * d, 1.0 * d, max(n_grid - 2, 3))
    S, Z = np.meshgrid(s, zs, indexing="ij")
    grids, planes_idx = [], []
    for i, (axis, sign) in enumerate([(0, 1), (1, 1), (0, -1), (1, -1)]):
        P = np.zeros(S.shape + (3,))
        P[..., axis] = sign * d
        P[..., 1 - axis] = S
        P[..., 2] = Z
        grids.append(P.reshape(-1, 3))
        planes_idx.append(np.full(S.size, i))
    grid_w = np.concatenate(grids)
    grid_plane = np.concatenate(planes_idx)
    grid_c = grid_w @ R.T + translation
    grid_pix, _ = project_theta(theta, grid_c)
    grid_pix = grid_pix + rng.normal(0.0, sigma_px, grid_pix.shape)
    grid_meas = (grid_w + rng.normal(0.0, 1.0, grid_w.shape) * approx_error * np.abs(grid_w)
                 + rng.normal(0.0, sigma_3d, grid_w.shape))
    # laser curve on the four planes: intersect cone (in C) with the planes (from W)
    az = np.linspace(0, 2 * np.pi, n_laser, endpoint=False) + 0.5 * np.pi / n_laser
    normals_w = np.array([[1, 0, 0], [0, 1, 0], [-1, 0, 0], [0, -1, 0]], float)
    normals_c = normals_w @ R.T
    offs_c = -d - normals_c @ translation          # plane n_c . P = d + n_c . t  ->  n.P + off = 0
    cone_dir = np.stack([np.sin(params.beta) * np.cos(az), np.sin(params.beta) * np.sin(az),
                         np.full_like(az, np.cos(params.beta))], axis=-1)
    apex = np.array([0.0, 0.0, -params.h])
    if laser is not None and not laser.is_aligned:
        cone_dir = cone_dir @ laser.rotation.T
        apex = np.array([laser.offset_x, laser.offset_y, -params.h])
    # ray apex + t dir meets plane n.P + off = 0 at t = -(n.apex + off) / n.dir
    with np.errstate(divide="ignore"):
        tt = -(normals_c @ apex + offs_c)[None, :] / (cone_dir @ normals_c.T)
    tt = np.where(tt > 0, tt, np.inf)
    laser_plane = tt.argmin(axis=1)
    laser_c = apex + tt.min(axis=1)[:, None] * cone_dir
    laser_pix, _ = project_theta(theta, laser_c)
    laser_pix = laser_pix + rng.normal(0.0, sigma_px, laser_pix.shape)
    return CalibrationData(angles=angles, translation=translation, grid_points_true=grid_w,
                           grid_points=grid_meas, grid_pixels=grid_pix, grid_plane=grid_plane,
                           laser_pixels=laser_pix, laser_points_true=laser_c,
                           laser_plane=laser_plane)


def simulate_room(params=None, *, range_mm, n_points=580, n_walls=7, sigma_px=0.5,
                  approx_error=0.0, sigma_3d=0.0, approx_model="fig9", nominal=None,
                  calib_distance_mm=None, n_grid=7, n_calib_laser=80, plan_angle_sd=0.01,
                  tilt=(0.0, 0.0), offset=(0.0, 0.0), rng=None):
    """Simulate the paper's room: laser points, their pixels and approximate 3D points.

    Parameters
    ----------
    params : SensorParams, optional
        True sensor; default :meth:`SensorParams.paper`.
    range_mm : float
        Scene size: walls lie 0.7-1.0 x ``range_mm`` from the axis (paper:
        ~1000 mm small range, ~5000 mm large range).
    n_points : int, optional
        Number of laser points on the walls (paper: 580).
    n_walls : int, optional
        Number of walls (paper: 7).
    sigma_px : float, optional
        Standard deviation of the Gaussian pixel noise, px.
    approx_error : float, optional
        Relative error of the approximate 3D points (0.05 = 5 %), see
        ``approx_model``.
    sigma_3d : float, optional
        Standard deviation (mm) of the 3D-point measurement noise added to the
        approximate laser points and to the calibration pattern points.
    approx_model : {"fig9", "wall", "gaussian"}, optional
        How approximate points are made from the true ones:

        * ``"fig9"`` (the paper's Fig. 9 protocol): x and y each carry an
          independent relative error ``approx_error * |x|`` (resp. ``|y|``),
          z is computed from them with the *nominal* cone;
        * ``"wall"``: each wall's distance carries one relative error (the
          walls were measured roughly), points re-intersected with the
          shifted walls along the same azimuth, z from the nominal cone;
        * ``"gaussian"``: every coordinate carries an independent error
          ``approx_error * |coordinate|`` (the Bayesian model's own
          likelihood; used for coverage tests).
    nominal : SensorParams, optional
        Design values used for z in ``fig9``/``wall``; default the paper's.
    calib_distance_mm : float, optional
        Half-side of the square of calibration planes; default ``0.8 * range_mm``.
    n_grid : int, optional
        Pattern points per plane row (the grid is ``n_grid x (n_grid - 2)``).
    n_calib_laser : int, optional
        Laser points on the calibration planes.
    plan_angle_sd : float, optional
        sd (rad) of each wall's orientation in ``ds.floor_plan`` (default 0.01
        rad, about half a degree: a wall's direction read off a drawing or
        squared with a tape).
    tilt : (float, float), optional
        True tilt ``(tilt_x, tilt_y)`` of the laser cone's axis, rad
        (:class:`~bayescal.LaserPose`; ``docs/conventions.md``).
    offset : (float, float), optional
        True lateral offset ``(offset_x, offset_y)`` of the cone's apex, mm. With
        tilt and offset zero (the default) the dataset is the aligned one, the
        same for the same seed as without these arguments.
    rng : numpy.random.Generator, int or None
        Randomness; the same seed gives the same dataset.

    Returns
    -------
    Dataset

    Examples
    --------
    >>> import bayescal as bc
    >>> ds = bc.simulate_room(range_mm=5000, sigma_px=0.1, approx_error=0.05, rng=1)
    >>> ds.pixels.shape, ds.approx_points.shape
    ((580, 2), (580, 3))
    """
    params = SensorParams.paper() if params is None else params
    if not isinstance(params, SensorParams):
        raise InvalidTypeError(f"params must be a SensorParams, got {type(params).__name__}")
    nominal = SensorParams.paper() if nominal is None else nominal
    range_mm = check_positive(range_mm, "range_mm")
    if (isinstance(n_points, bool) or not isinstance(n_points, (int, np.integer, float))
            or int(n_points) != n_points or n_points < 1):
        raise InvalidValueError(f"n_points must be a positive integer, got {n_points!r}")
    n_points = int(n_points)
    sigma_px, sigma_3d, approx_error = (check_positive(v, k, allow_zero=True) for v, k in (
        (sigma_px, "sigma_px"), (sigma_3d, "sigma_3d"), (approx_error, "approx_error")))
    if approx_model not in APPROX_MODELS:
        raise InvalidValueError(
            f"approx_model must be one of {APPROX_MODELS}, got {approx_model!r}")
    calib_distance = 0.8 * range_mm if calib_distance_mm is None else \
        check_positive(calib_distance_mm, "calib_distance_mm")
    plan_angle_sd = check_positive(plan_angle_sd, "plan_angle_sd")
    laser = _pose_from(tilt, offset)
    ss = np.random.SeedSequence(resolve_rng(rng).integers(2**63))
    rng_pix, rng_approx, rng_cal = (np.random.default_rng(s) for s in ss.spawn(3))
    rng_plan = np.random.default_rng(ss.spawn(1)[0])    # 4th child: earlier streams unchanged
    walls = room_walls(range_mm, n_walls)
    az = np.linspace(0, 2 * np.pi, n_points, endpoint=False) + np.pi / n_points
    rho, wall_idx = _ray_polygon_distance(az, walls)
    xy = rho[:, None] * np.stack([np.cos(az), np.sin(az)], axis=-1)
    theta = to_identifiable(params.to_array())
    points = _room_points(xy, rho, params, theta, laser)
    pixels_true, _ = project_theta(theta, points)
    pixels = pixels_true + rng_pix.normal(0.0, sigma_px, pixels_true.shape)

    eps = rng_approx.normal(0.0, 1.0, (n_points, 3))
    sigma_scene = np.empty((n_points, 3))
    if approx_model == "gaussian":
        sigma_scene[:] = approx_error * np.abs(points)
        approx = points + eps * sigma_scene
    else:
        if approx_model == "fig9":
            sigma_scene[:, :2] = approx_error * np.abs(xy)
            axy = xy + eps[:, :2] * sigma_scene[:, :2]
        else:
            wall_eps = rng_approx.normal(0.0, approx_error, len(walls))
            plan_eps = wall_eps
            axy = xy * (1.0 + wall_eps[wall_idx])[:, None]
            sigma_scene[:, :2] = approx_error * np.abs(xy)
        sigma_scene[:, 2] = np.inf
        approx = np.column_stack([axy, _cone_z(np.hypot(axy[:, 0], axy[:, 1]), nominal)])
    approx = approx + rng_approx.normal(0.0, sigma_3d, approx.shape)
    if sigma_3d > 0:
        sigma_scene = np.sqrt(sigma_scene**2 + sigma_3d**2)

    floor_plan = _rough_plan(walls, approx_error, plan_angle_sd, rng_plan,
                             plan_eps if approx_model == "wall" else None)
    calib = _calibration(params, calib_distance=calib_distance, sigma_px=sigma_px,
                         sigma_3d=sigma_3d, approx_error=approx_error, n_grid=int(n_grid),
                         n_laser=int(n_calib_laser), rng=rng_cal, laser=laser)
    return Dataset(params=params, pixels=pixels, pixels_true=pixels_true, points=points,
                   approx_points=approx, sigma_scene=sigma_scene, walls=walls, calibration=calib,
                   sigma_px=sigma_px, sigma_3d=sigma_3d, approx_error=approx_error,
                   range_mm=range_mm, approx_model=approx_model, nominal=nominal,
                   floor_plan=floor_plan, laser=laser)


def _room_points(xy, rho, params, theta, laser):
    """Points of the (possibly tilted) cone above the wall positions ``xy``, (N, 3) mm."""
    if laser.is_aligned:
        return np.column_stack([xy, _cone_z(rho, params)])
    points = cone_point_pose_theta(theta, laser.to_array(), xy)
    if not np.all(np.isfinite(points)):
        raise InvalidValueError(f"laser pose {laser}: the tilted laser cone does not reach every "
                                "wall of this room (its rays pass above it)")
    return points


def _pose_from(tilt, offset):
    """``tilt`` (rad) and ``offset`` (mm) pairs as a :class:`LaserPose`, checked."""
    pairs = {}
    for name, value in (("tilt", tilt), ("offset", offset)):
        try:
            a = np.asarray(value, dtype=float)
        except (TypeError, ValueError):
            raise InvalidTypeError(f"{name} must be a pair of numbers, got {value!r}") from None
        if a.shape != (2,) or not np.all(np.isfinite(a)):
            raise InvalidValueError(f"{name} must be a finite pair (x, y), got {value!r}")
        pairs[name] = a
    if np.any(np.abs(pairs["tilt"]) >= np.pi / 4):
        raise InvalidValueError(f"tilt must be below pi/4 rad in each component, got {tilt!r}")
    return LaserPose(*pairs["tilt"], *pairs["offset"])


def _rough_plan(walls, approx_error, angle_sd, rng, rel_eps=None):
    """The room's plan measured roughly (see :class:`Dataset`), a FloorPlan."""
    true = FloorPlan(walls, distance_sd=1.0, angle_sd=1.0)
    rel = max(approx_error, 1e-3)
    # at a shallow corner a few % on the distances can move the corner past a whole wall;
    # such a draw is no plan anyone would draw: redraw it (None if it keeps happening)
    for _ in range(100):
        eps = rng.normal(0.0, rel, len(walls)) if rel_eps is None else rel_eps
        d = true.distances * (1.0 + eps)
        a = true.angles + rng.normal(0.0, angle_sd, len(walls))
        try:
            return FloorPlan.from_lines(d, a, distance_sd=rel * true.distances,
                                        angle_sd=angle_sd)
        except ValueError:
            continue
    return None
