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

:func:`model_check` is the same check for a library user (``result.model_check()``):
it finds the data and noise levels the fit used on the result and returns a
:class:`ModelCheck`. Targeted statistics (each a function of the result and its
residuals giving a p-value) are listed in :data:`STATISTICS`; a model variant
adds its own there.
"""

from __future__ import annotations

import dataclasses

import numpy as np

from ..errors import InvalidValueError
from ..likelihood.scene_noise import scene_range
from .datafile import OUTLIER_FLAG
from .misalignment import harmonic_statistic
from .predictive import posterior_predictive_check
from .residuals import (
    least_squares_residuals,
    least_squares_scene_residuals,
    posterior_residuals,
)

__all__ = ["predictive_check", "model_check", "ModelCheck", "STATISTICS", "N_CHECK_DRAWS"]

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
        rho = scene_range(approx_points)
        ssc = np.repeat((noise["kappa"] * rho)[:, None], 3, axis=1)
    if ssc is None or approx_points is None:          # a floor plan, or unknown scene sds
        _, z = least_squares_residuals(result, pixels, spx, ssc)
        pix = np.broadcast_to(z, (N_CHECK_DRAWS,) + z.shape)
        return pix, np.full(pix.shape[:2] + (3,), np.nan), False
    zs = least_squares_scene_residuals(result, pixels, approx_points, spx, ssc)
    pix = np.full((N_CHECK_DRAWS,) + pixels.shape, np.nan)
    return pix, np.broadcast_to(zs, (N_CHECK_DRAWS,) + zs.shape), True


def predictive_check(result, info, pixels, *, approx_points=None, rng=0, alpha=0.01):
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
    alpha : float, optional
        A p-value below ``alpha`` fails the check.

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
    check = posterior_predictive_check(pix, sc, azimuth=az if use_az else None, rng=rng,
                                      alpha=alpha)
    check["azimuth"], check["excluded"] = az, int(flagged.sum())
    return check


#: targeted statistics run by :func:`model_check` besides the global ones: each is
#: ``f(result, check) -> dict or None`` with ``name``, ``p_value``, ``observed``,
#: ``expected`` and ``message`` (what a failure means and what to do), where ``check`` is
#: the :func:`predictive_check` output (its ``azimuth`` and per-point statistics)
STATISTICS = [harmonic_statistic]


@dataclasses.dataclass
class ModelCheck:
    """Does the model fit the data? The predictive check of a calibration result.

    Attributes
    ----------
    fits : bool
        False when any statistic's p-value is below ``alpha``.
    message : str
        ``"model fits: ..."`` or ``"MODEL DOES NOT FIT: ..."`` naming each failed statistic.
    p_values : dict
        ``{statistic: p}``: ``chi2`` (two-sided), ``tail`` (fraction of ``|z| > 3``),
        ``neighbour_corr`` (scene errors shared by neighbours in azimuth), and any of
        :data:`STATISTICS`.
    observed, expected : dict
        Each statistic's value on the data and its mean under the model.
    point_chi2 : ndarray, shape (N,)
        Each point's sum of squared standardized residuals (mean over draws).
    point_rows : ndarray, shape (N,)
        Its number of residual rows (its expectation under the model).
    azimuth : ndarray, shape (N,)
        Azimuth of each estimated point, rad.
    excluded : int
        Flagged outliers (``outlier_prob > 0.5``) left out of the check.
    """

    fits: bool
    message: str
    p_values: dict
    observed: dict
    expected: dict
    point_chi2: np.ndarray
    point_rows: np.ndarray
    azimuth: np.ndarray
    excluded: int

    def __str__(self):
        return self.message

    def __getitem__(self, key):         # the report reads the check as a mapping
        return getattr(self, key)

    def to_dict(self):
        """Plain-data form (arrays as arrays)."""
        return dataclasses.asdict(self)


def _result_data(result, pixels, approx_points):
    """Pixels, approximate points and the run record a result's check needs."""
    if _is_posterior(result):
        pix = result.pixels if pixels is None else pixels
        apx = result.approx_points if approx_points is None else approx_points
        return np.asarray(pix, float), None if apx is None else np.asarray(apx, float), {}
    ex = result.extras
    pix = ex.get("pixels") if pixels is None else pixels
    apx = ex.get("approx_points") if approx_points is None else approx_points
    if pix is None:
        raise InvalidValueError("this result does not carry the pixels it was fitted to (a file "
                                "written by an older bayescal): pass pixels=... (and "
                                "approx_points=...) to model_check")
    return np.asarray(pix, float), None if apx is None else np.asarray(apx, float), \
        {"sigma_px": ex.get("sigma_px")}


def model_check(result, *, pixels=None, approx_points=None, info=None, rng=0, alpha=0.01):
    """The predictive check of a calibration result: does the model fit the data?

    Parameters
    ----------
    result : CalibrationResult or Posterior
        From :func:`~bayescal.calibrate_simultaneous` (approximate points or a
        floor plan) or :func:`~bayescal.sample_posterior`.
    pixels : array_like, shape (N, 2), optional
        px; default the pixels the result was fitted to.
    approx_points : array_like, shape (N, 3), optional
        mm; default those the result was fitted to (none for a floor plan).
    info : dict, optional
        A command-line run's record (its ``sigma_px``), for a rebuilt report.
    rng : numpy.random.Generator, int or None
        For the replicated residuals (default 0: the same verdict every call).
    alpha : float, optional
        A p-value below ``alpha`` fails the check.

    Returns
    -------
    ModelCheck

    Raises
    ------
    ValueError
        A sequential result (its check is :func:`~bayescal.sequential_residuals`), or
        a result that carries neither its data nor the noise levels it used.

    Examples
    --------
    >>> import bayescal as bc
    >>> ds = bc.simulate_room(range_mm=1000, n_points=120, sigma_px=0.5, approx_error=0.01,
    ...                       approx_model="gaussian", rng=0)
    >>> res = bc.calibrate_simultaneous(ds.pixels, ds.approx_points, sigma_px=0.5,
    ...                                 sigma_scene=ds.sigma_scene)
    >>> res.model_check().fits
    True
    """
    if getattr(result, "method", None) == "sequential":
        raise InvalidValueError("model_check applies to simultaneous and Bayesian results; for the "
                                "sequential method see bayescal.sequential_residuals")
    pix, apx, found = _result_data(result, pixels, approx_points)
    info = found if info is None else {**found, **{k: v for k, v in info.items() if v is not None}}
    check = predictive_check(result, info, pix, approx_points=apx, rng=rng, alpha=alpha)
    if check is None:
        raise InvalidValueError("the result carries no noise level to standardize its residuals "
                                "with; refit it with this bayescal")
    p, obs, exp, msgs = (dict(check["p_values"]), dict(check["observed"]),
                         dict(check["expected"]), [])
    for stat in STATISTICS:
        extra = stat(result, check)
        if extra is None:
            continue
        name = extra["name"]
        p[name], obs[name], exp[name] = extra["p_value"], extra["observed"], extra["expected"]
        if extra["p_value"] < alpha:
            msgs.append(extra["message"])
    failed = [k for k in p if p[k] < alpha]
    message = check["message"]
    if msgs:
        message = "; ".join([message if not check["fits"] else "MODEL DOES NOT FIT"] + msgs)
    return ModelCheck(fits=not failed, message=message, p_values=p, observed=obs, expected=exp,
                      point_chi2=np.asarray(check["point_chi2"]),
                      point_rows=np.asarray(check["point_rows"]),
                      azimuth=np.asarray(check["azimuth"]), excluded=int(check["excluded"]))
