"""Data files: laser pixels and approximate points in CSV or NPZ, calibration patterns, JSON.

File formats (``docs/cli.md`` has examples):

* **Laser data**, one CSV with a header line, one laser point per line. Columns
  (case-insensitive, any order, extra columns ignored with a warning):

  ``u, v``
      laser pixel, px (required);
  ``x, y, z``
      approximate 3D point in frame C, mm (required for calibration; may sit
      in a second file with the same number of rows);
  ``sigma_x, sigma_y, sigma_z``
      optional standard deviation of each approximate coordinate, mm; an
      empty cell or ``inf`` means "no information on this axis";
  ``sigma_px``
      optional pixel noise standard deviation, px: one value for the whole
      file (empty cells allowed, different values rejected).

  ``cov_uu, cov_uv, cov_vv``
      optional per-point pixel covariance, px^2;
  ``snr, flagged``
      from ``bayescal extract``: rows with ``flagged = 1`` are left out
      (:attr:`LaserData.flagged_lines`).

  Lines starting with ``#`` and blank lines are skipped; line numbers in
  messages count every line of the file, the header being line 1. A comment
  line ``# image_size: WIDTHxHEIGHT`` before the header gives the image size
  in px (``bayescal extract`` writes it; :attr:`LaserData.image_size`).
* **NPZ** with the same names as 1-D arrays (``u``, ``v``, ``x``...), or the
  stacked arrays ``pixels`` (N, 2), ``approx_points`` (N, 3),
  ``sigma_scene`` (N, 3) and a scalar ``sigma_px``.
* **Calibration patterns** for the sequential method: an NPZ with the field
  names of :class:`~bayescal.CalibrationData` (``grid_points``,
  ``grid_pixels``, ``grid_plane``, ``laser_pixels``, ``laser_plane``
  required), or two CSVs: the pattern grid (``plane, u, v, x, y, z``) and the
  laser on the planes (``plane, u, v``).

* **Floor plans** (``calibrate --walls``): see :mod:`bayescal.io.planfile`.

Every reader raises :class:`InputError` (a ``ValueError``) naming the file,
the line (or array index) and the column, and what was expected.
"""

from __future__ import annotations

import csv
import pathlib
from dataclasses import dataclass

import numpy as np

from ..errors import InputError
from .jsonfile import read_json, to_jsonable, write_json
from .tables import (
    FLAG_COLUMNS,
    LASER_COLUMNS,
    PIXEL_COV_COLUMNS,
    SIGMA_COLUMNS,
    Table,
    drop_flagged,
    parse_image_size,
    read_table,
)

__all__ = ["InputError", "to_jsonable", "Table", "LaserData", "read_table", "load_laser_data",
           "load_pixels", "pixel_covariance", "load_calibration_data", "check_pixels_in_image",
           "check_projection_domain", "write_laser_csv", "write_laser_npz",
           "write_calibration_npz", "write_json", "read_json", "parse_image_size",
           "duplicate_rows", "LASER_COLUMNS", "SIGMA_COLUMNS", "PIXEL_COV_COLUMNS",
           "FLAG_COLUMNS"]

@dataclass
class LaserData:
    """Laser pixels and (optionally) approximate points, validated.

    Attributes
    ----------
    pixels : ndarray, shape (N, 2)
        ``(u, v)``, px.
    approx_points : ndarray, shape (N, 3) or None
        Approximate points in frame C, mm.
    sigma_scene : ndarray, shape (N, 3) or None
        Standard deviation of each approximate coordinate, mm (``inf`` = no
        information); None when the files have no sigma columns.
    sigma_px : float or None
        Pixel noise from the file, px.
    pixel_table, point_table : Table
        Where the numbers came from (for messages).
    pixel_cov : ndarray, shape (N, 2, 2) or None
        Per-point pixel covariances from the columns ``cov_uu, cov_uv, cov_vv``, px^2.
    """

    pixels: np.ndarray
    approx_points: np.ndarray | None
    sigma_scene: np.ndarray | None
    sigma_px: float | None
    pixel_table: Table
    point_table: Table | None
    pixel_cov: np.ndarray | None = None

    @property
    def n_points(self):
        """Number of laser points N."""
        return len(self.pixels)

    @property
    def flagged_lines(self):
        """Lines (NPZ: indices) of the rows left out as ``flagged = 1``; empty if none."""
        return self.pixel_table.dropped

    @property
    def image_size(self):
        """``(width, height)`` px from the file's ``# image_size: WxH`` line, or None."""
        return self.pixel_table.meta.get("image_size")

    @property
    def paths(self):
        """The input files, as a list of pathlib.Path."""
        tabs = [self.pixel_table] + ([self.point_table] if self.point_table is not None and
                                     self.point_table is not self.pixel_table else [])
        return [t.path for t in tabs]


def _sigma_px(tables):
    value, src = None, None
    for t in tables:
        if "sigma_px" in t.scalars:
            v = float(t.scalars["sigma_px"])
            if not (np.isfinite(v) and v > 0):
                raise InputError(f"{t.path}, array 'sigma_px': {v!r}; expected a positive "
                                 "number of pixels", path=str(t.path), column="sigma_px")
            vals, rows = np.array([v]), None
        elif "sigma_px" in t.columns:
            col = t.columns["sigma_px"]
            rows = np.flatnonzero(np.isfinite(col))
            vals = col[rows]
        else:
            continue
        for k, v in enumerate(vals):
            if rows is not None and v <= 0:
                raise t.error(rows[k], "sigma_px", f"{v!r} is not a valid pixel noise; "
                              "expected a positive number of pixels")
            if value is None:
                value, src = float(v), t.path
            elif not np.isclose(v, value, rtol=1e-12, atol=0):
                where = t.where(rows[k], "sigma_px") if rows is not None else str(t.path)
                raise InputError(f"{where}: sigma_px = {v:g} differs from the first value "
                                 f"{value:g} ({src}); expected one pixel-noise level for all "
                                 "points", path=str(t.path), column="sigma_px")
    return value


def load_pixels(path):
    """Read laser pixels ``u, v`` from a CSV or NPZ file.

    Returns
    -------
    pixels : ndarray, shape (N, 2)
    table : Table
    """
    t = read_table(path, required=("u", "v"), optional=("x", "y", "z") + SIGMA_COLUMNS
                   + ("sigma_px",) + PIXEL_COV_COLUMNS + FLAG_COLUMNS)
    (t,) = drop_flagged(t)
    return np.column_stack([t.columns["u"], t.columns["v"]]), t


def load_laser_data(path, points_path=None, *, need_points=True):
    """Read laser pixels and approximate points from one file or two.

    Parameters
    ----------
    path : str or pathlib.Path
        CSV/NPZ with ``u, v`` (and ``x, y, z`` when ``points_path`` is None).
    points_path : str or pathlib.Path, optional
        A second file with ``x, y, z`` (and sigma columns), same number of rows.
    need_points : bool, optional
        Require approximate points (calibration) or not (sequential, reconstruction).

    Returns
    -------
    LaserData

    Raises
    ------
    InputError
        See :func:`read_table`; also mismatched row counts between the two files.
    """
    opt = SIGMA_COLUMNS + ("sigma_px",)
    if points_path is None:
        req = ("u", "v") + (("x", "y", "z") if need_points else ())
        pt = read_table(path, required=req,
                        optional=("x", "y", "z") + opt + PIXEL_COV_COLUMNS + FLAG_COLUMNS)
        (pt,) = drop_flagged(pt)
        qt = pt if all(c in pt.columns for c in "xyz") else None
        tables = [pt]
    else:
        pt = read_table(path, required=("u", "v"),
                        optional=("sigma_px",) + PIXEL_COV_COLUMNS + FLAG_COLUMNS)
        qt = read_table(points_path, required=("x", "y", "z"), optional=opt)
        if len(pt) != len(qt):
            raise InputError(f"{pt.path} has {len(pt)} points (u, v) but {qt.path} has "
                             f"{len(qt)} (x, y, z); expected the same number, one row per "
                             "laser point in the same order", path=str(qt.path))
        pt, qt = drop_flagged(pt, qt)
        tables = [pt, qt]
    pixels = np.column_stack([pt.columns["u"], pt.columns["v"]])
    approx = sig = None
    if qt is not None:
        approx = np.column_stack([qt.columns[c] for c in "xyz"])
        if any(c in qt.columns for c in SIGMA_COLUMNS):
            sig = np.column_stack([qt.columns.get(c, np.full(len(qt), np.inf))
                                   for c in SIGMA_COLUMNS])
    return LaserData(pixels, approx, sig, _sigma_px(tables), pt, qt, pixel_covariance(pt))


def pixel_covariance(table):
    """The (N, 2, 2) pixel covariances (px^2) of ``cov_uu, cov_uv, cov_vv``, or None if absent;
    an :class:`InputError` names the line of a covariance that is not positive definite."""
    have = [c for c in PIXEL_COV_COLUMNS if c in table.columns]
    if not have:
        return None
    if len(have) < 3:
        missing = [c for c in PIXEL_COV_COLUMNS if c not in have]
        raise InputError(f"{table.path}: column(s) {', '.join(missing)} missing; pixel "
                         "covariances need all of cov_uu, cov_uv, cov_vv (px^2)",
                         path=str(table.path), column=missing[0])
    uu, uv, vv = (np.asarray(table.columns[c], float) for c in PIXEL_COV_COLUMNS)
    ok = np.isfinite(uu) & np.isfinite(uv) & np.isfinite(vv) & (uu > 0) & (uu * vv - uv**2 > 0)
    if not np.all(ok):
        k = int(np.flatnonzero(~ok)[0])
        raise table.error(k, "cov_uu", f"cov_uu, cov_uv, cov_vv = {uu[k]:g}, {uv[k]:g}, "
                          f"{vv[k]:g} is not a positive definite covariance (px^2)")
    return np.stack([np.stack([uu, uv], -1), np.stack([uv, vv], -1)], -2)


def duplicate_rows(data):
    """Groups of exactly repeated laser points (every column equal).

    Parameters
    ----------
    data : LaserData

    Returns
    -------
    list of list of int
        File line numbers (CSV, header = 1) or row indices (NPZ) of each group
        of identical rows; empty when every row is distinct. A duplicated row
        counts twice in the likelihood and shrinks every sd by about sqrt(2).
    """
    cols = [data.pixels]
    for a in (data.approx_points, data.sigma_scene):
        if a is not None:
            cols.append(a)
    rows = np.column_stack(cols)
    _, inverse, counts = np.unique(rows, axis=0, return_inverse=True, return_counts=True)
    inverse = np.asarray(inverse).ravel()
    lines = data.pixel_table.lines
    groups = []
    for g in np.flatnonzero(counts > 1):
        groups.append([int(lines[i]) for i in np.flatnonzero(inverse == g)])
    return sorted(groups)


def check_pixels_in_image(pixels, table, *, image_size, margin):
    """Reject pixels further than ``margin`` px outside the image.

    Parameters
    ----------
    pixels : ndarray, shape (N, 2)
    table : Table
        Where they came from (for the message).
    image_size : (int, int)
        Width, height in px; pixel ``(u, v)`` is inside when
        ``-margin <= u <= width + margin`` and likewise for ``v``.
    margin : float
        Tolerance in px.

    Raises
    ------
    InputError
        At the first offending row, with the count of all offending rows.
    """
    w, h = image_size
    for j, (name, size) in enumerate((("u", w), ("v", h))):
        bad = (pixels[:, j] < -margin) | (pixels[:, j] > size + margin)
        if np.any(bad):
            k = int(np.argmax(bad))
            more = f" ({int(bad.sum())} such rows in all)" if bad.sum() > 1 else ""
            raise table.error(k, name, f"pixel {name} = {pixels[k, j]:g} is outside the image; "
                              f"expected {-margin:g} <= {name} <= {size + margin:g} "
                              f"(--image-size {w}x{h}, --image-margin {margin:g}){more}")


def check_projection_domain(points, table, params):
    """Reject points outside the projection domain ``xi * r - z > 0`` of ``params``.

    Parameters
    ----------
    points : ndarray, shape (N, 3)
        mm in frame C.
    table : Table
    params : SensorParams
        Usually the nominal (design) sensor.

    Raises
    ------
    InputError
    """
    r = np.linalg.norm(points, axis=-1)
    d = params.xi * r - points[:, 2]
    bad = ~(d > 0)
    if np.any(bad):
        k = int(np.argmax(bad))
        more = f" ({int(bad.sum())} such rows in all)" if bad.sum() > 1 else ""
        p = points[k]
        raise table.error(
            k, "x, y, z",
            f"point ({p[0]:g}, {p[1]:g}, {p[2]:g}) mm is outside the projection domain of "
            f"the nominal sensor: xi*r - z = {d[k]:.3g}, expected > 0 (the point must not lie "
            f"on or above the mirror along its axis; z is up, mm, frame C){more}")


def _column_text(a):
    """Cells of one column: integers (and booleans, as 0/1) as integers, floats with
    ``repr`` (round-trip exact), ``inf`` as ``inf``."""
    a = np.asarray(a)
    if a.dtype.kind in "biu":
        return [str(int(v)) for v in a]
    return ["inf" if np.isposinf(v) else repr(float(v)) for v in a.astype(float)]


def write_laser_csv(path, pixels, approx_points=None, *, sigma_scene=None, sigma_px=None,
                    header_comment=None):
    """Write laser data in the CSV format read by :func:`load_laser_data`.

    Parameters
    ----------
    path : str or pathlib.Path
    pixels : ndarray, shape (N, 2)
        px.
    approx_points : ndarray, shape (N, 3), optional
        mm.
    sigma_scene : ndarray, shape (N, 3), optional
        mm, ``inf`` written as ``inf``.
    sigma_px : float, optional
        Written on every row.
    header_comment : str, optional
        Written first as ``# ...`` comment lines.

    Returns
    -------
    pathlib.Path
    """
    path = pathlib.Path(path)
    cols = {"u": pixels[:, 0], "v": pixels[:, 1]}
    if approx_points is not None:
        cols.update(zip("xyz", approx_points.T, strict=True))
    if sigma_scene is not None:
        cols.update(zip(SIGMA_COLUMNS, sigma_scene.T, strict=True))
    if sigma_px is not None:
        cols["sigma_px"] = np.full(len(pixels), float(sigma_px))
    _write_csv(path, cols, header_comment)
    return path


def _write_csv(path, cols, header_comment=None):
    with open(path, "w", newline="", encoding="utf-8") as f:
        if header_comment:
            for line in header_comment.splitlines():
                f.write(f"# {line}\n")
        w = csv.writer(f, lineterminator="\n")
        w.writerow(cols)
        texts = [_column_text(a) for a in cols.values()]
        w.writerows(zip(*texts, strict=True))


def write_laser_npz(path, pixels, approx_points=None, *, sigma_scene=None, sigma_px=None):
    """Write laser data as NPZ (``pixels``, ``approx_points``, ``sigma_scene``, ``sigma_px``)."""
    arrays = {"pixels": np.asarray(pixels, dtype=float)}
    if approx_points is not None:
        arrays["approx_points"] = np.asarray(approx_points, dtype=float)
    if sigma_scene is not None:
        arrays["sigma_scene"] = np.asarray(sigma_scene, dtype=float)
    if sigma_px is not None:
        arrays["sigma_px"] = np.asarray(float(sigma_px))
    np.savez(path, **arrays)
    return pathlib.Path(path)


_CALIB_REQUIRED = {"grid_points": 3, "grid_pixels": 2, "grid_plane": 0, "laser_pixels": 2,
                   "laser_plane": 0}
_CALIB_OPTIONAL = {"angles": None, "translation": None, "grid_points_true": 3,
                   "laser_points_true": 3}


def write_calibration_npz(path, calibration):
    """Write a :class:`~bayescal.CalibrationData` as NPZ with its field names."""
    from dataclasses import asdict

    np.savez(path, **{k: np.asarray(v) for k, v in asdict(calibration).items()})
    return pathlib.Path(path)


def _check_calib_array(path, name, a, last):
    where = f"{path}, array '{name}'"
    if last == 0:
        if a.ndim != 1:
            raise InputError(f"{where}: shape {a.shape}, expected (M,) plane indices",
                             path=str(path), column=name)
        if not np.issubdtype(a.dtype, np.number) or np.any(a != np.round(a)) or \
                np.any((a < 0) | (a > 3)):
            raise InputError(f"{where}: expected integer plane indices 0-3, got values "
                             f"{np.unique(a)[:8]}", path=str(path), column=name)
        return a.astype(int)
    if a.ndim != 2 or a.shape[1] != last:
        raise InputError(f"{where}: shape {a.shape}, expected (M, {last})", path=str(path),
                         column=name)
    try:
        a = a.astype(float)
    except (TypeError, ValueError):
        raise InputError(f"{where}: not numeric", path=str(path), column=name) from None
    if not np.all(np.isfinite(a)):
        k = int(np.argwhere(~np.isfinite(a))[0][0])
        raise InputError(f"{where}, index {k}: {a[k]} contains NaN or inf; expected finite "
                         "numbers", path=str(path), line=k, column=name)
    return a


def load_calibration_data(path, laser_path=None):
    """Read calibration-plane data for the sequential method.

    Parameters
    ----------
    path : str or pathlib.Path
        Either an NPZ with :class:`~bayescal.CalibrationData` field names
        (``grid_points`` (M, 3) mm in the pattern frame, ``grid_pixels`` (M, 2)
        px, ``grid_plane`` (M,) int 0-3, ``laser_pixels`` (K, 2) px,
        ``laser_plane`` (K,) int 0-3; optional ``angles``, ``translation``,
        ``grid_points_true``, ``laser_points_true``, unknown ones filled with
        NaN), or a CSV of the pattern grid with columns ``plane, u, v, x, y, z``.
    laser_path : str or pathlib.Path, optional
        With a CSV grid: CSV of the laser on the planes, columns ``plane, u, v``.

    Returns
    -------
    CalibrationData
    """
    from ..scene.simulate import CalibrationData

    path = pathlib.Path(path)
    if path.suffix.lower() == ".npz":
        if laser_path is not None:
            raise InputError(f"{laser_path}: not expected with an NPZ calibration file {path} "
                             "(it already holds laser_pixels and laser_plane)",
                             path=str(laser_path))
        if not path.is_file():
            raise InputError(f"{path}: no such file", path=str(path))
        try:
            with np.load(path, allow_pickle=False) as z:
                raw = {k: np.asarray(z[k]) for k in z.files}
        except Exception as exc:
            raise InputError(f"{path}: could not read as an NPZ archive ({exc})",
                             path=str(path)) from None
        missing = [k for k in _CALIB_REQUIRED if k not in raw]
        if missing:
            raise InputError(f"{path}: missing array(s) {', '.join(missing)}; found "
                             f"{', '.join(raw) or 'none'}, expected {', '.join(_CALIB_REQUIRED)}",
                             path=str(path), column=missing[0])
        f = {k: _check_calib_array(path, k, raw[k], last) for k, last in _CALIB_REQUIRED.items()}
        for k, _last in _CALIB_OPTIONAL.items():
            if k in raw:
                f[k] = np.asarray(raw[k], dtype=float)
    else:
        if laser_path is None:
            raise InputError(f"{path}: a CSV calibration grid needs the laser-on-planes CSV "
                             "too (columns plane, u, v)", path=str(path))
        g = read_table(path, required=("plane", "u", "v", "x", "y", "z"))
        la = read_table(laser_path, required=("plane", "u", "v"))
        for t in (g, la):
            p = t.columns["plane"]
            bad = (p != np.round(p)) | (p < 0) | (p > 3)
            if np.any(bad):
                k = int(np.argmax(bad))
                raise t.error(k, "plane", f"{p[k]:g} is not a plane index; expected 0, 1, 2 or 3")
        f = {"grid_points": np.column_stack([g.columns[c] for c in "xyz"]),
             "grid_pixels": np.column_stack([g.columns["u"], g.columns["v"]]),
             "grid_plane": g.columns["plane"].astype(int),
             "laser_pixels": np.column_stack([la.columns["u"], la.columns["v"]]),
             "laser_plane": la.columns["plane"].astype(int)}
    for a, b in (("grid_points", "grid_pixels"), ("grid_points", "grid_plane"),
                 ("laser_pixels", "laser_plane")):
        if len(f[a]) != len(f[b]):
            raise InputError(f"{path}: {a} has {len(f[a])} rows but {b} has {len(f[b])}; "
                             "expected the same number", path=str(path), column=b)
    f.setdefault("angles", np.full(3, np.nan))
    f.setdefault("translation", np.full(3, np.nan))
    f.setdefault("grid_points_true", np.full_like(f["grid_points"], np.nan))
    f.setdefault("laser_points_true", np.full((len(f["laser_pixels"]), 3), np.nan))
    return CalibrationData(**f)
