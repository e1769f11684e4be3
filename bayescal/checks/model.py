"""The model check of a calibration result: the posterior predictive check on its residuals.

:func:`predictive_check` runs :func:`bayescal.checks.predictive.posterior_predictive_check`
on a calibration result:

* **Bayes**: residuals of the pixels (and of the approximate points, when
  there are any) under 200 evenly thinned joint posterior draws, each with its
  own noise levels (:func:`bayescal.checks.residuals.posterior_residuals`);
* **least squares** (simultaneous): the residuals at the solution made
  independent N(0, 1) for a correct model: per point, its whitened residual
  vector (pixel and scene rows) expressed in an orthonormal basis of what the
  fit leaves free, one component per finite scene axis
  (:func:`bayescal.checks.residuals.least_squares_scene_residuals`); a floor-plan fit
  has one pixel residual per point across its image track
  (:func:`~bayescal.checks.residuals.least_squares_residuals`). The check compares
  them with 200 replicates. Without the scene sds the fit used (a rebuilt
  report of a run whose scene noise was inferred) only the pixel residuals,
  divided by the global degrees-of-freedom factor, are checked: approximate.

Points flagged as outliers (``outlier_prob > 0.5``) are left out of the check:
it tests the inlier model, the outliers being accounted for by the mixture.
"""

from __future__ import annotations

import numpy as np

from .datafile import OUTLIER_FLAG
from .predictive import posterior_predictive_check
from .residuals import (
    least_squares_residuals,
    least_squares_scene_residuals,
    posterior_residuals,
)

__all__ = ["predictive_check", "N_CHECK_DRAWS"]

#: posterior draws (or replicates) of the predictive check
N_CHECK_DRAWS = 200


def _is_posterior(result):
    return hasattr(result, "param_samples")


def _residuals(result, info, pixels, approx_points=None):
    """(pixel (S, N, 2), scene (S, N, 3), uses azimuth) or None when no check applies."""
    if _is_posterior(result):
        pix, sc = posterior_residuals(result, n_draws=N_CHECK_DRAWS, scene=True)
        return pix, sc, bool(np.isfinite(sc).any())
    if result.points is None or result.method == "sequential":
        return None
    noise = result.extras.get("noise") or {}
    spx = (info.get("sigma_px") or result.extras.get("sigma_px") or noise.get("sigma_px")
           or result.sigma_px_estimated)
    if not spx:
        return None
    ssc = result.extras.get("sigma_scene")
    if ssc is None and noise.get("kappa") and approx_points is not None:
        rho = np.hypot(approx_points[:, 0], approx_points[:, 1])
        ssc = np.repeat((noise["kappa"] * rho)[:, None], 3, axis=1)
    if ssc is None or approx_points is None:          # a floor plan, or unknown scene sds
        _, z = least_squares_residuals(result, pixels, spx, ssc)
        pix = np.broadcast_to(z, (N_CHECK_DRAWS,) + z.shape)
        return pix, np.full(pix.shape[:2] + (3,), np.nan), False
    zs = least_squares_scene_residuals(result, pixels, approx_points, spx, ssc)
    pix = np.full((N_CHECK_DRAWS,) + pixels.shape, np.nan)
    return pix, np.broadcast_to(zs, (N_CHECK_DRAWS,) + zs.shape), True


def predictive_check(result, info, pixels, *, approx_points=None, rng=0):
    """Global posterior predictive check of a calibration result.

    Parameters
    ----------
    result : CalibrationResult or Posterior
    info : dict
        The run record (``sigma_px`` used).
    pixels : ndarray, shape (N, 2)
        px.
    approx_points : ndarray, shape (N, 3), optional
        mm; with them (and the scene sds the fit used) a least-squares check
        also tests the scene residuals.
    rng : numpy.random.Generator, int or None
        For the replicated residuals.

    Returns
    -------
    dict or None
        The output of :func:`~bayescal.checks.predictive.posterior_predictive_check`
        plus ``azimuth`` (N,) (rad, of the estimated points) and ``excluded``
        (the number of flagged outliers left out); None for the sequential
        method or a result without points.
    """
    res = _residuals(result, info, pixels, approx_points)
    if res is None:
        return None
    pix, sc, use_az = res
    pts = np.asarray(result.points, float)
    az = np.arctan2(pts[:, 1], pts[:, 0])
    op = getattr(result, "outlier_prob", None)
    flagged = (np.zeros(len(pts), bool) if op is None or np.shape(op) != (len(pts),)
               else np.asarray(op, float) > OUTLIER_FLAG)
    if flagged.any():
        pix, sc = np.array(pix), np.array(sc)
        pix[:, flagged], sc[:, flagged] = np.nan, np.nan
    check = posterior_predictive_check(pix, sc, azimuth=az if use_az else None, rng=rng)
    check["azimuth"], check["excluded"] = az, int(flagged.sum())
    return check
