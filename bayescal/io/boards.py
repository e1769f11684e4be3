"""Files of chessboard corners: a set of board views in CSV or NPZ.

* **CSV**, one corner per line, a header line naming the columns (case-insensitive, any
  order): ``view`` (an integer, the view's index), ``u, v`` (px), ``x, y, z`` (the corner
  in the board's frame, mm), optionally ``cov_uu, cov_uv, cov_vv`` (px^2). Comment lines
  ``# view K: NAME WxH`` give view K a name and image size (both optional); other ``#``
  lines and blank lines are skipped. Views come out in the order of their index.
* **NPZ**: ``view`` (N,) int, ``pixels`` (N, 2), ``points`` (N, 3), optionally
  ``cov_uu, cov_uv, cov_vv`` (N,), ``names`` (V,) str and ``image_size`` (V, 2) int,
  one row per view in the order of the indices.

Every reader error is an :class:`~bayescal.errors.InputError` naming the file, the line
(or array index) and the column.
"""

from __future__ import annotations

import os
import pathlib
import re

import numpy as np

from ..errors import InputError
from ..image.views import BoardView, as_views
from .tables import PIXEL_COV_COLUMNS, read_table

__all__ = ["load_views", "write_views", "BOARD_COLUMNS"]

#: the required columns of a corners file
BOARD_COLUMNS = ("view", "u", "v", "x", "y", "z")
_COMMENT = re.compile(r"^#\s*view\s+(\d+)\s*:\s*(.*?)\s*(?:(\d+)\s*x\s*(\d+))?\s*$")


def _csv_meta(path):
    """View names and image sizes from ``# view K: NAME WxH`` comment lines."""
    meta = {}
    with open(path, encoding="utf-8-sig") as f:
        for line in f:
            m = _COMMENT.match(line.strip())
            if m:
                size = (int(m.group(3)), int(m.group(4))) if m.group(3) else None
                meta[int(m.group(1))] = (m.group(2) or None, size)
    return meta


def _npz_meta(path, n_views):
    with np.load(path, allow_pickle=False) as z:
        names = [str(s) for s in z["names"]] if "names" in z.files else [None] * n_views
        sizes = z["image_size"] if "image_size" in z.files else None
    if len(names) != n_views or (sizes is not None and np.shape(sizes) != (n_views, 2)):
        raise InputError(f"{path}: 'names' and 'image_size' must have one row per view "
                         f"({n_views}), got {len(names)} and {np.shape(sizes)}",
                         path=str(path), column="names")
    return {k: (names[k], None if sizes is None else tuple(int(s) for s in sizes[k]))
            for k in range(n_views)}


def _covariances(table, rows):
    c = table.columns
    if not all(n in c for n in PIXEL_COV_COLUMNS):
        if any(n in c for n in PIXEL_COV_COLUMNS):
            raise InputError(f"{table.path}: give all of {', '.join(PIXEL_COV_COLUMNS)} or none",
                             path=str(table.path), column=PIXEL_COV_COLUMNS[0])
        return None
    uu, uv, vv = (c[n][rows] for n in PIXEL_COV_COLUMNS)
    bad = (uu <= 0) | (vv <= 0) | (uu * vv - uv * uv <= 0)
    if np.any(bad):
        k = int(rows[np.argmax(bad)])
        raise table.error(k, "cov_uu", "the pixel covariance (cov_uu, cov_uv, cov_vv) is not "
                          "positive definite; expected cov_uu > 0, cov_vv > 0, "
                          "cov_uu * cov_vv > cov_uv^2 (px^2)")
    return np.stack([np.stack([uu, uv], -1), np.stack([uv, vv], -1)], -2)


def _view_index(table):
    view = table.columns["view"]
    bad = (view != np.round(view)) | (view < 0)
    if np.any(bad):
        k = int(np.argmax(bad))
        raise table.error(k, "view", f"{view[k]:g} is not a view index; expected an integer >= 0")
    return view.astype(int)


def load_views(path):
    """Read a set of board views from a CSV or NPZ file of corners.

    Parameters
    ----------
    path : str or os.PathLike
        ``.npz`` is read as NPZ, anything else as CSV (format: module docstring).

    Returns
    -------
    list of BoardView
        One per view index, in increasing order; ``name`` from the file or
        ``"<file> view K"``.

    Raises
    ------
    InputError
        A missing file or column, a cell that is not a number, a covariance that is not
        positive definite, or a view with fewer than 4 corners (naming file and line).
    """
    path = pathlib.Path(path)
    table = read_table(path, required=BOARD_COLUMNS, optional=PIXEL_COV_COLUMNS)
    view = _view_index(table)
    ids = np.unique(view)
    meta = _npz_meta(path, len(ids)) if table.kind == "npz" else _csv_meta(path)
    c = table.columns
    views = []
    for j, k in enumerate(ids):
        rows = np.flatnonzero(view == k)
        name, size = meta.get(j if table.kind == "npz" else int(k), (None, None))
        name = name or f"{path.name} view {k}"
        try:
            views.append(BoardView(np.column_stack([c["u"][rows], c["v"][rows]]),
                                   np.column_stack([c["x"][rows], c["y"][rows], c["z"][rows]]),
                                   _covariances(table, rows), name=name, image_size=size))
        except InputError:
            raise
        except ValueError as exc:
            raise table.error(int(rows[0]), "view", str(exc)) from None
    return views


def write_views(path, views):
    """Write board views in the format :func:`load_views` reads (by suffix: NPZ or CSV).

    Parameters
    ----------
    path : str or os.PathLike
        ``.npz`` or ``.csv``.
    views : sequence of BoardView

    Returns
    -------
    pathlib.Path
    """
    path = pathlib.Path(os.fspath(path))
    views = as_views(views)
    index = np.concatenate([np.full(v.n_corners, k) for k, v in enumerate(views)])
    pixels = np.concatenate([v.pixels for v in views])
    points = np.concatenate([v.points for v in views])
    has_cov = all(v.covariance is not None for v in views)
    cov = np.concatenate([v.covariance for v in views]) if has_cov else None
    if path.suffix.lower() == ".npz":
        arrays = {"view": index, "pixels": pixels, "points": points,
                  "names": np.array([v.name for v in views])}
        if all(v.image_size is not None for v in views):
            arrays["image_size"] = np.array([v.image_size for v in views])
        if has_cov:
            arrays.update(cov_uu=cov[:, 0, 0], cov_uv=cov[:, 0, 1], cov_vv=cov[:, 1, 1])
        np.savez(path, **arrays)
        return path
    with open(path, "w", encoding="utf-8", newline="") as f:
        for k, v in enumerate(views):
            size = "" if v.image_size is None else f" {v.image_size[0]}x{v.image_size[1]}"
            f.write(f"# view {k}: {v.name}{size}\n")
        names = list(BOARD_COLUMNS) + (list(PIXEL_COV_COLUMNS) if has_cov else [])
        f.write(",".join(names) + "\n")
        for i in range(len(index)):
            row = [str(index[i])] + [repr(float(a)) for a in (*pixels[i], *points[i])]
            if has_cov:
                row += [repr(float(a)) for a in (cov[i, 0, 0], cov[i, 0, 1], cov[i, 1, 1])]
            f.write(",".join(row) + "\n")
    return path
