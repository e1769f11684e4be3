"""Reading laser images: PNG, TIFF, JPEG, 8 or 16 bit, grey or colour."""

from __future__ import annotations

import os

import numpy as np

from ..errors import InvalidTypeError, InvalidValueError, MissingFileError

__all__ = ["as_gray", "read_image", "mosaic_ratio", "demosaiced_blur", "MOSAIC_RATIO",
           "MOSAIC_BLUR"]

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
