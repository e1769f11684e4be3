"""The least squares' EM on approximate points: the MAP of the outlier mixture with the
noise levels inferred or given, from a plain or a high-breakdown start.

Used by :func:`bayescal.calibrate_simultaneous` (``docs/robustness.md``, sections 1 and
4b): :func:`_fit_map` alternates the weighted Schur Levenberg-Marquardt
(:func:`~bayescal.fit.schur.solve_map`), the noise fit (:func:`_fit_noise`, the points
integrated out) and the E-step; :func:`_robust_start` is the start it falls back on when
the plain start ends on a bound or lets a few rows set the noise.
"""

from __future__ import annotations

import numpy as np

from ..checks.fit import robust_noise_ratio
from ..likelihood.outliers import NOISE_TRIM, annealed_outlier_prob, em_update
from .schur import solve_map

__all__ = ["ROBUST_STEPS", "ROBUST_KEEP", "TRIMMED_NOISE_LIMIT", "trimmed_weights"]


class _MapFit:
    """The MAP and the noise levels / outlier state it was solved at (internal)."""

    def __init__(self, **kw):
        self.__dict__.update(kw)

    def extra(self, lik):
        """The likelihood's extra globals at this fit, shape (n_extra,)."""
        e = []
        if lik.infer_px:
            e.append(np.log(self.sig))
        if lik.infer_scene:
            e.append(np.log(self.kappa))
        if lik.outliers:
            e.append(np.log(self.w) - np.log1p(-self.w))
        return np.array(e)

    def w_scene(self, lik):
        if lik.infer_scene:
            return np.ones((1, 3)) / (self.kappa * lik.rho[:, None])
        return lik.w_scene


def _fit_map(lik, prior, theta0, q0, max_iter, max_rounds=30, r_tol=1e-3, robust=False):
    """MAP of the (mixture) model: LM on (theta, q), alternating with the noise levels and,
    with outliers, with the EM responsibilities ``r`` and the outlier fraction ``w``.

    EM for the outlier mixture: the E-step computes each point's outlier probability
    with the points integrated out (:meth:`LaserLikelihood.outlier_prob`); the M-step is
    the least squares with per-point weights ``(1 - r_i) + r_i / c^2`` (the outlier
    component is the same Gaussian with c times the noise) and the logit-scale mode
    ``w = (sum r + a) / (N + a + b)``. The first E-step is taken at the start with the
    noise scaled to the median point's residual (annealing), so that a gross error
    never enters the first fit at full weight. With ``robust`` the EM starts from
    :func:`_robust_start` instead (a high-breakdown start: trimmed fits at a robust
    noise scale).
    """
    a, b = lik.outlier_prior
    fit = _MapFit(sig=1.0 if lik.infer_px else lik.sigma_px, kappa=0.05, sol=None,
                  w=a / (a + b), r=np.zeros(lik.n), n_rounds=0, robust=robust)
    u = np.ones(lik.n)
    if robust:
        theta0, q0 = _robust_start(lik, prior, fit, theta0, q0, max_iter)
        fit.w, u = em_update(fit.r, lik.outlier_prior, lik.outlier_scale)
        inliers = fit.r < 0.5             # the start's inliers: they alone set the noise
    elif lik.outliers:
        fit.r = _initial_outlier_prob(lik, fit, theta0, q0)
        u = em_update(fit.r, lik.outlier_prior, lik.outlier_scale)[1]
    rounds = max_rounds if lik.outliers else 1 + 3 * lik.n_noise
    for k in range(rounds):
        fit.sol = solve_map(lik, prior, theta0, q0, sigma_px=fit.sig, w_scene=fit.w_scene(lik),
                            max_iter=max_iter, weights=u)
        fit.n_rounds = k + 1
        theta0, q0 = fit.sol.theta, fit.sol.q
        old = (fit.sig, fit.kappa)
        if lik.n_noise:
            # the first noise fit leaves out the worst-fitting points (a robust start the
            # bad rows cannot drag: docs/robustness.md), later ones use the mixture
            # (robust: the noise of the robust start's inliers only, so that rows it
            # flagged cannot set the noise again; on clean data the same as plain)
            first = k == 0 and not robust
            fit.sig, fit.kappa = _fit_noise(lik, fit, trim=NOISE_TRIM if first else 0.0,
                                            mask=inliers if robust else None)
        if not lik.outliers:
            continue
        r = lik.outlier_prob(np.concatenate([fit.sol.theta, fit.extra(lik)]), fit.sol.q,
                             n_iter=2)
        r = np.where(np.isfinite(r), r, 1.0)
        change = np.max(np.abs(r - fit.r))
        fit.r = r
        fit.w, u = em_update(r, lik.outlier_prior, lik.outlier_scale)
        noise_change = max(abs(np.log(fit.sig / old[0])), abs(np.log(fit.kappa / old[1])))
        if change < r_tol and noise_change < 1e-4 and k > 0:
            break
    return fit


#: concentration steps of the high-breakdown start, and the fraction of points each keeps
ROBUST_STEPS, ROBUST_KEEP = 4, 0.8
#: an inferred level more than this many times its estimate from the best-fitting
#: ``1 - NOISE_TRIM`` of the points is set by a few rows (clean rooms: 1.10-1.43); it sends
#: the fit to the robust start
TRIMMED_NOISE_LIMIT = 1.75


def trimmed_weights(badness, outlier_scale):
    """A concentration step's weights: 1 for the ``ROBUST_KEEP`` fraction of points with
    the smallest ``badness`` (shape (N,)), the outlier component's ``1/c^2`` for the rest
    (the same trim for the per-point EM and the floor plan's, :mod:`.plan_robust`)."""
    n = len(badness)
    u = np.ones(n)
    u[np.argsort(-np.asarray(badness, float))[:n - int(ROBUST_KEEP * n)]] = \
        1.0 / outlier_scale**2
    return u


def _robust_start(lik, prior, fit, theta, q, max_iter):
    """A start a few bad rows cannot drag, for when the plain EM ended on a bound.

    Least trimmed squares by concentration steps: each step keeps the ``ROBUST_KEEP``
    best-fitting points (the rest at the outlier component's weight ``1/c^2``), holds the
    noise at a robust scale of the residuals (:func:`~bayescal.checks.fit.robust_noise_ratio`,
    the median point's chi-square quantile) and refits; inferred levels are then split by
    the trimmed collapsed likelihood of the kept points. No step lets the noise follow the
    worst rows, so the collapse ``h -> 0`` (cheaper only once bad rows have inflated the
    noise) is never the better explanation. Sets ``fit.sig``, ``fit.kappa``, ``fit.r``
    (outlier probabilities at the result) and returns its ``(theta, q)``.
    """
    from scipy.stats import chi2

    c = lik.outlier_scale
    dof = np.maximum(lik._n_rows - 2, 1)
    for step in range(ROBUST_STEPS):
        m = lik.min_residual(np.concatenate([theta, fit.extra(lik)]), q)
        m = np.where(np.isfinite(m), m, np.inf)
        if lik.n_noise and step == 0:          # the noise at the median point's scale
            s = robust_noise_ratio(m, dof)
            fit.sig, fit.kappa = fit.sig * s, fit.kappa * s
            m = m / s**2
        u = trimmed_weights(-chi2.logsf(m, dof), c)
        fit.sol = solve_map(lik, prior, theta, q, sigma_px=fit.sig, w_scene=fit.w_scene(lik),
                            max_iter=max_iter, weights=u)
        theta, q = fit.sol.theta, fit.sol.q
        if lik.n_noise:
            fit.sig, fit.kappa = _fit_noise(lik, fit, trim=1.0 - ROBUST_KEEP)
    r = lik.outlier_prob(np.concatenate([theta, fit.extra(lik)]), q, n_iter=2)
    fit.r = np.where(np.isfinite(r), r, 1.0)
    return theta, q


def _initial_outlier_prob(lik, fit, theta0, q0):
    """Outlier probabilities at the start (:func:`~.outliers.annealed_outlier_prob`;
    ``m_i`` at the point's own best q, ``dof_i = n_rows_i - 2``)."""
    extra = fit.extra(lik)
    m = lik.min_residual(np.concatenate([theta0, extra]), q0)
    c, n_rows = lik.outlier_scale, lik._n_rows

    def log_ratio(mm):                  # mix's: two latent dimensions, n_rows rows
        return 0.5 * mm * (1.0 - 1.0 / c**2) + (2.0 - n_rows) * np.log(c)

    r = annealed_outlier_prob(m, np.maximum(n_rows - 2, 1), extra[-1], log_ratio)
    return np.zeros(lik.n) if r is None else r


def _fit_noise(lik, fit, trim=0.0, mask=None):
    """Maximise the collapsed likelihood (points integrated out) over the inferred noise.

    The joint maximum over points and noise degenerates (each point can absorb its two
    pixel rows, driving sigma_px to 0); integrating the points out keeps their degrees
    of freedom (the REML-like behaviour of the flat noise prior). With outliers the
    likelihood is the mixture's at the current outlier fraction. With ``trim`` > 0 only
    the best ``1 - trim`` of the points' terms count (a least-trimmed likelihood): a
    block of bad rows (a reflection streak) cannot inflate the noise it is judged by.
    With ``mask`` (N,) bool only those points' terms count.
    """
    from scipy.optimize import minimize

    sol, sig, kappa = fit.sol, fit.sig, fit.kappa
    tail = fit.extra(lik)[lik.n_noise:]
    lik.set_reference_noise(sigma_px=sig, kappa=kappa)
    x0 = []
    if lik.infer_px:
        x0.append(np.log(sig))
    if lik.infer_scene:
        x0.append(np.log(kappa))

    n_keep = lik.n - int(trim * lik.n)

    if mask is not None and np.count_nonzero(mask) < 0.5 * lik.n:
        mask = None                   # not a credible inlier set: all points count

    def f(e):
        psi = np.concatenate([sol.theta, e, tail])
        if n_keep < lik.n or mask is not None:
            terms = lik._laplace_points(psi, sol.q, 3)[0]
            terms = np.where(np.isfinite(terms), terms, -np.inf)
            v = (np.sum(terms[mask]) if mask is not None
                 else np.sum(np.sort(terms)[lik.n - n_keep:]))
        else:
            v = lik.laplace(psi, sol.q, n_iter=3)[0]
        v = v + lik.log_prior_extra(psi[7:])
        return -v if np.isfinite(v) else 1e300

    e = minimize(f, np.array(x0), method="Nelder-Mead",
                 options={"xatol": 1e-4, "fatol": 1e-6}).x
    k = 0
    if lik.infer_px:
        sig = float(np.exp(e[k]))
        k += 1
    if lik.infer_scene:
        kappa = float(np.exp(e[k]))
    return sig, kappa
