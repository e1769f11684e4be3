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

from ..errors import InvalidValueError, MissingDependencyError
from .read import as_gray, read_image
from .views import BoardView, board_points, board_shape

__all__ = ["find_chessboard", "order_corners"]

_METHODS = ("classic", "sb")


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
                    center=None, name=None):
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
    return BoardView(pixels, points, name=default_name if name is None else str(name),
                     image_size=(w, h))
