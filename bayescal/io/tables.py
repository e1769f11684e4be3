"""Reading numeric tables from CSV and NPZ files, with every error located.

:func:`read_table` returns a :class:`Table` (float columns, the line of each
row); every problem raises :class:`~bayescal.errors.InputError` naming the
file, the line (or array index) and the column, and what was expected. The
file formats are described in :mod:`bayescal.io.data`.
"""

from __future__ import annotations

import csv
import io as _io
import math
import pathlib
import re
import sys
from dataclasses import dataclass, field

import numpy as np

from ..errors import InputError, InvalidValueError

__all__ = ["Table", "read_table", "drop_flagged", "parse_image_size", "LASER_COLUMNS",
           "SIGMA_COLUMNS", "PIXEL_COV_COLUMNS", "FLAG_COLUMNS", "IMAGE_SIZE_KEY",
           "image_size_line", "OFFSET_SD_KEY", "offset_sd_line"]

LASER_COLUMNS = ("u", "v", "x", "y", "z")
SIGMA_COLUMNS = ("sigma_x", "sigma_y", "sigma_z")
#: per-point pixel covariances, px^2 (``bayescal extract`` writes them)
PIXEL_COV_COLUMNS = ("cov_uu", "cov_uv", "cov_vv")
#: the comment line that carries the image size: ``# image_size: 1280x1024`` (px)
IMAGE_SIZE_KEY = "image_size"
_META_RE = re.compile(r"^#\s*image_size\s*[:=]\s*(\d+)\s*[xX]\s*(\d+)\s*$")
#: the comment line that carries the sd of a translation shared by every pixel (px, each
#: axis): ``# offset_sd: 0.02`` (``bayescal extract`` writes it; calibrate adds its variance
#: to u0 and v0)
OFFSET_SD_KEY = "offset_sd"
_OFFSET_RE = re.compile(r"^#\s*offset_sd\s*[:=]\s*(\S+?)\s*(?:px)?\s*$")


def image_size_line(size):
    """The comment line (without its ``#``) that carries ``size = (width, height)`` px."""
    return f"{IMAGE_SIZE_KEY}: {int(size[0])}x{int(size[1])}"


def offset_sd_line(sd):
    """The comment line (without its ``#``) that carries ``sd`` px."""
    return f"{OFFSET_SD_KEY}: {float(sd):.6g}"


#: the smallest standard deviation a ``sigma_*`` cell stands for (mm, px): a nanometre is far
#: below any approximate point's error; a smaller positive value is a relative error times a
#: coordinate of ~0 (``simulate_room`` gives 1e-15 mm on an axis where cos(az) rounds to
#: 6e-17), taken as this, which the fit treats the same (the coordinate known) without
#: weights of 1e30, and said in a warning naming the lines
MIN_SD = 1e-9
#: what ``bayescal extract`` writes beside the pixels: peak over noise, distractor flag
FLAG_COLUMNS = ("snr", "flagged")
_KNOWN = LASER_COLUMNS + SIGMA_COLUMNS + ("sigma_px", "plane") + PIXEL_COV_COLUMNS
_STACKED = {"pixels": ("u", "v"), "approx_points": ("x", "y", "z"), "points": ("x", "y", "z"),
            "sigma_scene": SIGMA_COLUMNS}


@dataclass
class Table:
    """Numeric columns read from one CSV or NPZ file.

    Attributes
    ----------
    path : pathlib.Path
    columns : dict of str to ndarray, shape (N,)
        Float columns; ``nan`` marks an empty cell (only kept for sigma columns).
    lines : ndarray of int, shape (N,)
        Line of each row in the file (CSV, 1-based, header = 1) or row index (NPZ).
    kind : {"csv", "npz"}
    scalars : dict of str to float
        Scalar NPZ entries (``sigma_px``).
    meta : dict
        What the file says about itself in ``# key: value`` comment lines before the
        header (CSV): ``image_size`` as ``(width, height)`` px (:data:`IMAGE_SIZE_KEY`).
    dropped : tuple of int
        Lines (or NPZ indices) left out of the table: the rows ``bayescal extract``
        flagged (``flagged = 1``), see :func:`drop_flagged`.
    """

    path: pathlib.Path
    columns: dict
    lines: np.ndarray
    kind: str
    scalars: dict = field(default_factory=dict)
    meta: dict = field(default_factory=dict)
    dropped: tuple = ()

    def __len__(self):
        return len(self.lines)

    def where(self, row, column):
        """Human-readable location of ``row`` (0-based data row) in ``column``."""
        if self.kind == "csv":
            return f"{self.path}, line {int(self.lines[row])}, column '{column}'"
        return f"{self.path}, array '{column}', index {int(self.lines[row])}"

    def error(self, row, column, message):
        """An :class:`InputError` located at ``row``/``column``."""
        return InputError(f"{self.where(row, column)}: {message}", path=str(self.path),
                          line=int(self.lines[row]), column=column)


def _fmt(value):
    return f"{value:.6g}" if isinstance(value, float) else repr(value)


def _sd_unit(column):
    """The unit of a standard-deviation column (``sigma_px``: px, ``sigma_x/y/z``: mm), or
    None for any other column."""
    return ("px" if column == "sigma_px" else "mm") if column.startswith("sigma_") else None


def _parse_cell(text, *, where, sigma):
    """Parse one CSV cell; sigma columns (``sigma`` their unit) accept empty/inf as 'no
    information'."""
    s = text.strip()
    if s == "":
        if sigma:
            return math.inf
        raise InputError(f"{where}: empty cell; expected a number")
    try:
        value = float(s)
    except ValueError:
        raise InputError(f"{where}: could not read {s!r} as a number") from None
    if math.isnan(value):
        raise InputError(f"{where}: NaN is not allowed; expected a finite number"
                         + (" (or empty/inf for 'no information')" if sigma else ""))
    if math.isinf(value) and not sigma:
        raise InputError(f"{where}: {s!r} is not allowed; expected a finite number")
    if sigma and value <= 0:
        raise InputError(f"{where}: {s!r} is not a valid standard deviation; expected a "
                         f"positive number in {sigma} (or empty/inf for 'no information')")
    if sigma and value < MIN_SD:        # see _floor_note
        return MIN_SD
    return value


def _meta(path, text):
    """``# key: value`` lines before the header: the image size (``# image_size: WxH``) and
    the shared translation's sd (``# offset_sd: SD``, px)."""
    meta = {}
    for lineno, line in enumerate(text.splitlines(), 1):
        s = line.strip()
        if s and not s.startswith("#"):
            break
        off = _OFFSET_RE.match(s)
        if off is not None:
            meta[OFFSET_SD_KEY] = _offset_sd(path, lineno, off.group(1))
        m = _META_RE.match(s)
        if m is None:
            continue
        w, h = int(m.group(1)), int(m.group(2))
        if w <= 0 or h <= 0:
            raise InputError(f"{path}, line {lineno}: image size {w}x{h}; expected a "
                             "positive width and height in px", path=str(path), line=lineno)
        meta[IMAGE_SIZE_KEY] = (w, h)
    return meta


def _offset_sd(path, lineno, text):
    try:
        sd = float(text)
    except ValueError:
        sd = float("nan")
    if not (np.isfinite(sd) and sd >= 0):
        raise InputError(f"{path}, line {lineno}: offset_sd {text!r}; expected a finite "
                         "non-negative number of pixels", path=str(path), line=lineno)
    return sd


def _read_csv(path, required, optional):
    try:
        text = path.read_text(encoding="utf-8-sig")
    except UnicodeDecodeError as exc:
        raise InputError(f"{path}: not a UTF-8 text file ({exc.reason}); expected a CSV file",
                         path=str(path)) from None
    rows = [(i + 1, r) for i, r in enumerate(csv.reader(_io.StringIO(text)))
            if r and any(c.strip() for c in r) and not r[0].lstrip().startswith("#")]
    if not rows:
        raise InputError(f"{path}: the file is empty; expected a header line naming the "
                         f"columns {', '.join(required)} and one line per point", path=str(path))
    header_line, header = rows[0]
    names = [h.strip().lower() for h in header]
    for j, n in enumerate(names):
        if n in names[:j]:
            raise InputError(f"{path}, line {header_line}: column '{n}' appears twice",
                             path=str(path), line=header_line, column=n)
    missing = [c for c in required if c not in names]
    if missing:
        extra = [c for c in optional if c not in required]
        raise InputError(
            f"{path}, line {header_line}: missing column(s) {', '.join(repr(m) for m in missing)}; "
            f"the header has {', '.join(repr(n) for n in names)}, expected "
            f"{', '.join(required)}" + (f" (optional: {', '.join(extra)})" if extra else ""),
            path=str(path), line=header_line, column=missing[0])
    ignored = [n for n in names if n not in required and n not in optional]
    if ignored:
        print(f"bayescal: warning: {path}: ignoring column(s) {', '.join(ignored)} "
              f"(known columns: {', '.join(dict.fromkeys(tuple(required) + tuple(optional)))})",
              file=sys.stderr)
    data = rows[1:]
    if not data:
        raise InputError(f"{path}: the header is there but no data lines follow",
                         path=str(path), line=header_line)
    wanted = [c for c in names if c in required or c in optional]
    cols = {c: np.empty(len(data)) for c in wanted}
    lines = np.empty(len(data), dtype=int)
    for k, (lineno, cells) in enumerate(data):
        if len(cells) != len(names):
            raise InputError(f"{path}, line {lineno}: {len(cells)} fields, expected "
                             f"{len(names)} (one per header column)", path=str(path), line=lineno)
        lines[k] = lineno
        for c in wanted:
            j = names.index(c)
            sigma = _sd_unit(c)
            where = f"{path}, line {lineno}, column '{c}'"
            try:
                cols[c][k] = _parse_cell(cells[j], where=where, sigma=sigma)
            except InputError as exc:
                exc.path, exc.line, exc.column = str(path), lineno, c
                raise
    _floor_note(path, cols, lines, {c: names.index(c) for c in wanted},
                [cells for _, cells in data])
    return Table(path, cols, lines, "csv", meta=_meta(path, text))


def _floor_note(path, cols, lines, index, cells):
    """Warn about the sds below :data:`MIN_SD` that were read as it (CSV)."""
    hits = []
    for c, j in index.items():
        if _sd_unit(c) is None:
            continue
        small = np.flatnonzero(cols[c] == MIN_SD)
        hits += [(int(lines[k]), c) for k in small if float(cells[k][j]) < MIN_SD]
    if hits:
        where = ", ".join(f"{line} ({c})" for line, c in sorted(hits)[:5])
        print(f"bayescal: warning: {path}: standard deviation(s) below {MIN_SD:g} on line(s) "
              f"{where}{' ...' if len(hits) > 5 else ''}: a relative error times a coordinate "
              f"of ~0; read as {MIN_SD:g} (that coordinate known)", file=sys.stderr)


def _read_npz(path, required, optional):
    try:
        with np.load(path, allow_pickle=False) as z:
            raw = {k.lower(): np.asarray(z[k]) for k in z.files}
    except Exception as exc:  # np.load raises many kinds for a corrupt file
        raise InputError(f"{path}: could not read as an NPZ archive ({exc})",
                         path=str(path)) from None
    arrays, scalars = {}, {}
    for name, a in raw.items():
        if name in _STACKED:
            sub = _STACKED[name]
            if a.ndim != 2 or a.shape[1] != len(sub):
                raise InputError(f"{path}, array '{name}': shape {a.shape}, expected "
                                 f"(N, {len(sub)})", path=str(path), column=name)
            for j, c in enumerate(sub):
                arrays.setdefault(c, a[:, j])
        elif a.ndim == 0:
            scalars[name] = a
        else:
            arrays[name] = a
    missing = [c for c in required if c not in arrays]
    if missing:
        raise InputError(f"{path}: missing array(s) {', '.join(repr(m) for m in missing)}; "
                         f"found {', '.join(repr(k) for k in raw) or 'none'}, expected "
                         f"{', '.join(required)} (or the stacked arrays pixels (N, 2), "
                         "approx_points (N, 3))", path=str(path), column=missing[0])
    wanted = [c for c in arrays if c in required or c in optional]
    n = None
    cols = {}
    for c in wanted:
        a = arrays[c]
        if a.ndim != 1:
            raise InputError(f"{path}, array '{c}': shape {a.shape}, expected (N,)",
                             path=str(path), column=c)
        if n is None:
            n, first = len(a), c
        elif len(a) != n:
            raise InputError(f"{path}, array '{c}': {len(a)} entries but '{first}' has {n}; "
                             "expected the same length", path=str(path), column=c)
        try:
            cols[c] = a.astype(float)
        except (TypeError, ValueError):
            raise InputError(f"{path}, array '{c}': dtype {a.dtype} is not numeric; expected "
                             "numbers", path=str(path), column=c) from None
    if not n:
        raise InputError(f"{path}: the arrays are empty; expected one entry per point",
                         path=str(path))
    table = Table(path, cols, np.arange(n), "npz",
                  {k: v for k, v in scalars.items() if k in optional or k in required})
    for c, a in cols.items():
        sigma = _sd_unit(c)
        if sigma:
            _floor_npz(path, c, a)
        bad = np.isnan(a) | (np.isinf(a) if not sigma else (a < MIN_SD))
        if np.any(bad):
            k = int(np.argmax(bad))
            what = (f"a number of at least {MIN_SD:g} {sigma} (or inf for 'no information')"
                    if sigma else "a finite number")
            raise table.error(k, c, f"{_fmt(float(a[k]))} is not allowed; expected {what}")
    return table


def _floor_npz(path, column, a):
    """Read the sds of ``a`` below :data:`MIN_SD` as it, with a warning (NPZ)."""
    small = np.flatnonzero((a > 0) & (a < MIN_SD))
    if len(small):
        print(f"bayescal: warning: {path}, array '{column}': {len(small)} standard deviation(s) "
              f"below {MIN_SD:g} (index {', '.join(map(str, small[:5]))}): a relative error "
              f"times a coordinate of ~0; read as {MIN_SD:g} (that coordinate known)",
              file=sys.stderr)
        a[small] = MIN_SD


def read_table(path, *, required, optional=()):
    """Read numeric columns from a CSV or NPZ file, checking every cell.

    Parameters
    ----------
    path : str or pathlib.Path
        ``.npz`` files are read as NPZ, anything else as CSV.
    required : sequence of str
        Columns that must be present (lower-case names).
    optional : sequence of str
        Columns read when present; others are ignored (with a warning for CSV).

    Returns
    -------
    Table

    Raises
    ------
    InputError
        Missing file or column, empty file, a cell that is not a number, NaN,
        infinity outside the sigma columns, rows of the wrong length.
    """
    path = pathlib.Path(path)
    if not path.is_file():
        raise InputError(f"{path}: no such file", path=str(path))
    if path.suffix.lower() == ".npz":
        return _read_npz(path, tuple(required), tuple(optional))
    return _read_csv(path, tuple(required), tuple(optional))


def parse_image_size(text):
    """Parse ``"WIDTHxHEIGHT"`` (px) into ``(width, height)`` ints."""
    try:
        w, h = (int(s) for s in str(text).lower().split("x"))
    except ValueError:
        raise InvalidValueError(f"image size must look like 800x600 (width x height in px), "
                                f"got {text!r}") from None
    if w <= 0 or h <= 0:
        raise InvalidValueError(f"image size must be positive, got {text!r}")
    return w, h


def drop_flagged(table, *others):
    """Leave out the rows ``bayescal extract`` flagged as likely distractors.

    Parameters
    ----------
    table : Table
        The pixel table; its ``flagged`` column (0 or 1), if any, decides.
    *others : Table
        Tables with the same rows (a separate points file), cut the same way.

    Returns
    -------
    tuple of Table
        ``table`` and ``others`` without the flagged rows; the pixel table's
        :attr:`Table.dropped` lists their lines. Unchanged without a ``flagged`` column.

    Raises
    ------
    InputError
        A ``flagged`` cell that is not 0 or 1, or every row flagged.
    """
    flag = table.columns.get("flagged")
    if flag is None:
        return (table, *others)
    bad = (flag != 0) & (flag != 1)
    if np.any(bad):
        k = int(np.argmax(bad))
        raise table.error(k, "flagged", f"{_fmt(float(flag[k]))}; expected 0 (a laser point) "
                          "or 1 (flagged as a likely distractor by bayescal extract)")
    keep = flag == 0
    if not keep.any():
        raise InputError(f"{table.path}: every one of its {len(flag)} rows is flagged "
                         "(flagged = 1, likely distractors); no laser point left to use. "
                         "Re-extract (bayescal extract --background, --center, --channel)",
                         path=str(table.path), column="flagged")
    dropped = tuple(int(v) for v in table.lines[~keep])
    out = []
    for t in (table, *others):
        cols = {c: a[keep] for c, a in t.columns.items()}
        out.append(Table(t.path, cols, t.lines[keep], t.kind, dict(t.scalars), dict(t.meta),
                         dropped if t is table else ()))
    return tuple(out)
