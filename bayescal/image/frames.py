"""Sequences of camera frames: a folder of images, a list of files or arrays, a video file.

:func:`iter_frames` yields each frame with a name (a file's stem, ``frame_00012`` of a
video, ``frame 12`` of an array), read as :func:`~bayescal.image.read.read_image` reads an
image for the extractor (the file's own type and colour channels). A video is decoded
through imageio's PyAV plugin, an optional extra (``pip install bayescal[video]``).
"""

from __future__ import annotations

import os
import pathlib

import numpy as np

from ..errors import (
    InvalidTypeError,
    InvalidValueError,
    MissingDependencyError,
    MissingFileError,
)
from .read import read_image

__all__ = ["iter_frames", "frame_names", "count_frames", "VIDEO_SUFFIXES", "FRAME_SUFFIXES"]

#: file suffixes read as video (decoded by imageio's PyAV plugin)
VIDEO_SUFFIXES = (".mp4", ".avi", ".mkv", ".mov", ".webm", ".m4v", ".mpg", ".mpeg")
#: file suffixes of a frame in a folder of frames
FRAME_SUFFIXES = (".png", ".tif", ".tiff", ".jpg", ".jpeg")


def _is_pathlike(x):
    return isinstance(x, (str, os.PathLike))


def _folder_frames(folder):
    files = sorted(p for p in folder.iterdir()
                   if p.is_file() and p.suffix.lower() in FRAME_SUFFIXES)
    if not files:
        raise InvalidValueError(f"folder {str(folder)!r} holds no image "
                                f"({', '.join(FRAME_SUFFIXES)}) to read as frames")
    return files


def _expand(frames):
    """A folder, a video file or an image file, or an iterable of frames, as a list of
    paths and arrays, or a video's path (a str); every path checked to exist."""
    if _is_pathlike(frames):
        path = pathlib.Path(frames)
        if path.is_dir():
            return _folder_frames(path)
        if not path.is_file():
            raise MissingFileError(f"frames {str(path)!r}: no such file or folder")
        return str(path) if path.suffix.lower() in VIDEO_SUFFIXES else [path]
    if isinstance(frames, np.ndarray) and (frames.ndim == 2 or
                                           (frames.ndim == 3 and frames.shape[2] <= 4)):
        raise InvalidTypeError(f"frames must be a sequence of images, a folder or a video "
                               f"file, got one image of shape {frames.shape}: pass [image]")
    try:
        items = iter(frames)
    except TypeError:
        raise InvalidTypeError(f"frames must be a sequence of images (arrays or paths), a "
                               f"folder or a video file, got {type(frames).__name__}") from None
    return items


def frame_names(frames):
    """The names :func:`iter_frames` gives, when known without reading (a folder or a list
    of paths); None for a video or arrays."""
    items = _expand(frames)
    if isinstance(items, list) and all(_is_pathlike(p) for p in items):
        return [pathlib.Path(p).stem for p in items]
    return None


def count_frames(frames):
    """The number of frames, when known without decoding them (a folder, a list, a video
    whose container says); None otherwise."""
    items = _expand(frames)
    if isinstance(items, str):
        return _video_length(items)
    if isinstance(items, list):
        return len(items)
    try:
        return len(frames)
    except TypeError:
        return None


def iter_frames(frames, *, channel=0):
    """Yield ``(name, image)`` for each frame of ``frames``, in order.

    Parameters
    ----------
    frames : str, os.PathLike or iterable
        A folder (its PNG, TIFF and JPEG files in the order of their names), a video file
        (:data:`VIDEO_SUFFIXES`), one image file, or an iterable of images: arrays of shape
        (H, W) or (H, W, C), or paths of image files.
    channel : int, optional
        The laser's colour channel: a file must have it.

    Yields
    ------
    name : str
    image : ndarray, shape (H, W) or (H, W, C)
        As the file holds it (its integer type and colour channels kept).

    Raises
    ------
    MissingFileError, InvalidValueError, InvalidTypeError
        A file that does not exist or cannot be read, an empty folder, a frame that is no
        image; :class:`~bayescal.errors.MissingDependencyError` when a video needs
        PyAV, which is not installed.
    """
    items = _expand(frames)
    if isinstance(items, str):
        yield from _video_frames(items)
        return
    for i, item in enumerate(items):
        if _is_pathlike(item):
            yield pathlib.Path(item).stem, read_image(item, channel=channel, raw=True)
        else:
            arr = np.asarray(item)
            if arr.ndim not in (2, 3):
                raise InvalidValueError(f"frame {i} must be an image of shape (H, W) or "
                                        f"(H, W, C), got shape {arr.shape}")
            yield f"frame {i}", arr


def _imageio_video():
    """imageio's v3 interface once PyAV is known to be there."""
    try:
        import av  # noqa: F401
    except ImportError:
        raise MissingDependencyError("reading a video file needs PyAV: pip install "
                                     "'bayescal[video]' (or extract the frames to a folder "
                                     "of PNG files)") from None
    import imageio.v3 as iio

    return iio


def _video_frames(path):
    iio = _imageio_video()
    stem = pathlib.Path(path).stem
    try:
        for i, frame in enumerate(iio.imiter(path, plugin="pyav")):
            yield f"{stem}_{i:05d}", np.asarray(frame)
    except (OSError, ValueError, RuntimeError) as exc:
        raise InvalidValueError(f"cannot read video {path!r}: {exc}") from None


def _video_length(path):
    iio = _imageio_video()
    try:
        n = iio.improps(path, plugin="pyav").n_images
    except Exception:  # PyAV raises several types for a container it cannot measure
        return None
    return int(n) if n is not None and np.isfinite(n) and n > 0 else None
