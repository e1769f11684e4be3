"""Checks on a finished fit: is it a fit one can trust?

* :func:`check_noise_levels` refuses an inferred noise level that ended at its
  prior bound (:class:`NoiseCollapseError`, naming the rows that drive it);
* :func:`fit_problems` lists what makes a least-squares solution untrustworthy
  although the solver stopped: a parameter on the bound of its domain or far
  outside its prior, or inferred noise levels that disagree with a robust
  scale of the fit's own residuals (:func:`robust_noise_ratio`: bad rows
  dragged the noise, and with it every sd). Such a fit is reported as not
  converged, naming the rows that fit worst (a failed model check:
  :mod:`bayescal.checks.misfit`).

See ``docs/robustness.md``.
"""

from __future__ import annotations

import numpy as np

from ..errors import BayescalError, BayescalWarning
from .rows import rows_text as _rows_text

__all__ = ["NoiseCollapseError", "NoiseUndeterminedWarning", "pixel_noise_ceiling",
           "check_noise_levels", "fit_problems", "robust_noise_ratio",
           "worst_rows", "flag_untrusted", "OffPlanWarning", "off_plan_text", "DOMAIN",
           "BOUND_TOL", "PRIOR_SD_LIMIT", "NOISE_RATIO_LIMIT", "GROSS_RATIO"]

#: the domain of the parameters that have one (the model is undefined beyond it)
DOMAIN = {"xi": (0.0, np.inf), "h": (0.0, np.inf), "beta": (0.0, np.pi / 2)}
#: a parameter closer than this many prior sds to a bound of its domain sits on it
BOUND_TOL = 1e-3
#: a parameter further than this many prior sds from its prior mean is not credible
PRIOR_SD_LIMIT = 10.0
#: inferred noise and a robust scale of the residuals further apart than this disagree
NOISE_RATIO_LIMIT = 1.5
#: with the noise given, residuals whose robust scale exceeds it this many times fail grossly
GROSS_RATIO = 2.0


class NoiseCollapseError(BayescalError, ValueError):
    """An inferred noise level ended at its prior bound.

    Attributes
    ----------
    name : str
        ``"sigma_px"`` or ``"kappa"``.
    value : float
    rows : ndarray of int
        Input rows (0-based) whose data pull the level towards the bound most.
    """

    def __init__(self, message, *, name, value, rows):
        super().__init__(message)
        self.name, self.value, self.rows = name, value, np.asarray(rows, dtype=int)


class NoiseUndeterminedWarning(BayescalWarning):
    """The data do not determine the pixel noise: their likelihood is flat from the lower
    bound up to a level beyond which it falls (:func:`pixel_noise_ceiling`); the fit was made
    with ``sigma_px`` at that level, the largest the data allow (``result.extras
    ["sigma_px_ceiling"]``)."""


#: the pixel noise's ceiling: where the collapsed log likelihood has fallen this many nats
#: below its largest value over the prior's range
CEILING_DROP = 2.0


def pixel_noise_ceiling(lik, psi, q, *, drop=CEILING_DROP, n=49, factor=2.0):
    """The largest pixel noise the data allow when they do not determine it, or None.

    The collapsed log likelihood (:meth:`~bayescal.likelihood.points.LaserLikelihood.laplace`
    per point, summed) over ``sigma_px`` on a log grid of ``n`` levels across its prior's
    range, the other parameters and the points held at the fit ``psi``, ``q``: the largest
    level within ``drop`` nats of the best. None when that level lies within ``factor`` of
    the upper bound (the data bound the noise on neither side), or within 10 times the lower
    bound (the likelihood is not flat over a decade: the noise is small, not undetermined).
    """
    from ..likelihood.points import NOISE_BOUNDS

    k = 7 + list(lik.extra_names).index("sigma_px")       # as check_noise_levels reads it
    lo, hi = NOISE_BOUNDS["sigma_px"]
    grid = np.geomspace(lo, hi, n)
    ll = np.full(n, -np.inf)
    for i, s in enumerate(grid):
        p = np.array(psi, dtype=float)
        p[k] = np.log(s)
        v = float(np.sum(lik._laplace_points(p, q, 2)[0]))
        ll[i] = v if np.isfinite(v) else -np.inf
    if not np.isfinite(ll).any():
        return None
    top = grid[np.flatnonzero(ll >= np.max(ll) - drop).max()]
    return None if top >= hi / factor or top < 10 * lo else float(top)


def check_noise_levels(lik, psi, q, *, factor=2.0, n_rows=5):
    """Refuse inferred noise levels that ended within ``factor`` of their prior bounds.

    Parameters
    ----------
    lik : bayescal.likelihood.points.LaserLikelihood
    psi : ndarray, shape (7 + n_extra,)
        Parameters and extra globals at the fit (``log sigma_px``, ``log kappa``...).
    q : ndarray, shape (N, 2)
        Scene coordinates at the fit.
    factor : float
        A level within this factor of a bound counts as at the bound.
    n_rows : int
        How many driving rows to name.

    Raises
    ------
    NoiseCollapseError
        Naming the level, its value, the bound and the rows whose collapsed
        likelihood gains most by moving the level further towards the bound.
    """
    from ..likelihood.points import NOISE_BOUNDS

    psi = np.asarray(psi, dtype=float)
    for k, name in enumerate(lik.extra_names):
        if name not in NOISE_BOUNDS:
            continue
        lo, hi = NOISE_BOUNDS[name]
        v = float(np.exp(psi[7 + k]))
        if lo * factor < v < hi / factor:
            continue
        toward = -1.0 if v <= lo * factor else 1.0
        step = np.zeros_like(psi)
        step[7 + k] = 0.1 * toward
        gain = (lik._laplace_points(psi + step, q, 2)[0]
                - lik._laplace_points(psi, q, 2)[0])
        gain = np.where(np.isfinite(gain), gain, -np.inf)
        rows = np.argsort(-gain)[:n_rows]
        what = "pixel noise sigma_px" if name == "sigma_px" else "scene noise kappa"
        side = "lower" if toward < 0 else "upper"
        raise NoiseCollapseError(
            f"the inferred {what} ended at {v:.3g}, at its {side} bound ({lo:g}-{hi:g}): "
            f"the data cannot determine it (e.g. the other noise level leaves no degrees of "
            f"freedom, or a few rows dominate). Rows driving it most (0-based): "
            f"{_rows_text(rows)}. Check those rows, or give {name} explicitly",
            name=name, value=v, rows=rows)


def robust_noise_ratio(m, dof):
    """The factor by which the residuals' robust scale differs from the noise they were
    whitened with: ``s`` such that ``median_i F_dof_i(m_i / s^2) = 1/2``.

    For a correct noise level the per-point statistics ``m_i`` follow ``chi2(dof_i)``
    and ``s = 1``; the median ignores up to half of the points, so a block of bad rows
    that inflated an inferred noise level gives ``s`` well below 1.

    Parameters
    ----------
    m : ndarray, shape (N,)
        Per-point squared whitened residual norms (NaN/inf rows are ignored).
    dof : int or ndarray, shape (N,)
        Their degrees of freedom.

    Returns
    -------
    float
    """
    from scipy import optimize, stats

    m = np.asarray(m, dtype=float)
    dof = np.broadcast_to(np.asarray(dof, dtype=float), m.shape)
    ok = np.isfinite(m) & (dof > 0)
    if ok.sum() < 3:
        return 1.0
    m, dof = m[ok], dof[ok]

    def excess(log_s):
        return np.median(stats.chi2.cdf(m * np.exp(-2.0 * log_s), dof)) - 0.5

    lo, hi = -10.0, 10.0
    if excess(lo) <= 0 or excess(hi) >= 0:
        return float(np.exp(lo if excess(lo) <= 0 else hi))
    return float(np.exp(optimize.brentq(excess, lo, hi, xtol=1e-6)))


def worst_rows(m, dof, n=5):
    """The ``n`` rows (0-based) whose residuals are least likely under the model (ranked by
    the Wilson-Hilferty normal score of ``m / dof``, which, unlike the chi-square tail
    probability, does not underflow to a tie among the far rows)."""
    m = np.asarray(m, dtype=float)
    dof = np.broadcast_to(np.asarray(dof, dtype=float), m.shape)
    v = 2.0 / (9.0 * dof)
    with np.errstate(invalid="ignore", divide="ignore", over="ignore"):
        z = (np.cbrt(np.maximum(m, 0.0) / dof) - (1.0 - v)) / np.sqrt(v)
    return np.argsort(-np.where(np.isfinite(z), z, np.inf), kind="stable")[:n]


def fit_problems(params, prior, *, noise_ratio=None, given_ratio=None):
    """What makes a finished least-squares solution untrustworthy, in words.

    Parameters
    ----------
    params : SensorParams
        The solution.
    prior : Prior
        The priors it was solved with.
    noise_ratio : float, optional
        :func:`robust_noise_ratio` of its residuals when a noise level was inferred.
    given_ratio : float, optional
        :func:`robust_noise_ratio` of its residuals when the noise levels were given.

    Returns
    -------
    list of str
        Empty for a fit that passes (see the module docstring for the rules).
    """
    out = []
    for name, dist in prior.dists.items():
        v, sd = float(getattr(params, name)), float(dist.std())
        lo, hi = DOMAIN.get(name, (-np.inf, np.inf))
        if min(v - lo, hi - v) < BOUND_TOL * sd:
            out.append(f"{name} = {v:.4g} sits on the bound of its domain ({lo:g}, {hi:.4g})")
        elif abs(v - dist.mean()) > PRIOR_SD_LIMIT * sd:
            out.append(f"{name} = {v:.4g} lies {abs(v - dist.mean()) / sd:.0f} prior sds "
                       f"from its prior mean {dist.mean():.4g}")
    if noise_ratio is not None and abs(np.log(noise_ratio)) > np.log(NOISE_RATIO_LIMIT):
        out.append(f"the inferred noise is {1.0 / noise_ratio:.3g} times a robust scale of the "
                   "fit's own residuals: a few bad rows, or errors the model does not describe "
                   "(approximate points sharing a wall's error: give a floor plan), set it and "
                   "every sd with it")
    if given_ratio is not None and given_ratio > GROSS_RATIO:
        out.append(f"the residuals are {given_ratio:.3g} times the noise given (a robust scale "
                   "of them): the noise levels given are too small, or the model does not fit "
                   "the data (see result.model_check())")
    return out


def flag_untrusted(result, prior, m, dof, *, noise_inferred):
    """Mark a least-squares result the solver accepted as not converged when
    :func:`fit_problems` finds it untrustworthy; the message names the rows fitting
    worst (also in ``result.extras["failed_rows"]``).

    Parameters
    ----------
    result : CalibrationResult
        Changed in place.
    prior : Prior
    m : ndarray, shape (N,)
        Per-point squared whitened residual norms at the solution.
    dof : int or ndarray, shape (N,)
        Their degrees of freedom.
    noise_inferred : bool
        Whether a noise level was inferred (its robust scale is checked against the
        inferred level; else against the levels given).
    """
    ratio = robust_noise_ratio(m, dof)
    problems = fit_problems(result.params, prior, noise_ratio=ratio if noise_inferred else None,
                            given_ratio=None if noise_inferred else ratio)
    if not problems:
        return
    rows = worst_rows(m, dof)
    result.converged = False
    result.message = "; ".join(problems) + " (rows fitting worst, 0-based: " + \
        ", ".join(map(str, rows)) + ")"
    result.extras["failed_rows"] = rows


class OffPlanWarning(BayescalWarning):
    """Blocks of neighbouring laser points off their wall were set aside as outliers.

    Furniture, a person in front of a wall, or an opening the floor plan does not show
    (``docs/floorplan.md``, "Furniture"). ``runs``: the list of
    :func:`bayescal.fit.plan_runs.find_runs`.
    """

    def __init__(self, message, runs=()):
        super().__init__(message)
        self.runs = list(runs)


def off_plan_text(runs, *, where=None):
    """The warning about blocks of points off the plan (str; empty without runs).

    Parameters
    ----------
    runs : list of dict
        :func:`bayescal.fit.plan_runs.find_runs`: ``wall``, ``side``, ``rows``,
        ``azimuth_deg``, ``depth_mm``.
    where : callable, optional
        ``where(rows)`` -> text naming the rows' input lines (the CLI's file lines).
    """
    parts = []
    for run in runs:
        a0, a1 = run["azimuth_deg"]
        what = ("furniture or a person the plan does not show?" if run["side"] == "front"
                else "an opening the plan does not show?")
        rows = f" ({where(run['rows'])})" if where is not None else ""
        parts.append(f"{len(run['rows'])} neighbouring laser points{rows} at azimuths "
                     f"{a0:.0f} to {a1:.0f} deg lie about {abs(run['depth_mm']):.0f} mm "
                     f"{'in front of' if run['side'] == 'front' else 'behind'} wall "
                     f"{run['wall']} ({what})")
    if not parts:
        return ""
    return ("; ".join(parts) + ": set aside as outliers, a block off the floor plan; the "
            "parameters are fitted without them (check the room there, or give that surface "
            "as a wall of the plan)")
