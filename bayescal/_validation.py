"""Input checking and randomness helpers shared by the whole package.

Every public function funnels user input through these helpers so that bad
input gives the same kind of message everywhere: the argument's name, what was
received and what was expected.
"""

from __future__ import annotations

import numpy as np

from .errors import InvalidTypeError, InvalidValueError

__all__ = ["as_points", "as_pixels", "as_finite_array", "resolve_rng", "check_positive"]


def as_finite_array(value, name, *, last_dim=None, allow_nan=False, dtype=float):
    """Convert ``value`` to a float array and check its trailing dimension.

    Parameters
    ----------
    value : array_like
        The user's input.
    name : str
        Argument name used in error messages.
    last_dim : int, optional
        Required size of the last axis.
    allow_nan : bool, optional
        If False (default) NaN and infinities are rejected.

    Returns
    -------
    ndarray
    """
    try:
        arr = np.asarray(value, dtype=dtype)
    except (TypeError, ValueError) as exc:
        raise InvalidTypeError(
            f"{name} must be a numeric array, got {type(value).__name__}: {exc}"
        ) from None
    if last_dim is not None and (arr.ndim == 0 or arr.shape[-1] != last_dim):
        raise InvalidValueError(f"{name} must have shape (..., {last_dim}), got shape {arr.shape}")
    if not allow_nan and not np.all(np.isfinite(arr)):
        bad = np.argwhere(~np.isfinite(arr))
        where = tuple(int(i) for i in bad[0]) if bad.size else ()
        raise InvalidValueError(
            f"{name} must contain only finite values; found {arr[where] if where else arr} "
            f"at index {where} ({len(bad)} non-finite entries in all)"
        )
    return arr


def as_points(points, name="points", *, allow_nan=False):
    """Check a ``(..., 3)`` array of 3D points in millimetres."""
    return as_finite_array(points, name, last_dim=3, allow_nan=allow_nan)


def as_pixels(pixels, name="pixels", *, allow_nan=False):
    """Check a ``(..., 2)`` array of pixel coordinates ``(u, v)``."""
    return as_finite_array(pixels, name, last_dim=2, allow_nan=allow_nan)


def check_positive(value, name, *, allow_zero=False):
    """Return ``float(value)`` after checking it is finite and positive."""
    try:
        v = float(value)
    except (TypeError, ValueError):
        raise InvalidTypeError(f"{name} must be a number, got {value!r}") from None
    ok = np.isfinite(v) and (v >= 0 if allow_zero else v > 0)
    if not ok:
        what = "non-negative" if allow_zero else "positive"
        raise InvalidValueError(f"{name} must be a finite {what} number, got {value!r}")
    return v


def resolve_rng(rng):
    """Turn ``rng`` into a :class:`numpy.random.Generator`.

    Parameters
    ----------
    rng : numpy.random.Generator, int, numpy.random.SeedSequence or None
        ``None`` gives fresh OS entropy; an int or a SeedSequence seeds a new
        generator; a Generator is returned unchanged (and so is consumed).

    Returns
    -------
    numpy.random.Generator
    """
    if isinstance(rng, np.random.Generator):
        return rng
    if rng is None or isinstance(rng, (int, np.integer, np.random.SeedSequence)):
        if isinstance(rng, (int, np.integer)) and rng < 0:
            raise InvalidValueError(f"rng seed must be non-negative, got {rng}")
        return np.random.default_rng(rng)
    raise InvalidTypeError(
        f"rng must be a numpy.random.Generator, an int seed, a SeedSequence or None, "
        f"got {type(rng).__name__}"
    )
