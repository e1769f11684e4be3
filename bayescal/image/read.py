"""Reading laser images (PNG, TIFF, JPEG, 8 or 16 bit, grey or colour) and sequences of
frames (a folder of images, a list of files or arrays, a video file).

:func:`iter_frames` yields each frame with a name (a file's stem, ``frame_00012`` of a
video, ``frame 12`` of an array), read as :func:`read_image` reads an image for the
extractor (the file's own type and colour channels). A video is decoded through imageio's
PyAV plugin, an optional extra (``pip install bayescal[video]``).
"""

from __future__ import annotations

import itertools
import os
import pathlib

import numpy as np

from ..errors import (
    InvalidTypeError,
    InvalidValueError,
    MissingDependencyError,
    MissingFileError,
)

__all__ = ["as_gray", "read_image", "mosaic_ratio", "demosaiced_blur", "iter_frames",
           "frame_names", "count_frames", "as_frame", "per_frame", "MOSAIC_RATIO", "MOSAIC_BLUR",
           "IMAGE_SUFFIXES", "VIDEO_SUFFIXES"]

#: a colour channel is taken as demosaiced from a Bayer mosaic when, along rows and along
#: columns, every other pixel is the mean of its two neighbours: its mean squared miss is at
#: most MOSAIC_RATIO of the other half's (bilinearly demosaiced red channels of two
#: renderers: 0.02-0.12, 0.45-0.46 once saved as JPEG at quality 92 without chroma
#: subsampling, 0.70-0.73 at 88 with it; full colour renders of two others: 0.90-1.00,
#: 0.95-1.00 as JPEG at quality 75-95)
MOSAIC_RATIO = 0.6
#: Gaussian sd (px) that smooths such a channel: its laser stripe is sampled every 2 px and
#: interpolated, so a 5-sample peak fit errs with the stripe's phase on that lattice (robust
#: sd 0.24-0.26 px on a third renderer's Bayer images, 0.19-0.22 px smoothed by 0.8 px; 0.5
#: px gave 0.21-0.25, 1.0-1.3 px raised the z rms of another renderer's to 1.4-1.7)
MOSAIC_BLUR = 0.8


def read_image(path, *, channel=0, raw=False):
    """Read an image file and reduce it to the laser's channel.

    Parameters
    ----------
    path : str or os.PathLike
        A PNG, TIFF or JPEG file (8 or 16 bit, grey or colour), read with imageio.
    channel : int, optional
        Colour channel of the laser (0: red).
    raw : bool, optional
        Return the array as the file holds it (its integer type and colour channels kept,
        for :func:`~bayescal.image.extract.extract_laser`, which tells a clipped stripe by
        the type's top and a laser by its colour), once checked to have ``channel``.

    Returns
    -------
    ndarray, shape (H, W), or (H, W) or (H, W, C) with ``raw``
        Grey levels as float (the file's own scale: 0-255 or 0-65535).
    """
    import imageio.v3 as iio

    path = os.fspath(path)
    if not os.path.isfile(path):
        raise MissingFileError(f"image file {path!r} does not exist")
    try:
        arr = iio.imread(path)
    except Exception as exc:  # imageio raises several types for an unreadable file
        raise InvalidValueError(f"cannot read image {path!r}: {exc}") from None
    gray = as_gray(arr, channel=channel, name=f"image {path!r}")
    return np.asarray(arr) if raw else gray


def as_gray(image, *, channel=0, name="image"):
    """Return a 2D float image: a colour image reduced to ``channel``.

    Parameters
    ----------
    image : array_like, shape (H, W) or (H, W, C)
    channel : int, optional
        Channel kept from a colour image (an alpha channel is never chosen).
    name : str, optional
        Name used in error messages.

    Returns
    -------
    ndarray, shape (H, W), float
    """
    arr = np.asarray(image)
    if arr.dtype == bool or not np.issubdtype(arr.dtype, np.number):
        raise InvalidTypeError(f"{name} must be a numeric array, got dtype {arr.dtype}")
    if arr.ndim == 3:
        if not 0 <= int(channel) < min(arr.shape[2], 3):
            raise InvalidValueError(f"channel must be 0-{min(arr.shape[2], 3) - 1} for {name} "
                                    f"with {arr.shape[2]} channels, got {channel!r}")
        arr = arr[..., int(channel)]
    if arr.ndim != 2 or min(arr.shape) < 16:
        raise InvalidValueError(f"{name} must have shape (H, W) or (H, W, C) with H, W >= 16, "
                                f"got {arr.shape}")
    out = arr.astype(float)
    if not np.issubdtype(arr.dtype, np.integer) and not np.all(np.isfinite(out)):
        raise InvalidValueError(f"{name} contains NaN or infinite values")
    return out


def mosaic_ratio(gray):
    """How far a channel is from one interpolated off a 2-px lattice (a demosaiced Bayer
    channel): along rows and along columns, the mean squared miss of every other pixel from
    the mean of its two neighbours, over that of the other half (the smaller over the
    larger); the larger of the two ratios.

    Parameters
    ----------
    gray : ndarray, shape (H, W)

    Returns
    -------
    float
        In [0, 1]: near 0 for a bilinearly demosaiced channel, near 1 for a channel sampled
        at every pixel.
    """
    out = 0.0
    for a in (np.asarray(gray, float), np.asarray(gray, float).T):
        miss = a[:, 1:-1] - 0.5 * (a[:, :-2] + a[:, 2:])
        ms = [float(np.mean(miss[:, p::2] ** 2)) for p in (0, 1)]
        out = max(out, min(ms) / max(max(ms), 1e-12))
    return out


def demosaiced_blur(image, gray):
    """Gaussian sd (px) to smooth the laser's channel ``gray`` of ``image`` with:
    :data:`MOSAIC_BLUR` for a colour image whose channel was demosaiced from a Bayer mosaic
    (:func:`mosaic_ratio` below :data:`MOSAIC_RATIO`), else 0."""
    if np.asarray(image).ndim != 3 or min(gray.shape) < 16:
        return 0.0
    return MOSAIC_BLUR if mosaic_ratio(gray) < MOSAIC_RATIO else 0.0


#: file suffixes read as video (decoded by imageio's PyAV plugin)
VIDEO_SUFFIXES = (".mp4", ".avi", ".mkv", ".mov", ".webm", ".m4v", ".mpg", ".mpeg")
#: file suffixes of an image (a frame in a folder of frames)
IMAGE_SUFFIXES = (".png", ".tif", ".tiff", ".jpg", ".jpeg")


def _is_pathlike(x):
    return isinstance(x, (str, os.PathLike))


def _folder_frames(folder):
    files = sorted(p for p in folder.iterdir()
                   if p.is_file() and p.suffix.lower() in IMAGE_SUFFIXES)
    if not files:
        raise InvalidValueError(f"folder {str(folder)!r} holds no image "
                                f"({', '.join(IMAGE_SUFFIXES)}) to read as frames")
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
