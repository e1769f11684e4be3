"""A chessboard seen by the camera: one view's corners in the image and on the board.

A :class:`BoardView` is to the camera what laser pixels and their approximate 3D points
are to the sensor: pixels, and the points they image, in a frame of their own (the
board's), with an unknown pose per view. It is plain data: it comes from an image
(:func:`bayescal.find_chessboard`), from a file of corners, or from a simulation, and
goes into :func:`bayescal.calibrate_camera`.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from .._validation import as_pixels, as_points
from ..errors import InvalidTypeError, InvalidValueError

__all__ = ["BoardView", "board_points", "board_shape", "as_views"]


def board_shape(board):
    """``(columns, rows)`` of inner corners as ints, checked (at least 2 x 2)."""
    try:
        nx, ny = (int(b) for b in board)
    except (TypeError, ValueError):
        raise InvalidTypeError(
            f"board must be a pair of ints (columns, rows), got {board!r}") from None
    if nx < 2 or ny < 2:
        raise InvalidValueError(f"board must have at least 2 x 2 inner corners, got {board!r}")
    return nx, ny


def board_points(board, square):
    """The inner corners of a chessboard in its own frame.

    Parameters
    ----------
    board : tuple of int
        ``(columns, rows)`` of inner corners, e.g. ``(8, 6)``.
    square : float
        Side of one square, mm.

    Returns
    -------
    ndarray, shape (columns * rows, 3)
        Corner positions in mm, row by row (x fastest), z = 0; the order in which
        OpenCV's ``findChessboardCorners`` lists them.
    """
    nx, ny = board_shape(board)
    s = float(square)
    if not np.isfinite(s) or s <= 0:
        raise InvalidValueError(f"square must be a positive size in mm, got {square!r}")
    j, i = np.mgrid[0:ny, 0:nx]
    return np.stack([i.ravel() * s, j.ravel() * s, np.zeros(nx * ny)], axis=-1)


@dataclass(frozen=True)
class BoardView:
    """One view of a calibration board.

    Parameters
    ----------
    pixels : array_like, shape (M, 2)
        Detected corners ``(u, v)``, px.
    points : array_like, shape (M, 3)
        The same corners in the board's frame, mm (usually z = 0).
    covariance : array_like, shape (M, 2, 2), optional
        Per-corner pixel covariance, px^2, if the detector gives one.
    name : str
        Where the view comes from (an image's file name), used in messages.
    image_size : tuple of int, optional
        ``(width, height)`` of the image in px.

    Raises
    ------
    ValueError
        If the shapes disagree, a value is not finite, or there are fewer than
        4 corners.
    """

    pixels: np.ndarray
    points: np.ndarray
    covariance: np.ndarray | None = None
    name: str = "view"
    image_size: tuple | None = field(default=None)

    def __post_init__(self):
        px = as_pixels(self.pixels, f"pixels of {self.name}")
        pt = as_points(self.points, f"points of {self.name}")
        if px.ndim != 2 or pt.ndim != 2 or len(px) != len(pt):
            raise InvalidValueError(
                f"{self.name}: pixels must have shape (M, 2) and points (M, 3) with the same M, "
                f"got {px.shape} and {pt.shape}"
            )
        if len(px) < 4:
            raise InvalidValueError(f"{self.name}: a view needs at least 4 corners, got {len(px)}")
        object.__setattr__(self, "pixels", px)
        object.__setattr__(self, "points", pt)
        if self.covariance is not None:
            cov = np.asarray(self.covariance, dtype=float)
            if cov.shape != (len(px), 2, 2) or not np.all(np.isfinite(cov)):
                raise InvalidValueError(
                    f"{self.name}: covariance must be finite with shape ({len(px)}, 2, 2), "
                    f"got shape {cov.shape}"
                )
            object.__setattr__(self, "covariance", cov)
        if self.image_size is not None:
            size = tuple(int(s) for s in self.image_size)
            if len(size) != 2 or min(size) <= 0:
                raise InvalidValueError(
                    f"{self.name}: image_size must be (width, height) > 0, got {self.image_size!r}"
                )
            object.__setattr__(self, "image_size", size)

    @property
    def n_corners(self):
        """Number of corners, M."""
        return len(self.pixels)

    def subset(self, index, *, name=None):
        """The view restricted to some corners (cross-validation, held-out corners).

        Parameters
        ----------
        index : array_like of int or bool
            Corners to keep.
        name : str, optional
            Name of the new view (default: this one's).
        """
        idx = np.asarray(index)
        cov = None if self.covariance is None else self.covariance[idx]
        return BoardView(self.pixels[idx], self.points[idx], cov,
                         name=self.name if name is None else name, image_size=self.image_size)


def as_views(views):
    """A non-empty list of :class:`BoardView` from one view or a sequence of them.

    Raises
    ------
    TypeError
        Anything else, naming what was given, or the first element that is not a view (a
        None: an image where :func:`~bayescal.find_chessboard` found no board).
    """
    given = type(views).__name__
    if isinstance(views, BoardView):
        return [views]
    try:
        views = list(views)
    except TypeError:
        views = []
    if not views:
        raise InvalidTypeError(f"views must be a non-empty sequence of BoardView, got {given}")
    bad = [k for k, v in enumerate(views) if not isinstance(v, BoardView)]
    if bad:
        k = bad[0]
        why = (" (find_chessboard returns None for an image where it finds no whole board: "
               "leave that image out)" if views[k] is None else "")
        raise InvalidTypeError(f"views[{k}] is {type(views[k]).__name__}, not a BoardView"
                               f"{why}; {len(bad)} of the {len(views)} views are not"
                               + (f": indices {', '.join(map(str, bad))}" if len(bad) > 1
                                  else ""))
    return views
