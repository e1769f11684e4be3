"""Sequences of camera frames: a folder of images, a list of files or arrays, a video file;
one frame's laser pixels as the ring tracker returns them (:class:`TrackedPixels`), and two
extractions of one frame compared (:func:`agreement`).

:func:`iter_frames` yields each frame with a name (a file's stem, ``frame_00012`` of a
video, ``frame 12`` of an array), read as :func:`~bayescal.image.read.read_image` reads an
image for the extractor (the file's own type and colour channels). A video is decoded
through imageio's PyAV plugin, an optional extra (``pip install bayescal[video]``).
"""

from __future__ import annotations

import itertools
import os
import pathlib
from dataclasses import dataclass, fields

import numpy as np

from ..errors import (
    ExtractionError,
    InvalidTypeError,
    InvalidValueError,
    MissingDependencyError,
    MissingFileError,
)
from .extract import LaserPixels
from .read import read_image

__all__ = ["iter_frames", "frame_names", "count_frames", "as_frame", "per_frame",
           "TrackedPixels", "agreement",
           "VIDEO_SUFFIXES", "FRAME_SUFFIXES"]

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
    if isinstance(frames, (list, tuple)):
        return list(frames)
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


def as_frame(image):
    """An image given as a path, read as the file holds it; an array or None as it is."""
    return read_image(image, raw=True) if _is_pathlike(image) else image


def per_frame(image):
    """One image per frame: None or one image (or path) for every frame, or the items of a
    sequence of them."""
    single = image is None or isinstance(image, np.ndarray) or _is_pathlike(image)
    yield from itertools.repeat(image) if single else image


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


@dataclass(frozen=True)
class TrackedPixels(LaserPixels):
    """One frame's laser pixels (as :class:`~bayescal.image.extract.LaserPixels`) and how
    they were found.

    Attributes
    ----------
    tracked : bool
        True: followed from the previous frame's ring; False: the full extractor ran (the
        first frame, a frame after a refused one, or one where the tracker lost the ring).
    name : str
        The frame's name (a file's stem, ``frame 3``).
    note : str
        Why the full extractor ran (``first frame``, ``lost: ...``); empty when tracked.
    error : ExtractionError or None
        The full extractor's refusal: the frame has no points then (``len == 0``).
    """

    tracked: bool = False
    name: str = ""
    note: str = ""
    error: ExtractionError | None = None

    @property
    def refused(self):
        """bool: the extractor refused the frame (no points; see :attr:`error`)."""
        return self.error is not None

    @classmethod
    def of(cls, lp, **kw):
        """A :class:`LaserPixels` with the tracker's attributes ``kw``."""
        return cls(**{f.name: getattr(lp, f.name) for f in fields(LaserPixels)}, **kw)

    @classmethod
    def refusal(cls, error, **kw):
        """An empty frame that carries the extractor's ``error``."""
        return cls(pixels=np.zeros((0, 2)), covariance=np.zeros((0, 2, 2)), snr=np.zeros(0),
                   flagged=np.zeros(0, bool), center=np.full(2, np.nan), error=error, **kw)


def agreement(a, b, *, along_px=1.5):
    """How far two extractions of one frame agree, point by point (the tracker's against
    the full extractor's, ``docs/images.md``).

    Each point of ``a`` is paired with the point of ``b`` nearest to it if it lies within
    ``along_px`` of it along the ring; a pair's difference is taken along ``b``'s normal
    (the direction of its covariance's smaller eigenvalue: along the ring a point's place
    is the chosen azimuth of its profile, not a measurement).

    Parameters
    ----------
    a, b : LaserPixels
    along_px : float, optional

    Returns
    -------
    dict
        ``pairs`` (points unflagged in both and paired), ``diff_px`` (their differences
        along the normal, px), ``sd_ratio`` (``a``'s sd along the normal over ``b``'s),
        ``only_a`` and ``only_b`` (paired points unflagged in one only), ``unpaired``.
    """
    if len(a) == 0 or len(b) == 0:
        return dict(pairs=0, diff_px=np.zeros(0), sd_ratio=np.zeros(0), only_a=0, only_b=0,
                    unpaired=len(a))
    db = b.pixels - b.center
    ab = np.arctan2(db[:, 1], db[:, 0])
    order = np.argsort(ab)
    da = a.pixels - b.center
    aa = np.arctan2(da[:, 1], da[:, 0])
    pos = np.searchsorted(ab[order], aa)
    cand = order[np.stack([(pos - 1) % len(b), pos % len(b)], -1)]
    dist = np.linalg.norm(a.pixels[:, None] - b.pixels[cand], axis=-1)
    j = cand[np.arange(len(a)), np.argmin(dist, axis=1)]
    w, v = np.linalg.eigh(b.covariance[j])
    normal = v[..., 0]
    delta = a.pixels - b.pixels[j]
    across = np.abs(np.sum(delta * normal, axis=1))
    paired = np.hypot(*delta.T) ** 2 - across ** 2 <= along_px ** 2
    both = paired & ~a.flagged & ~b.flagged[j]
    return dict(pairs=int(both.sum()), diff_px=across[both],
                sd_ratio=a.sd_normal[both] / np.sqrt(np.maximum(w[both, 0], 1e-300)),
                only_a=int(np.sum(paired & ~a.flagged & b.flagged[j])),
                only_b=int(np.sum(paired & a.flagged & ~b.flagged[j])),
                unpaired=int(np.sum(~paired)))
