"""The per-point outlier mixture: a heavy-tailed scale mixture of the model's noise.

Each laser point (its pixel and approximate point together) is an inlier with
probability ``1 - w`` or an outlier with probability ``w``; an outlier's rows
have ``c`` times the model's noise (all of them, pixel and scene). Both
components share the latent point ``q`` and its prior, so the improper point
prior's constants cancel in the ratio ``L_out / L_in``, which depends only on
the point's squared whitened residual ``m`` and its number of rows::

    log L_out - log L_in = m (1 - 1/c^2) / 2 + (v - n_rows) log c

``v = 2`` for the Laplace marginals (the outlier's q-integral is c^2 wider),
``v = 0`` for densities at a given q. See ``docs/robustness.md``.
"""

from __future__ import annotations

import numpy as np
from scipy.special import betaln, log_expit

from .._validation import check_positive
from ..errors import InvalidTypeError, InvalidValueError

__all__ = ["OUTLIER_SCALE", "OUTLIER_PRIOR", "NOISE_TRIM", "check_outlier_options",
           "log_prior_logit_frac",
           "mix", "combine", "em_update", "annealed_outlier_prob", "trimmed_mean_square"]

#: fraction of the worst-fitting points the first inferred-noise estimate leaves out
NOISE_TRIM = 0.2

#: default noise inflation ``c`` of the outlier component
OUTLIER_SCALE = 100.0

#: default Beta(a, b) prior of the outlier fraction (mean a / (a + b) = 0.05)
OUTLIER_PRIOR = (1.0, 19.0)


def check_outlier_options(outliers, scale, prior):
    """Validate the outlier switch, scale and prior; returns ``(bool, float, (a, b))``."""
    if not isinstance(outliers, (bool, np.bool_)):
        raise InvalidTypeError(f"outliers must be True or False, got {outliers!r}")
    c = check_positive(scale, "outlier_scale")
    if c <= 1.0:
        raise InvalidValueError(f"outlier_scale must be > 1 (the outlier component is broader than "
                                f"the model's noise), got {scale!r}")
    try:
        a, b = (float(v) for v in prior)
    except (TypeError, ValueError):
        raise InvalidTypeError(f"outlier_prior must be a pair (a, b) of Beta parameters, got "
                               f"{prior!r}") from None
    if not (np.isfinite(a) and np.isfinite(b) and a > 0 and b > 0):
        raise InvalidValueError(f"outlier_prior must be a pair (a, b) of positive finite Beta "
                                f"parameters, got {prior!r}")
    return bool(outliers), c, (a, b)


def log_prior_logit_frac(x, prior):
    """Log density of ``x = logit w`` under ``w ~ Beta(a, b)``: ``w^a (1 - w)^b / B(a, b)``.

    Parameters
    ----------
    x : ndarray, shape (...)
    prior : tuple of float
        ``(a, b)``.
    """
    a, b = prior
    return a * log_expit(x) + b * log_expit(-x) - betaln(a, b)


def mix(x, per_in, m, n_rows, c, *, laplace):
    """Mix each point's inlier log term with the outlier component's.

    Parameters
    ----------
    x : ndarray, shape (...)
        ``logit w``.
    per_in : ndarray, shape (..., N)
        Inlier log marginal (Laplace) or log density at q, per point.
    m : ndarray, shape (..., N)
        Squared whitened residual norm at the point's mode (Laplace) or at q.
    n_rows : ndarray, shape (N,)
        Residual rows per point.
    c : float
        Noise inflation of the outlier component.
    laplace : bool
        True for the q-integrated marginals, False for densities at q.

    Returns
    -------
    per_point : ndarray, shape (..., N)
        ``log((1 - w) L_in + w L_out)``.
    r : ndarray, shape (..., N)
        Outlier probability ``w L_out / ((1 - w) L_in + w L_out)``.
    """
    vol = 2.0 if laplace else 0.0
    delta = 0.5 * m * (1.0 - 1.0 / c**2) + (vol - n_rows) * np.log(c)
    return combine(np.asarray(x, dtype=float)[..., None], per_in, per_in + delta)


def combine(x, log_in, log_out):
    """``log((1 - w) L_in + w L_out)`` and the outlier probability, from ``logit w``.

    ``x`` broadcasts against ``log_in`` and ``log_out`` (e.g. (..., 1) against
    (..., N)). Shared by the per-point model (:func:`mix`) and the floor plan's,
    which build ``L_out`` differently.
    """
    a = log_expit(-x) + log_in
    b = log_expit(x) + log_out
    with np.errstate(over="ignore", invalid="ignore"):
        r = 1.0 / (1.0 + np.exp(a - b))
        return np.logaddexp(a, b), r


def em_update(r, prior, c):
    """EM M-step quantities from the outlier probabilities ``r`` (N,).

    Returns ``(w, weights)``: the logit-scale mode of the outlier fraction under its
    Beta(a, b) prior, ``w = (sum r + a) / (N + a + b)``, and each point's weight of its
    squared residuals, ``(1 - r) + r / c^2`` (the outlier component is the same
    Gaussian with c times the noise). Shared by the least squares on approximate
    points and on a floor plan.
    """
    a, b = prior
    r = np.asarray(r, dtype=float)
    return float((np.sum(r) + a) / (r.size + a + b)), (1.0 - r) + r / c**2


def annealed_outlier_prob(m, dof, x, log_ratio):
    """First E-step at a start: outlier probabilities with the noise scaled to the median point.

    Away from the MAP every point misfits by several noise sd; scaling the noise by
    ``T = sqrt(median m_i / median chi2(dof_i))`` makes the typical point an inlier and
    leaves the gross errors far out, so that none enters the first fit at full weight.
    Shared by the least squares on approximate points and on a floor plan.

    Parameters
    ----------
    m : ndarray, shape (N,)
        Each point's squared whitened residual at its own best latent (NaN or inf
        outside the model's domain).
    dof : ndarray, shape (N,), or float
        Its degrees of freedom (residual rows minus latent dimensions).
    x : float
        ``logit w``.
    log_ratio : callable
        ``log_ratio(m)`` -> ``log L_out - log L_in`` of the model, elementwise.

    Returns
    -------
    ndarray, shape (N,), or None
        ``r``, 1 outside the domain; None if no point is inside it.
    """
    from scipy.stats import chi2

    m = np.asarray(m, dtype=float)
    ok = np.isfinite(m)
    if not np.any(ok):
        return None
    dof = np.broadcast_to(np.asarray(dof, dtype=float), m.shape)
    T2 = max(1.0, float(np.median(m[ok] / chi2.median(dof[ok]))))
    r = combine(x, 0.0, log_ratio(np.where(ok, m, 0.0) / T2))[1]
    return np.where(ok, r, 1.0)


def trimmed_mean_square(s, dof, keep=1.0 - NOISE_TRIM):
    """Robust mean of chi-square-like per-point statistics: the mean of the smallest
    ``keep`` fraction, made consistent for ``chi2(dof)`` (so that an outlier-free sample
    gives the plain mean's expectation, ``dof``, times the noise scale squared).

    Parameters
    ----------
    s : ndarray, shape (N,)
        Per-point sums of squared whitened residuals.
    dof : int
        Their degrees of freedom under the model.
    keep : float, optional
        Fraction of the points kept, in (0, 1] (default ``1 - NOISE_TRIM``).

    Returns
    -------
    float
        The estimate of ``mean(s) / dof`` a bad block of rows cannot drag.
    """
    from scipy import stats

    s = np.sort(np.asarray(s, dtype=float)[np.isfinite(s)])
    n = max(1, int(round(keep * len(s))))
    q = stats.chi2.ppf(keep, dof)
    truncated_mean = dof * stats.chi2.cdf(q, dof + 2) / keep     # E[X | X < q] for chi2(dof)
    return float(np.mean(s[:n]) / truncated_mean)
