"""A second generator of laser rooms, written apart from the package's own.

Written from the paper (eq. (1) projection, eq. (3) the cone) and ``docs/conventions.md``,
``docs/model.md``, ``docs/cli.md`` without reading ``bayescal/scene/simulate.py``. It exists
so that robustness rules tuned on the package's simulator can be checked on rooms it did
not make. Only :meth:`Room.to_dataset` and :meth:`Room.floor_plan` touch bayescal (its
public ``Dataset`` / ``FloorPlan`` constructors); the projection here is its own (the tests
check it against ``bc.project``).

How it differs from ``bc.simulate_room`` (as far as its docstring tells):

- rooms are irregular convex polygons of 3 or more walls (4-8 intended) whose *lines* lie
  0.5-1.0 x ``range_mm`` from the axis (perpendicular distance), with uneven angular gaps;
- laser points sit at i.i.d. uniform azimuths (no grid), rows in draw order (random along
  the ring) unless ``sort_azimuth=True``; points whose true or noisy pixel falls outside
  the image, or outside the projection domain, are redrawn;
- approximate points: ``"isotropic"`` adds N(0, approx_sd^2) mm to x, y and z;
  ``"relative"`` adds N(0, (approx_sd * |P|)^2) to each coordinate (sd proportional to the
  point's distance from the focus, not to each coordinate); ``z_known=False`` replaces z
  by the nominal cone's height at the approximate (x, y) and gives it sd ``inf``.

Use (tests in ``tests/scene`` import it as ``rooms2``; from other test folders
``from scene.rooms2 import make_room``)::

    room = make_room(0, range_mm=3000, n_points=300, n_walls=6, approx="relative",
                     approx_sd=0.03)
    ds = room.to_dataset()                 # bc.Dataset, calibration=None
    room.write_csv(tmp_path / "laser.csv")  # u, v, x, y, z (+ sigma_x, sigma_y, sigma_z)
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

import bayescal as bc
from bayescal.errors import InvalidValueError

__all__ = ["Room", "make_room", "project2", "random_walls", "wall_corners"]

#: Default ``approx_sd`` per model: mm for "isotropic", a fraction of |P| for "relative".
DEFAULT_APPROX_SD = {"isotropic": 20.0, "relative": 0.02}
#: Wall lines lie this many ``range_mm`` from the axis (perpendicular distance).
WALL_DISTANCE = (0.5, 1.0)
#: Shortest wall (fraction of range_mm) and farthest corner (multiple of range_mm) kept.
MIN_WALL, MAX_CORNER = 0.2, 2.5


def project2(params, points):
    """Eq. (1), written here: pixels of points in frame C and the domain mask.

    Parameters
    ----------
    params : SensorParams or array_like, shape (8,)
        ``(xi, phi, alpha_u, alpha_v, u0, v0, h, beta)``.
    points : ndarray, shape (N, 3)
        mm, frame C (z up).

    Returns
    -------
    pixels : ndarray, shape (N, 2)
        px; NaN where ``xi * |P| - z <= 0``.
    valid : ndarray of bool, shape (N,)
    """
    xi, phi, au, av, u0, v0 = _param_array(params)[:6]
    p = np.asarray(points, float)
    den = xi * np.sqrt(np.sum(p * p, axis=-1)) - p[..., 2]
    valid = den > 0
    den = np.where(valid, den, np.nan)
    u = au * (xi + phi) * p[..., 0] / den + u0
    v = av * (xi + phi) * p[..., 1] / den + v0
    return np.stack([u, v], axis=-1), valid


def wall_corners(dist, angle):
    """Corner ``k``: where wall line ``k`` meets line ``k + 1`` (the last meets the first).

    Parameters
    ----------
    dist, angle : ndarray, shape (W,)
        Each line ``{p : p . (cos a_k, sin a_k) = d_k}``: distance (mm) and normal (rad).

    Returns
    -------
    corners : ndarray, shape (W, 2)
        mm.
    walls : ndarray, shape (W, 2, 2)
        Wall ``k`` runs from corner ``k - 1`` to corner ``k`` (counterclockwise).
    """
    n = np.stack([np.cos(angle), np.sin(angle)], axis=-1)
    mat = np.stack([n, np.roll(n, -1, axis=0)], axis=1)
    rhs = np.stack([dist, np.roll(dist, -1)], axis=-1)
    corners = np.linalg.solve(mat, rhs[..., None])[..., 0]
    return corners, np.stack([np.roll(corners, 1, axis=0), corners], axis=1)


def random_walls(rng, range_mm, n_walls, *, max_tries=1000):
    """An irregular convex room around the axis.

    Normal angles advance by uneven gaps (``2 pi g / sum g``, ``g ~ U(0.6, 1.4)``) from a
    random start; distances ``d_k ~ U(0.5, 1.0) range_mm``. A draw is kept when every wall
    is longer than ``0.2 range_mm`` (each line is a real wall) and every corner lies within
    ``2.5 range_mm`` of the axis.

    Returns
    -------
    dist, angle : ndarray, shape (W,)
        Line distances (mm) and normal angles (rad, in ``(-pi, pi]``).
    walls : ndarray, shape (W, 2, 2)
        Wall end points ``(x, y)``, mm, counterclockwise.
    """
    if n_walls < 3:
        raise InvalidValueError(f"n_walls = {n_walls}; expected at least 3 (4-8 intended)")
    for _ in range(max_tries):
        g = rng.uniform(0.6, 1.4, n_walls)
        gaps = 2 * np.pi * g / g.sum()
        if gaps.max() >= 0.95 * np.pi:
            continue
        angle = rng.uniform(-np.pi, np.pi) + np.concatenate([[0.0], np.cumsum(gaps[:-1])])
        angle = np.angle(np.exp(1j * angle))
        dist = rng.uniform(*WALL_DISTANCE, n_walls) * range_mm
        corners, walls = wall_corners(dist, angle)
        tangent = np.stack([-np.sin(angle), np.cos(angle)], axis=-1)
        length = np.sum((walls[:, 1] - walls[:, 0]) * tangent, axis=-1)
        if length.min() > MIN_WALL * range_mm and \
                np.hypot(*corners.T).max() < MAX_CORNER * range_mm:
            return dist, angle, walls
    raise InvalidValueError(f"no room with {n_walls} walls found in {max_tries} draws")


def _wall_hits(dist, angle, azimuth):
    """Horizontal range (mm) and wall index where rays at ``azimuth`` (rad) leave the room."""
    c = np.cos(azimuth[:, None] - angle[None, :])
    with np.errstate(divide="ignore"):
        t = np.where(c > 1e-12, dist[None, :] / c, np.inf)
    k = np.argmin(t, axis=1)
    return t[np.arange(len(azimuth)), k], k


def cone_points(h, beta, rho, azimuth):
    """Eq. (3): the lit cone's point at horizontal range ``rho`` (mm) and ``azimuth``."""
    return np.stack([rho * np.cos(azimuth), rho * np.sin(azimuth),
                     rho / np.tan(beta) - h], axis=-1)


def _inside(pixels, image_size):
    w, h = image_size
    return (np.all(np.isfinite(pixels), axis=-1) & (pixels[:, 0] >= 0) & (pixels[:, 0] <= w - 1)
            & (pixels[:, 1] >= 0) & (pixels[:, 1] <= h - 1))


def _laser_rows(rng, dist, angle, params, n_points, sigma_px, image_size):
    """Draw azimuths until ``n_points`` rows have true and noisy pixels inside the image."""
    keep = []
    for _ in range(20):
        az = rng.uniform(-np.pi, np.pi, 2 * n_points)
        rho, wall = _wall_hits(dist, angle, az)
        pts = cone_points(params[6], params[7], rho, az)
        true, valid = project2(params, pts)
        noisy = true + rng.normal(0.0, sigma_px, true.shape)
        ok = valid & _inside(true, image_size) & _inside(noisy, image_size)
        keep.append((pts[ok], true[ok], noisy[ok], wall[ok]))
        if sum(len(k[0]) for k in keep) >= n_points:
            return [np.concatenate(parts)[:n_points] for parts in zip(*keep, strict=True)]
    raise InvalidValueError(
        f"params {np.round(params, 4).tolist()}: too few laser points of this room image "
        f"inside the {image_size[0]}x{image_size[1]} image and the projection domain")


def _approximate(rng, points, approx, approx_sd, z_known, nominal):
    """Approximate points (N, 3) mm and the sds (N, 3) mm of their errors."""
    if approx == "isotropic":
        sd = np.full(points.shape, float(approx_sd))
    elif approx == "relative":
        sd = approx_sd * np.repeat(np.linalg.norm(points, axis=1)[:, None], 3, axis=1)
    else:
        raise InvalidValueError(f"approx = {approx!r}; expected 'isotropic' or 'relative'")
    out = points + sd * rng.standard_normal(points.shape)
    if not z_known:
        out[:, 2] = np.hypot(out[:, 0], out[:, 1]) / np.tan(nominal[7]) - nominal[6]
        sd[:, 2] = np.inf
    return out, sd


@dataclass(frozen=True)
class Room:
    """One generated room and its laser data.

    Attributes
    ----------
    params, nominal : ndarray, shape (8,)
        True and nominal (design) sensor, order of ``bc.PARAM_NAMES``.
    pixels, pixels_true : ndarray, shape (N, 2)
        Noisy and noise-free laser pixels, px.
    points : ndarray, shape (N, 3)
        True laser points in frame C, mm (on the cone and on wall ``wall_index``).
    approx_points : ndarray, shape (N, 3)
        Approximate points given to a calibration, mm.
    sigma_px : float
        Pixel noise sd, px (each of u, v).
    sigma_scene : ndarray, shape (N, 3)
        True sds of ``approx_points - points``, mm; ``inf`` for z when ``z_known=False``.
    walls : ndarray, shape (W, 2, 2)
        Wall end points ``(x, y)``, mm, counterclockwise (wall k ends where k + 1 starts).
    wall_lines : ndarray, shape (W, 2)
        Each wall's line: ``(d_k, a_k)``, distance (mm) and normal angle (rad).
    wall_index : ndarray of int, shape (N,)
        The wall each laser point is on.
    range_mm : float
    image_size : (int, int)
        Width, height, px.
    approx : str
        "isotropic" or "relative".
    approx_sd : float
        mm ("isotropic") or fraction of |P| ("relative").
    z_known, sd_columns : bool
        z carries its own error (else from the nominal cone, sd inf); ``write_csv``
        writes the sd columns by default.
    """

    params: np.ndarray
    pixels: np.ndarray
    pixels_true: np.ndarray
    points: np.ndarray
    approx_points: np.ndarray
    sigma_px: float
    sigma_scene: np.ndarray
    walls: np.ndarray
    wall_lines: np.ndarray
    wall_index: np.ndarray
    range_mm: float
    nominal: np.ndarray
    image_size: tuple
    approx: str
    approx_sd: float
    z_known: bool
    sd_columns: bool

    @property
    def n_points(self):
        """Number of laser points N."""
        return len(self.pixels)

    def to_dataset(self, *, floor_plan=None):
        """The room as a ``bc.Dataset`` (``calibration=None``: no sequential-method data).

        ``sigma_3d`` is ``approx_sd`` for "isotropic" (else 0), ``approx_error`` is it for
        "relative" (else 0); ``approx_model`` is ``"rooms2-<approx>"`` (``"-zcone"`` added
        when z comes from the nominal cone).
        """
        iso = self.approx == "isotropic"
        return bc.Dataset(
            params=bc.SensorParams.from_array(self.params), pixels=self.pixels.copy(),
            pixels_true=self.pixels_true.copy(), points=self.points.copy(),
            approx_points=self.approx_points.copy(), sigma_scene=self.sigma_scene.copy(),
            walls=self.walls.copy(), calibration=None, sigma_px=float(self.sigma_px),
            sigma_3d=float(self.approx_sd) if iso else 0.0,
            approx_error=0.0 if iso else float(self.approx_sd), range_mm=float(self.range_mm),
            approx_model=f"rooms2-{self.approx}" + ("" if self.z_known else "-zcone"),
            nominal=bc.SensorParams.from_array(self.nominal), floor_plan=floor_plan)

    def floor_plan(self, rng, *, distance_sd, angle_sd):
        """A rough ``bc.FloorPlan``: each wall line moved by one draw of N(0, distance_sd^2)
        mm and turned by one of N(0, angle_sd^2) rad, corners re-intersected; the plan
        carries those sds."""
        rng = np.random.default_rng(rng)
        d, a = self.wall_lines.T
        w = len(d)
        _, walls = wall_corners(d + rng.normal(0, distance_sd, w), a + rng.normal(0, angle_sd, w))
        return bc.FloorPlan(walls, distance_sd=distance_sd, angle_sd=angle_sd)

    def write_csv(self, path, *, with_sd=None, with_sigma_px=False):
        """Write the CLI's laser CSV: ``# image_size: WxH``, then ``u, v, x, y, z``, the sd
        columns ``sigma_x, sigma_y, sigma_z`` (``inf`` = no information) when ``with_sd``
        (default ``self.sd_columns``) and ``sigma_px`` on every row when ``with_sigma_px``.
        Numbers are written with 17 significant digits (they read back exactly). Refuses to
        overwrite an existing file."""
        path = Path(path)
        if path.exists():
            raise FileExistsError(f"{path} exists; expected a new file")
        with_sd = self.sd_columns if with_sd is None else with_sd
        cols = [self.pixels, self.approx_points]
        names = ["u", "v", "x", "y", "z"]
        if with_sd:
            cols.append(self.sigma_scene)
            names += ["sigma_x", "sigma_y", "sigma_z"]
        if with_sigma_px:
            cols.append(np.full((self.n_points, 1), self.sigma_px))
            names.append("sigma_px")
        table = np.concatenate(cols, axis=1)
        lines = [f"# image_size: {self.image_size[0]}x{self.image_size[1]}", ",".join(names)]
        lines += [",".join(f"{x:.17g}" for x in row) for row in table]
        path.write_text("\n".join(lines) + "\n")
        return path


def make_room(rng=None, *, range_mm, n_points=300, n_walls=6, params=None, sigma_px=0.2,
              approx="isotropic", approx_sd=None, z_known=True, sd_columns=True,
              image_size=(800, 600), nominal=None, sort_azimuth=False):
    """Generate a room, its laser points, their pixels and approximate points.

    Parameters
    ----------
    rng : numpy.random.Generator, int or None
        The same seed gives the same room.
    range_mm : float
        Scene size, mm (1000-5000 intended): wall lines 0.5-1.0 x range_mm from the axis.
    n_points : int
        Laser points N (100-600 intended).
    n_walls : int
        Walls W (4-8 intended).
    params, nominal : SensorParams or array_like (8,), optional
        True sensor, and the design values used for z when ``z_known=False``; default both
        ``SensorParams.paper()``.
    sigma_px : float
        Gaussian pixel noise sd, px (> 0).
    approx : {"isotropic", "relative"}
        Error model of the approximate points (module docstring).
    approx_sd : float, optional
        mm for "isotropic" (default 20), fraction of |P| for "relative" (default 0.02).
    z_known, sd_columns : bool
        See :class:`Room`.
    image_size : (int, int)
        Width, height, px; every true and noisy pixel lies in ``[0, W-1] x [0, H-1]``.
    sort_azimuth : bool
        Order rows by azimuth (like an extracted ring) instead of draw order.

    Returns
    -------
    Room
    """
    rng = np.random.default_rng(rng)
    params = _param_array(params)
    nominal = _param_array(nominal)
    if approx not in DEFAULT_APPROX_SD:
        raise InvalidValueError(f"approx = {approx!r}; expected 'isotropic' or 'relative'")
    approx_sd = DEFAULT_APPROX_SD[approx] if approx_sd is None else approx_sd
    if not (sigma_px > 0 and approx_sd > 0 and range_mm > 0 and n_points >= 1):
        raise InvalidValueError(
            f"sigma_px = {sigma_px}, approx_sd = {approx_sd}, range_mm = {range_mm}, "
            f"n_points = {n_points}; expected positive numbers")
    dist, angle, walls = random_walls(rng, range_mm, n_walls)
    pts, true, noisy, wall = _laser_rows(rng, dist, angle, params, n_points, sigma_px,
                                         tuple(image_size))
    if sort_azimuth:
        order = np.argsort(np.arctan2(pts[:, 1], pts[:, 0]))
        pts, true, noisy, wall = pts[order], true[order], noisy[order], wall[order]
    approx_pts, sd = _approximate(rng, pts, approx, approx_sd, z_known, nominal)
    for name, p in (("params", params), ("nominal", nominal)):
        if not np.all(project2(p, approx_pts)[1]):
            raise InvalidValueError(f"an approximate point is outside the projection domain "
                                    f"of {name}; expected xi * |P| - z > 0")
    return Room(params=params, pixels=noisy, pixels_true=true, points=pts,
                approx_points=approx_pts, sigma_px=float(sigma_px), sigma_scene=sd,
                walls=walls, wall_lines=np.stack([dist, angle], axis=1), wall_index=wall,
                range_mm=float(range_mm), nominal=nominal, image_size=tuple(image_size),
                approx=approx, approx_sd=float(approx_sd), z_known=bool(z_known),
                sd_columns=bool(sd_columns))


def _param_array(params):
    if params is None:
        return bc.SensorParams.paper().to_array()
    if isinstance(params, bc.SensorParams):
        return params.to_array()
    return bc.SensorParams.from_array(np.asarray(params, float)).to_array()
