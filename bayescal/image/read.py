"""Reading laser images: PNG, TIFF, JPEG, 8 or 16 bit, grey or colour."""

from __future__ import annotations

import os

import numpy as np

__all__ = ["as_gray", "read_image"]


def read_image(path, *, channel=0):
    """Read an image file and reduce it to the laser's channel.

    Parameters
    ----------
    path : str or os.PathLike
        A PNG, TIFF or JPEG file (8 or 16 bit, grey or colour), read with imageio.
    channel : int, optional
        Colour channel of the laser (0: red).

    Returns
    -------
    ndarray, shape (H, W)
        Grey levels as float (the file's own scale: 0-255 or 0-65535).
    """
    import imageio.v3 as iio

    path = os.fspath(path)
    if not os.path.isfile(path):
        raise FileNotFoundError(f"image file {path!r} does not exist")
    try:
        arr = iio.imread(path)
    except Exception as exc:  # imageio raises several types for an unreadable file
        raise ValueError(f"cannot read image {path!r}: {exc}") from None
    return as_gray(arr, channel=channel, name=f"image {path!r}")


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
        raise TypeError(f"{name} must be a numeric array, got dtype {arr.dtype}")
    if arr.ndim == 3:
        if not 0 <= int(channel) < min(arr.shape[2], 3):
            raise ValueError(f"channel must be 0-{min(arr.shape[2], 3) - 1} for {name} "
                             f"with {arr.shape[2]} channels, got {channel!r}")
        arr = arr[..., int(channel)]
    if arr.ndim != 2 or min(arr.shape) < 16:
        raise ValueError(f"{name} must have shape (H, W) or (H, W, C) with H, W >= 16, "
                         f"got {arr.shape}")
    out = arr.astype(float)
    if not np.all(np.isfinite(out)):
        raise ValueError(f"{name} contains NaN or infinite values")
    return out
