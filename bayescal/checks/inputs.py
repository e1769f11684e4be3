"""Checks on calibration input before any fitting.

:func:`check_calibration_input` refuses degenerate input (too few points, one
azimuth, no scene information, points the model cannot hold) with a message
saying what is missing, and warns about exact duplicate rows
(:class:`DuplicateRowsWarning`, naming the rows). Used by the least squares,
the sampler and the CLI; see ``docs/robustness.md``.
"""

from __future__ import annotations

import warnings

import numpy as np

from .._validation import as_pixels, as_points
from ..errors import BayescalWarning
from ..errors import DegenerateInputError as _Degenerate
from .rows import rows_text as _rows_text

__all__ = ["DuplicateRowsWarning", "check_calibration_input", "MIN_POINTS",
           "MIN_AZIMUTH_COVERAGE_DEG"]

#: fewest laser points a calibration accepts
MIN_POINTS = 4

#: smallest azimuth range (degrees) the laser pixels must cover around the principal point
MIN_AZIMUTH_COVERAGE_DEG = 45.0


class DuplicateRowsWarning(BayescalWarning):
    """Exact duplicate input rows (each would count twice and shrink every sd)."""


def check_calibration_input(pixels, approx_points, *, sigma_scene, center):
    """Refuse input a calibration cannot use, before any fitting.

    Parameters
    ----------
    pixels : array_like, shape (N, 2)
        Laser pixels, px.
    approx_points : array_like, shape (N, 3)
        Approximate 3D points in frame C, mm.
    sigma_scene : float, array_like broadcastable to (N, 3), or None
        Scene noise, mm (None = inferred).
    center : tuple of float
        ``(u0, v0)`` used to measure the pixels' azimuths, px (the start values).

    Returns
    -------
    pixels : ndarray, shape (N, 2)
    approx_points : ndarray, shape (N, 3)

    Raises
    ------
    ValueError
        Non-finite values (rows named), fewer than :data:`MIN_POINTS` points,
        pixels covering less than :data:`MIN_AZIMUTH_COVERAGE_DEG` of azimuth,
        approximate points on the sensor axis, or no scene information at all.

    Warns
    -----
    DuplicateRowsWarning
        Rows whose pixel and approximate point are both identical (rows named).
    """
    pix = _finite_rows(pixels, "pixels", as_pixels)
    apx = _finite_rows(approx_points, "approx_points", as_points)
    if pix.ndim != 2 or apx.ndim != 2 or len(pix) != len(apx):
        raise _Degenerate(f"pixels must have shape (N, 2) and approx_points (N, 3) with the "
                         f"same length N, got {pix.shape} and {apx.shape}")
    n = len(pix)
    if n < MIN_POINTS:
        raise _Degenerate(f"need at least {MIN_POINTS} laser points, got N={n}: the seven "
                         "identifiable parameters need points spread around the laser ring")
    on_axis = np.flatnonzero(np.hypot(apx[:, 0], apx[:, 1]) <= 0)
    if on_axis.size:
        raise _Degenerate(f"approx_points rows {_rows_text(on_axis)} lie on the sensor axis "
                         "(x = y = 0), outside the model's domain: a laser point is on the "
                         "cone, away from the axis")
    _check_azimuths(pix, center)
    if sigma_scene is not None:
        s = np.asarray(sigma_scene, dtype=float)
        if s.size and np.all(np.isinf(s)):
            raise _Degenerate("sigma_scene is inf everywhere: the approximate points carry no "
                             "information, and the pixels alone (two rows per point, two "
                             "unknowns per point) cannot calibrate; give finite sigma_scene "
                             "on at least x and y")
    _warn_duplicates(pix, apx)
    return pix, apx


def _finite_rows(value, name, conv):
    arr = conv(value, name, allow_nan=True)
    if arr.ndim == 2 and not np.all(np.isfinite(arr)):
        bad = np.flatnonzero(~np.all(np.isfinite(arr), axis=1))
        raise _Degenerate(f"{name} must contain only finite values; rows {_rows_text(bad)} "
                         f"(0-based) hold NaN or inf ({bad.size} rows in all)")
    return conv(arr, name)


def _check_azimuths(pix, center):
    az = np.sort(np.arctan2(pix[:, 1] - center[1], pix[:, 0] - center[0]))
    gaps = np.diff(np.append(az, az[0] + 2 * np.pi))
    coverage = np.degrees(2 * np.pi - np.max(gaps))
    if coverage < MIN_AZIMUTH_COVERAGE_DEG:
        raise _Degenerate(f"pixels: all laser pixels lie within {coverage:.1f} degrees of "
                         f"azimuth around the principal point ({center[0]:g}, {center[1]:g}) "
                         f"(nearly one azimuth); the cone and the principal point cannot be "
                         f"separated: use points spread around the laser ring (at least "
                         f"{MIN_AZIMUTH_COVERAGE_DEG:g} degrees)")


def _warn_duplicates(pix, apx):
    rows = np.hstack([pix, apx])
    _, first, inverse, counts = np.unique(rows, axis=0, return_index=True,
                                          return_inverse=True, return_counts=True)
    dup = np.flatnonzero(counts[inverse.ravel()] > 1)
    if dup.size:
        groups = {}
        for i in dup:
            groups.setdefault(int(inverse.ravel()[i]), []).append(int(i))
        txt = "; ".join("rows " + ", ".join(map(str, g)) for g in groups.values())
        warnings.warn(f"exact duplicate input rows (0-based): {txt}; each copy counts as an "
                      "independent measurement and shrinks every sd", DuplicateRowsWarning,
                      stacklevel=3)
