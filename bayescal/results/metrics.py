"""The paper's error metric: mean Euclidean distance of reconstructed to true points.

"The presented error is the average distance from the reconstructed 3D points
and the synthetic ones" (paper, sec. IV). Both calibrations, the Bayesian
posterior and the studies use these two functions.

Invalid points: a reconstruction is NaN where a pixel's ray misses the laser
cone (see :func:`~bayescal.triangulate`). :func:`reconstruction_errors` keeps
them as NaN; :func:`reconstruction_error` raises by default (a mean that
silently skips the worst points would flatter a calibration) and, with
``invalid="ignore"``, averages the valid ones only -- count them with
``np.isnan(reconstruction_errors(...)).sum()``.
"""

from __future__ import annotations

import numpy as np

from .._validation import as_points
from ..errors import InvalidValueError

__all__ = ["reconstruction_errors", "reconstruction_error"]

_INVALID = ("raise", "ignore")


def reconstruction_errors(reconstructed, true):
    """Per-point Euclidean distance between reconstructed and true points.

    Parameters
    ----------
    reconstructed : array_like, shape (..., 3)
        Reconstructed points, mm; NaN marks points that could not be
        reconstructed.
    true : array_like, shape (..., 3)
        True points, mm (must be finite); broadcast against ``reconstructed``
        (e.g. ``(S, N, 3)`` samples against ``(N, 3)`` truth).

    Returns
    -------
    ndarray, shape (...)
        Distances in mm; NaN where ``reconstructed`` has a NaN coordinate.

    Examples
    --------
    >>> import numpy as np
    >>> import bayescal as bc
    >>> bc.reconstruction_errors(np.zeros((2, 3)), np.array([[3.0, 4.0, 0.0], [0.0, 0.0, 1.0]]))
    array([5., 1.])
    """
    rec = as_points(reconstructed, "reconstructed", allow_nan=True)
    tru = as_points(true, "true")
    try:
        diff = rec - tru
    except ValueError:
        raise InvalidValueError(f"reconstructed and true must have broadcastable shapes, got "
                                f"{rec.shape} and {tru.shape}") from None
    return np.linalg.norm(diff, axis=-1)


def reconstruction_error(reconstructed, true, *, invalid="raise"):
    """Mean Euclidean distance (mm) between reconstructed and true points.

    Parameters
    ----------
    reconstructed : array_like, shape (..., 3)
        Reconstructed points, mm (NaN = not reconstructed).
    true : array_like, shape (..., 3)
        True points, mm.
    invalid : {"raise", "ignore"}, optional
        What to do with NaN reconstructions: raise a ValueError that gives
        their number (default), or leave them out of the mean.

    Returns
    -------
    float
        Mean distance in mm over all (valid) points; NaN if ``invalid="ignore"``
        and no point is valid.

    Examples
    --------
    >>> reconstruction_error([[3.0, 4.0, 0.0], [0.0, 0.0, 1.0]], [[0.0, 0.0, 0.0]] * 2)
    3.0
    """
    if invalid not in _INVALID:
        raise InvalidValueError(f"invalid must be one of {_INVALID}, got {invalid!r}")
    d = reconstruction_errors(reconstructed, true)
    if d.size == 0:
        raise InvalidValueError("reconstructed and true hold no points")
    bad = np.isnan(d)
    if bad.any():
        if invalid == "raise":
            first = tuple(int(i) for i in np.argwhere(bad)[0])
            raise InvalidValueError(f"reconstructed has {int(bad.sum())} invalid (NaN) points of "
                                    f"{d.size} (first at index {first}); pass invalid='ignore' to "
                                    "average the valid ones")
        if bad.all():
            return float("nan")
        return float(np.mean(d[~bad]))
    return float(np.mean(d))
