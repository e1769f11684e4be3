"""Chessboard corners in an image: OpenCV's detector, refined to sub-pixel, in a fixed order.

The detection is OpenCV's (``cv2.findChessboardCorners``, then ``cv2.cornerSubPix``), an
optional dependency (``pip install bayescal[camera]``): a detector that decades of
calibrations have exercised on blur, glare and distorted boards is worth more than a new one.
When it finds no board, ``cv2.findChessboardCornersSB`` (which copes with more blur) finds
it and ``cornerSubPix`` refines its corners the same way. The sector-based detector's own
sub-pixel corners are available as ``method="sb"``; ``docs/camera_images.md`` compares the
two on rendered and real catadioptric views.

The grid of inner corners looks the same turned by 180 degrees (with an even number of
corners each way, such as 8 x 6, so does the printed board), and OpenCV lists the corners
in either direction. :func:`find_chessboard` fixes the order: the first row of corners is
the one farther from the image centre (in a catadioptric image, radially outwards is
upwards in the room, so a board held upright has its first row at the top in every view).
"""

from __future__ import annotations

import os

import numpy as np

from ..errors import BayescalWarning, InvalidValueError, MissingDependencyError
from .read import as_gray, read_image
from .views import BoardView, board_points, board_shape

__all__ = ["find_chessboard", "order_corners", "board_extent", "JUNCTION_F2", "JUNCTION_AMP",
           "ROW_FRACTION"]

_METHODS = ("classic", "sb")

#: a point is a board corner (where two dark and two light squares meet) when, on a circle of
#: 0.3 x the local corner spacing about it, the second angular harmonic holds at least this
#: fraction of the grey levels' variance (harmonics 1-15 of 32 samples). Measured on the five
#: real views of docs/camera_images.md and five renders, 10th-90th percentiles over the points
#: of each view: the corners OpenCV found 0.71-0.98, corners it skipped (a 6x4 search on the
#: 8x6 board finds every other row) 0.58-0.96; points that are no corner: halfway between
#: two found corners (on a square's edge) 0.00-0.19, one spacing past a whole board's edge
#: (an outer square's outer corner, one dark quadrant: 0.29 in theory) 0.00-0.59
JUNCTION_F2 = 0.6
#: ... and its second-harmonic amplitude is at least this fraction of the found corners'
#: median (a corner of the same contrast; an outer square's outer corner has 0.5 in theory)
JUNCTION_AMP = 0.3
#: a row of candidate corners (between two found rows, or past the lattice's edge, each point
#: first moved to the nearest corner by cornerSubPix) is part of the board when at least this
#: fraction of its points pass: on the views above the rows that are had 0.94-1.00 (one
#: row at the edge of the most foreshortened view 0.50-0.67: that view's size comes out one
#: row short), the rows that are not at most 0.38
ROW_FRACTION = 2.0 / 3.0
#: radius of the test circle over the local corner spacing (below 0.5: the circle stays
#: inside the four squares about a corner)
_RING = 0.3
_N_RING = 32


def _cv2():
    try:
        import cv2
    except ImportError:
        raise MissingDependencyError(
            "find_chessboard needs OpenCV: pip install bayescal[camera] "
            "(installs opencv-contrib-python-headless)"
        ) from None
    return cv2


def _load(image):
    """A 2-D float image and a name for it."""
    if isinstance(image, (str, os.PathLike)):
        return read_image(image), os.path.basename(os.fspath(image))
    arr = np.asarray(image)
    if arr.ndim == 3 and arr.shape[2] >= 3 and np.issubdtype(arr.dtype, np.number):
        arr = arr[..., :3].astype(float).mean(axis=2)     # luminance, not one channel
    return as_gray(arr, name="image"), "image"


def _to_uint8(gray):
    lo, hi = np.percentile(gray, [0.5, 99.5])
    if hi <= lo:
        return None
    return np.clip((gray - lo) * (255.0 / (hi - lo)), 0, 255).astype(np.uint8)


def order_corners(pixels, board, *, center):
    """Put a board's corners in the fixed order of :func:`find_chessboard`.

    Parameters
    ----------
    pixels : array_like, shape (columns * rows, 2)
        Corners row by row (x fastest), in either of the two 180-degree-related orders.
    board : tuple of int
        ``(columns, rows)`` of inner corners.
    center : array_like, shape (2,)
        The point (px) the rows are compared against, e.g. the image centre.

    Returns
    -------
    ndarray, shape (columns * rows, 2)
        The corners, reversed if the last row is farther from ``center`` than the first.
    """
    nx, ny = board_shape(board)
    px = np.asarray(pixels, dtype=float).reshape(ny, nx, 2)
    c = np.asarray(center, dtype=float)
    first = np.linalg.norm(px[0] - c, axis=-1).mean()
    last = np.linalg.norm(px[-1] - c, axis=-1).mean()
    out = px.reshape(-1, 2)
    return out[::-1].copy() if last > first else out.copy()


def _window(corners, nx, ny):
    """Half-size of cornerSubPix's window: half the short corner spacing, 2-5 px.

    The short spacing is the 10th percentile of the distances between neighbouring
    corners (robust to one misplaced coarse corner): a wider window reaches the next
    corner's edges, a narrower one averages fewer pixels.
    """
    g = corners.reshape(ny, nx, 2)
    gaps = np.concatenate([np.linalg.norm(np.diff(g, axis=0), axis=-1).ravel(),
                           np.linalg.norm(np.diff(g, axis=1), axis=-1).ravel()])
    return int(np.clip(np.percentile(gaps, 10) // 2, 2, 5))


def _sector_based(cv2, img8, nx, ny):
    flags = cv2.CALIB_CB_EXHAUSTIVE + cv2.CALIB_CB_ACCURACY
    found, corners = cv2.findChessboardCornersSB(img8, (nx, ny), flags=flags)
    return corners.reshape(-1, 2).astype(float) if found else None


def _detect(cv2, img8, gray, nx, ny, method, window):
    """Corners (M, 2) px or None: SB's own, or found (classic, else SB) and refined."""
    if method == "sb":
        return _sector_based(cv2, img8, nx, ny)
    flags = cv2.CALIB_CB_ADAPTIVE_THRESH + cv2.CALIB_CB_NORMALIZE_IMAGE
    found, corners = cv2.findChessboardCorners(img8, (nx, ny), flags=flags)
    corners = corners.reshape(-1, 2) if found else _sector_based(cv2, img8, nx, ny)
    if corners is None:
        return None
    w = _window(corners, nx, ny) if window is None else int(window)
    crit = (cv2.TERM_CRITERIA_EPS + cv2.TERM_CRITERIA_MAX_ITER, 100, 1e-4)
    refined = cv2.cornerSubPix(gray.astype(np.float32),
                               corners.reshape(-1, 1, 2).astype(np.float32), (w, w), (-1, -1),
                               crit)
    return refined.reshape(-1, 2).astype(float)


def find_chessboard(image, board=(8, 6), square=42.0, *, method="classic", window=None,
                    center=None, name=None, check_extent=True):
    """Find a chessboard's inner corners in an image, to sub-pixel.

    Parameters
    ----------
    image : str, os.PathLike or array_like, shape (H, W) or (H, W, C)
        An image file (PGM, PNG, TIFF, JPEG; 8 or 16 bit) or its grey levels; a colour
        image is reduced to the mean of its colour channels.
    board : tuple of int, optional
        ``(columns, rows)`` of inner corners.
    square : float, optional
        Side of one square, mm.
    method : {"classic", "sb"}, optional
        ``"classic"``: ``cv2.findChessboardCorners`` (or, when it finds no board,
        ``cv2.findChessboardCornersSB``, which copes with more blur), then
        ``cv2.cornerSubPix``; ``"sb"``: ``cv2.findChessboardCornersSB``'s own sub-pixel
        corners (accuracy flag; slower, and more biased on catadioptric boards).
    window : int, optional
        Half-size of ``cornerSubPix``'s window, px (classic only). Default: half the short
        corner spacing (10th percentile of the neighbour distances), between 2 and 5.
    center : array_like, shape (2,), optional
        Point the corner order is fixed against (see :func:`order_corners`), px.
        Default: the image centre ``((W - 1) / 2, (H - 1) / 2)``.
    name : str, optional
        Name of the view (default: the file's base name, or ``"image"``).
    check_extent : bool, optional
        Warn (:class:`~bayescal.BayescalWarning`) when the board's lattice goes on past the
        corners found (:func:`board_extent`): ``board`` smaller than the board, whose corners
        then belong to other board points than :func:`board_points` gives them.

    Returns
    -------
    BoardView or None
        ``pixels`` (M, 2) px and ``points`` (M, 3) mm (:func:`board_points` order, z = 0),
        ``image_size`` ``(W, H)``; None when no complete board is found.

    Raises
    ------
    ImportError
        If OpenCV is not installed (``pip install bayescal[camera]``).
    FileNotFoundError, ValueError
        If the image cannot be read or is not an image.
    """
    nx, ny = board_shape(board)
    points = board_points((nx, ny), square)
    if method not in _METHODS:
        raise InvalidValueError(f"method must be one of {_METHODS}, got {method!r}")
    if window is not None and int(window) < 1:
        raise InvalidValueError(f"window must be a positive half-size in px, got {window!r}")
    cv2 = _cv2()
    gray, default_name = _load(image)
    h, w = gray.shape
    img8 = _to_uint8(gray)
    if img8 is None:
        return None
    corners = _detect(cv2, img8, gray, nx, ny, method, window)
    if corners is None or len(corners) != nx * ny or not np.all(np.isfinite(corners)):
        return None
    c = ((w - 1) / 2.0, (h - 1) / 2.0) if center is None else center
    pixels = order_corners(corners, (nx, ny), center=c)
    view = BoardView(pixels, points, name=default_name if name is None else str(name),
                     image_size=(w, h))
    if check_extent:
        seen = _extent(gray, view)
        if seen != (nx, ny):
            import warnings

            warnings.warn(f"{view.name}: the chessboard goes on past the {nx}x{ny} inner corners "
                          f"found: {seen[0]}x{seen[1]} seen; pass board={seen} (a board "
                          "smaller than the real one gives its corners the wrong board points)",
                          BayescalWarning, stacklevel=2)
    return view


def _harmonic(gray, points, radius):
    """Second angular harmonic of the grey levels on a circle about each point.

    Returns ``(fraction of the variance in it, its amplitude)``, each of the points' shape;
    points whose circle leaves the image get ``(0, 0)``.
    """
    pts = np.asarray(points, float)
    r = np.broadcast_to(np.asarray(radius, float), pts.shape[:-1])
    ang = 2.0 * np.pi * np.arange(_N_RING) / _N_RING
    x = pts[..., 0, None] + r[..., None] * np.cos(ang)
    y = pts[..., 1, None] + r[..., None] * np.sin(ang)
    h, w = gray.shape
    inside = np.all((x >= 0) & (x <= w - 1) & (y >= 0) & (y <= h - 1), axis=-1) & (r >= 1.0)
    x0 = np.clip(np.floor(x).astype(int), 0, w - 2)
    y0 = np.clip(np.floor(y).astype(int), 0, h - 2)
    fx, fy = np.clip(x - x0, 0, 1), np.clip(y - y0, 0, 1)
    ring = ((1 - fy) * ((1 - fx) * gray[y0, x0] + fx * gray[y0, x0 + 1])
            + fy * ((1 - fx) * gray[y0 + 1, x0] + fx * gray[y0 + 1, x0 + 1]))
    spec = np.fft.rfft(ring - ring.mean(axis=-1, keepdims=True), axis=-1)
    power = np.abs(spec[..., 1:_N_RING // 2]) ** 2
    total = power.sum(axis=-1)
    frac = np.where(inside & (total > 0), power[..., 1] / np.maximum(total, 1e-300), 0.0)
    return frac, np.where(inside, np.abs(spec[..., 2]), 0.0)


def _spacing(rows):
    """Distance of each point (..., n, 2) to its nearer neighbour along the last point axis."""
    d = np.linalg.norm(np.diff(rows, axis=-2), axis=-1)
    return np.minimum(np.concatenate([d[..., :1], d], axis=-1),
                      np.concatenate([d, d[..., -1:]], axis=-1))


def _snap(gray, points, radius):
    """``points`` (n, 2) moved to the nearest corner-like point by ``cv2.cornerSubPix`` within
    ``radius`` (n,) px (a point moved farther than that, or off the image, is kept)."""
    cv2 = _cv2()
    out = np.array(points, float)
    h, w = gray.shape
    img = gray.astype(np.float32)
    crit = (cv2.TERM_CRITERIA_EPS + cv2.TERM_CRITERIA_MAX_ITER, 30, 1e-3)
    for k, (p, r) in enumerate(zip(out, radius, strict=True)):
        win = int(np.clip(round(r), 2, 10))
        if not (win < p[0] < w - 1 - win and win < p[1] < h - 1 - win):
            continue
        q = cv2.cornerSubPix(img, p.reshape(1, 1, 2).astype(np.float32), (win, win),
                             (-1, -1), crit).reshape(2)
        if np.all(np.isfinite(q)) and np.linalg.norm(q - p) <= r:
            out[k] = q
    return out


def _corners_at(gray, points, across, amp0):
    """Which of ``points`` (..., n, 2) (rows of n) are board corners, and the points snapped
    to them; ``across`` (..., n) the spacing to the neighbouring row, px."""
    radius = _RING * np.minimum(_spacing(points), across)
    points = _snap(gray, points.reshape(-1, 2), radius.ravel()).reshape(points.shape)
    frac, amp = _harmonic(gray, points, radius)
    return (frac >= JUNCTION_F2) & (amp >= JUNCTION_AMP * amp0), points


def _subdivide(gray, g, amp0):
    """The lattice ``g`` (rows, columns, 2) with its rows split where corners lie between them
    (a detection that skipped every other or every third row); one axis at a time."""
    for m in (2, 3):
        step = np.linalg.norm(np.diff(g, axis=0), axis=-1) / m
        between, found = [], []
        for j in range(1, m):
            ok, row = _corners_at(gray, g[:-1] + (j / m) * (g[1:] - g[:-1]), step, amp0)
            found.append(ok.ravel())
            between.append(row)
        if np.concatenate(found).mean() >= ROW_FRACTION:
            fine = np.empty(((len(g) - 1) * m + 1,) + g.shape[1:])
            fine[::m] = g
            for j, b in enumerate(between, 1):
                fine[j::m] = b
            return fine
    return g


def _extend(gray, g, amp0, max_rows=50):
    """How many rows of corners the lattice ``g`` (rows, columns, 2) continues by past its
    last row (each new row extrapolated from the last two and tested)."""
    last, prev, n = g[-1], g[-2], 0
    while n < max_rows:
        new = 2.0 * last - prev
        ok, new = _corners_at(gray, new, np.linalg.norm(new - last, axis=-1), amp0)
        if ok.mean() < ROW_FRACTION:
            break
        last, prev, n = new, last, n + 1
    return n


def board_extent(image, view):
    """The size of the chessboard lattice a view's corners belong to.

    A board option smaller than the board makes OpenCV find part of it: a smaller board
    inside it, or every other row. Both leave corners that the view does not hold: between
    its rows or columns, or past its edge along its own lattice. This counts them, with a
    test of the grey levels about each candidate point (:data:`JUNCTION_F2`,
    :data:`JUNCTION_AMP`, :data:`ROW_FRACTION`; ``docs/camera_images.md``).

    Parameters
    ----------
    image : str, os.PathLike or array_like, shape (H, W) or (H, W, C)
        The image the view was found in.
    view : BoardView
        Its corners in :func:`find_chessboard`'s order (a whole board of ``board_points``).

    Returns
    -------
    tuple of int
        ``(columns, rows)`` of inner corners the lattice shows, in the view's own order:
        the view's board when it is the whole board.
    """
    return _extent(_load(image)[0], view)


def _extent(gray, view):
    """:func:`board_extent` on a grey image."""
    xs, ys = np.unique(view.points[:, 0]), np.unique(view.points[:, 1])
    nx, ny = len(xs), len(ys)
    if nx * ny != view.n_corners:
        raise InvalidValueError(f"{view.name}: the view's {view.n_corners} corners are not a "
                                "whole board; expected find_chessboard's corners")
    g = view.pixels.reshape(ny, nx, 2)
    across = np.minimum(_spacing(np.swapaxes(g, 0, 1)).T, _spacing(g))
    _, amp = _harmonic(gray, g, _RING * across)
    amp0 = float(np.median(amp))
    g = np.swapaxes(_subdivide(gray, np.swapaxes(_subdivide(gray, g, amp0), 0, 1), amp0), 0, 1)
    rows = len(g) + _extend(gray, g, amp0) + _extend(gray, g[::-1], amp0)
    gt = np.swapaxes(g, 0, 1)
    cols = len(gt) + _extend(gray, gt, amp0) + _extend(gray, gt[::-1], amp0)
    return int(cols), int(rows)
