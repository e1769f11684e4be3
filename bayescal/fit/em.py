"""The least squares' EM on approximate points: the MAP of the outlier mixture with the
noise levels inferred or given, from a high-breakdown start.

Used by :func:`bayescal.calibrate_simultaneous` (``docs/robustness.md``, sections 1, 4b
and 4c): :func:`_fit_map` runs the concentration steps of :func:`_robust_start` (least
trimmed squares, the noise held at a robust scale), then alternates the weighted Schur
Levenberg-Marquardt (:func:`~bayescal.fit.schur.solve_map`), the noise fit
(:func:`_fit_noise`, the points integrated out) and the E-step. Every fit takes that path:
a plain start whose failure had to be recognised by its symptoms before a robust retry
ran let failures without a symptom through (a near-collapse of ``h`` on no bound).
:func:`_make_result` turns the fit into a :class:`~bayescal.CalibrationResult` (the trust
checks of :func:`~bayescal.checks.fit.flag_untrusted` included).
"""

from __future__ import annotations

import numpy as np

from ..checks.fit import flag_untrusted, robust_noise_ratio
from ..likelihood.outliers import em_update
from ..results.calibration import CalibrationResult, ConvergenceError, identifiability_report
from ..sensor.parameters import (
    IDENTIFIABLE_NAMES,
    PARAM_NAMES,
    SensorParams,
    from_identifiable,
    identifiable_jacobian,
)
from ..sensor.pose import POSE_NAMES, LaserPose
from .schur import solve_map
from .start import ROBUST_KEEP, ROBUST_STEPS, tail_score, trimmed_weights

__all__ = ["ROBUST_STEPS", "ROBUST_KEEP", "CUT_P", "improbable_rows"]


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


def _fit_map(lik, prior, theta0, q0, max_iter, max_rounds=30, r_tol=1e-3):
    """MAP of the (mixture) model from a high-breakdown start: LM on (theta, q), alternating
    with the noise levels and, with outliers, with the EM responsibilities ``r`` and the
    outlier fraction ``w``.

    :func:`_robust_start` first (concentration steps of least trimmed squares at a robust
    noise scale), then EM for the outlier mixture (:func:`_em`), whose E-step also sets
    aside the rows the fitted model makes improbable at p < :data:`CUT_P` (:func:`_cut`).
    """
    a, b = lik.outlier_prior
    fit = _MapFit(sig=1.0 if lik.infer_px else lik.sigma_px, kappa=0.05, sol=None,
                  w=a / (a + b), r=np.zeros(lik.n), n_rounds=0, robust=True,
                  held=np.zeros(lik.n, bool))
    theta0, q0 = _robust_start(lik, prior, fit, theta0, q0, max_iter)
    rounds = max_rounds if lik.outliers else 1 + 3 * lik.n_noise
    return _em(lik, prior, fit, theta0, q0, max_iter, rounds, r_tol)


#: a row whose residual the fitted model makes this improbable (chi-square tail of its
#: squared whitened residual, ``n_rows - 2`` degrees of freedom) is set aside although the
#: mixture keeps it: 0.03 false cuts per 300-row file for a correct model; on the clean
#: rooms of the two generators (24 rooms x noise given or inferred) the smallest tail was
#: 3e-4 with the noise given, and 3 rows in 12 rooms fell below 1e-4 with the noise
#: inferred on relative per-coordinate errors (which an inferred kappa * rho does not
#: describe). The mixture alone keeps a row up to m ~ 37 at w = 1 % (its outlier
#: component is 100 times broader, so its volume costs 3 log 100 nats): corruptions of
#: 5-6 sd, and a streak of 3-4 sd rows that bends the geometry to itself and, with the noise
#: inferred, inflates sigma_px (3x at 1000-1240 mm, isotropic 16-50 mm points) until it
#: looks normal. Set aside rows stay aside.
CUT_P = 1e-4


def _cut(lik, fit):
    """Rows (N,) bool whose residual at the fit has a chi-square tail below :data:`CUT_P`."""
    return improbable_rows(lik, np.concatenate([fit.sol.theta, fit.extra(lik)]), fit.sol.q)


def improbable_rows(lik, psi, q):
    """Rows (N,) bool whose squared whitened residual at ``psi`` (parameters and extra
    globals), each point at its best latent from ``q`` (N, 2), has a chi-square tail below
    :data:`CUT_P`: the least squares' cut, and the posterior's confirmation of it
    (:func:`bayescal.sample_posterior` flags the rows its start cut that the posterior mean
    still fits that badly)."""
    from scipy.stats import chi2

    m = lik.min_residual(psi, q)
    with np.errstate(invalid="ignore"):
        tail = chi2.logsf(np.where(np.isfinite(m), m, np.inf), np.maximum(lik._n_rows - 2, 1))
    return tail < np.log(CUT_P)


def _em(lik, prior, fit, theta0, q0, max_iter, rounds, r_tol):
    """EM for the outlier mixture from the state ``fit`` (its ``r``, ``w``, noise levels):
    the E-step computes each point's outlier probability with the points integrated out
    (:meth:`LaserLikelihood.outlier_prob`), 1 for the rows :func:`_cut` sets aside (they
    stay aside: ``fit.held``); the M-step is the least squares with per-point weights
    ``(1 - r_i) + r_i / c^2`` (the outlier component is the same Gaussian with c times the
    noise) and the logit-scale mode ``w = (sum r + a) / (N + a + b)``. Inferred noise
    levels are fitted to the state's inliers only (``r < 0.5`` at the start, and never a
    row set aside), so that rows set aside cannot set the noise again (on clean data every
    point). Without the mixture, ``rounds`` plain alternations of fit and noise."""
    u, inliers = np.ones(lik.n), None
    if lik.outliers:
        fit.w, u = em_update(fit.r, lik.outlier_prior, lik.outlier_scale)
        inliers = fit.r < 0.5
    for k in range(rounds):
        fit.sol = solve_map(lik, prior, theta0, q0, sigma_px=fit.sig, w_scene=fit.w_scene(lik),
                            max_iter=max_iter, weights=u)
        fit.n_rounds = k + 1
        theta0, q0 = fit.sol.theta, fit.sol.q
        old = (fit.sig, fit.kappa)
        if lik.n_noise:
            fit.sig, fit.kappa = _fit_noise(lik, fit, mask=None if inliers is None
                                            else inliers & ~fit.held)
        if not lik.outliers:
            continue
        fit.held = fit.held | _cut(lik, fit)
        r = lik.outlier_prob(np.concatenate([fit.sol.theta, fit.extra(lik)]), fit.sol.q,
                             n_iter=2)
        r = np.where(np.isfinite(r) & ~fit.held, r, 1.0)
        change = np.max(np.abs(r - fit.r))
        fit.r = r
        fit.w, u = em_update(r, lik.outlier_prior, lik.outlier_scale)
        noise_change = max(abs(np.log(fit.sig / old[0])), abs(np.log(fit.kappa / old[1])))
        if change < r_tol and noise_change < 1e-4 and k > 0:
            break
    return fit


def _robust_start(lik, prior, fit, theta, q, max_iter):
    """A start a few bad rows cannot drag: the path of every fit before a noise level is
    free.

    Least trimmed squares by concentration steps: each step keeps the ``ROBUST_KEEP``
    best-fitting points (ranked by :func:`~bayescal.fit.start.tail_score`; the rest at the
    outlier component's weight ``1/c^2``), holds the noise at a robust scale of the
    residuals (:func:`~bayescal.checks.fit.robust_noise_ratio`, the median point's
    chi-square quantile) and refits; inferred levels are then split by the trimmed
    collapsed likelihood of the kept points. No step lets the noise follow the worst rows,
    so the collapse ``h -> 0`` (cheaper only once bad rows have inflated the noise or
    pulled at full weight) is never the better explanation. Sets ``fit.sig``,
    ``fit.kappa``, ``fit.r`` (outlier probabilities at the result; zeros without the
    mixture) and returns its ``(theta, q)``.
    """
    c = lik.outlier_scale
    dof = np.maximum(lik._n_rows - 2, 1)
    kept = None
    for step in range(ROBUST_STEPS):
        m = lik.min_residual(np.concatenate([theta, fit.extra(lik)]), q)
        m = np.where(np.isfinite(m), m, np.inf)
        if lik.n_noise and step == 0:          # the noise at the median point's scale
            s = robust_noise_ratio(m, dof)
            fit.sig, fit.kappa = fit.sig * s, fit.kappa * s
            m = m / s**2
        u = trimmed_weights(tail_score(m, dof), c)
        if kept is not None and np.count_nonzero((u < 1) != kept) <= 0.01 * lik.n:
            break                   # the trim repeats but for a few borderline points
        kept = u < 1
        # a concentration step needs the trimmed fit's basin, not its last digits
        fit.sol = solve_map(lik, prior, theta, q, sigma_px=fit.sig, w_scene=fit.w_scene(lik),
                            max_iter=max_iter, weights=u, ftol=CONCENTRATION_FTOL)
        theta, q = fit.sol.theta, fit.sol.q
        if lik.n_noise:
            fit.sig, fit.kappa = _bounded(lik, (fit.sig, fit.kappa),
                                          _fit_noise(lik, fit, trim=1.0 - ROBUST_KEEP))
    if lik.outliers:
        r = lik.outlier_prob(np.concatenate([theta, fit.extra(lik)]), q, n_iter=2)
        fit.r = np.where(np.isfinite(r), r, 1.0)
    return theta, q


#: relative cost decrease at which a concentration step's least squares stops (the EM's
#: solves go on to 1e-12): halves its iterations on clean rooms
CONCENTRATION_FTOL = 1e-6


def _bounded(lik, old, new):
    """The start's noise levels: ``new`` (sigma_px, kappa), but a level the trimmed
    likelihood drove within a factor 2 of its prior bound stays at ``old`` (the trim keeps
    the points that fit best, so a level the data barely determine - sigma_px when the
    scene noise is several pixels wide - runs to 0.001 px and every point with it)."""
    from ..likelihood.points import NOISE_BOUNDS

    out = []
    for name, o, v in zip(("sigma_px", "kappa"), old, new, strict=True):
        lo, hi = NOISE_BOUNDS[name]
        out.append(v if 2 * lo < v < hi / 2 else o)
    return tuple(out)


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


def _make_result(lik, prior, fit, absolute_sigma, raise_on_failure):
    n, nt = lik.n, lik.n_geo
    sol, sig, w = fit.sol, fit.sig, np.broadcast_to(fit.w_scene(lik), (n, 3))
    noise = {"sigma_px": sig, "kappa": fit.kappa if lik.infer_scene else None}
    if lik.outliers:
        noise["outlier_frac"] = float(fit.w)
    R = sol.R
    # degrees of freedom of the data rows only: the 8 prior rows carry no noise and
    # phi is fixed by them alone, so neither enters the noise estimate
    n_res = 2 * n + int(np.count_nonzero(w))
    n_unk = nt + 2 * n
    # outliers (probability r) leave the noise statistics: each point counts 1 - r
    keep = 1.0 - fit.r
    n_res_in = float(np.sum(keep * (2 + np.count_nonzero(w, axis=1))))
    chi2 = float(np.sum(keep * np.sum(R * R, axis=1)))
    red = chi2 / max(n_res_in - nt - 2 * np.sum(keep), 1)
    scale = 1.0 if absolute_sigma else red
    theta7 = sol.theta[:7]
    J = identifiable_jacobian(theta7, sol.phi)
    sub = np.r_[0:7, nt]                                # (theta, phi) without the pose
    cov8 = J @ (sol.cov_theta_phi[np.ix_(sub, sub)] * scale) @ J.T
    cov8 = 0.5 * (cov8 + cov8.T)
    params = SensorParams.from_array(from_identifiable(theta7, sol.phi))
    pix_rms, scene_rms = _residual_rms(lik, R, keep, w, sig)
    result = CalibrationResult(
        method="simultaneous", params=params, points=lik.points_3d(sol.theta, sol.q),
        covariance=cov8, covariance_identifiable=sol.cov_theta * scale,
        laser=LaserPose.from_array(sol.theta[7:], h=params.h) if nt > 7 else None,
        residual_rms={"pixel_px": pix_rms, "scene_mm": scene_rms},
        sigma_px_estimated=float(sig * np.sqrt(red)), n_residuals=n_res, n_unknowns=n_unk,
        converged=bool(sol.converged and np.all(np.isfinite(sol.theta))), message=sol.message,
        nfev=sol.nfev, identifiability=_identifiability(sol),
        extras={"point_covariance": sol.cov_points * scale, "map": sol, "noise": noise,
                "theta": sol.theta,
                "identifiable_names": IDENTIFIABLE_NAMES + POSE_NAMES[:nt - 7],
                "reduced_chi2": red, "em_rounds": fit.n_rounds, **_fitted_data(lik),
                "cut_rows": np.flatnonzero(getattr(fit, "held", np.zeros(0, bool))),
                "log_evidence": _log_evidence(lik, prior, fit),
                "pose_prior_sd": (np.array([prior.pose_dists[n].std() for n in POSE_NAMES])
                                  if nt > 7 else None)},
        outlier_prob=fit.r.copy() if lik.outliers else None)
    if result.converged:
        m = lik.min_residual(np.concatenate([sol.theta, fit.extra(lik)]), sol.q)
        flag_untrusted(result, prior, m, np.maximum(lik._n_rows - 2, 1),
                       noise_inferred=bool(lik.n_noise))
    if not result.converged and raise_on_failure:
        raise ConvergenceError(f"simultaneous calibration did not converge: {result.message}",
                               result=result)
    return result


def _log_evidence(lik, prior, fit):
    """Laplace estimate of the log evidence of the fitted model (``docs/model.md``,
    "Which model"): the collapsed log likelihood (points integrated out) and the log
    prior at the MAP, plus ``(d/2) log 2 pi + log det(cov)/2`` of the d geometric
    unknowns; the noise levels and outlier fraction are held at their fitted values.
    Comparable between the aligned and misaligned fits of the same data."""
    sol = fit.sol
    psi = np.concatenate([sol.theta, fit.extra(lik)])
    with np.errstate(invalid="ignore", divide="ignore"):
        value = (lik.laplace(psi, sol.q)[0] + prior.logpdf_theta(psi[:7])
                 + lik.log_prior_extra(psi[7:]))
        sign, logdet = np.linalg.slogdet(sol.cov_theta)
    d = len(sol.theta)
    return float(value + 0.5 * d * np.log(2 * np.pi) + 0.5 * logdet) if sign > 0 else np.nan


def _identifiability(sol):
    """What the data alone (points reduced out by the Schur complement, priors left out)
    determine of the 8 paper parameters (and the pose): square-root rows of that
    information, in the paper's coordinates."""
    nt = len(sol.theta)
    e, V = np.linalg.eigh(0.5 * (sol.info_data + sol.info_data.T))
    root = np.sqrt(np.clip(e, 0, None))[:, None] * V.T
    T = np.zeros((nt, nt + 1))                        # d geometry / d (paper, pose)
    T[:7, :8] = np.linalg.inv(identifiable_jacobian(sol.theta[:7], sol.phi))[:7]
    T[7:, 8:] = np.eye(nt - 7)
    return identifiability_report(root @ T, PARAM_NAMES + POSE_NAMES[:nt - 7])


def _residual_rms(lik, R, keep, w, sig):
    """RMS of the inliers' pixel residuals (px) and scene residuals (mm) at the fit."""
    R_px = R[:, :2]
    if lik.px_white is not None:        # back to px: undo the per-point whitening
        a, b, c = lik.px_white.T
        rv = R_px[:, 1] / c
        R_px = np.stack([(R_px[:, 0] - b * rv) / a, rv], axis=-1)
    pix_rms = float(np.sqrt(np.sum(keep[:, None] * (R_px * sig) ** 2)
                            / max(2 * np.sum(keep), 1e-300)))
    mask = w > 0
    scene_res = np.where(mask, R[:, 2:] / np.where(mask, w, 1.0), 0.0)
    scene_rms = float(np.sqrt(np.sum(keep[:, None] * scene_res**2)
                              / max(np.sum(keep[:, None] * mask), 1e-300)))
    return pix_rms, scene_rms


def _fitted_data(lik):
    """What the result keeps of its data for its model check: pixels, approximate points,
    the per-point pixel covariances and the noise levels that were given (``None`` when
    inferred)."""
    given = not lik.infer_scene
    cov = None
    if lik.px_white is not None:                       # back from L (L^T L = cov^-1)
        a, b, c = lik.px_white.T
        cov = np.linalg.inv(np.stack([np.stack([a * a, a * b], -1),
                                      np.stack([a * b, b * b + c * c], -1)], -2))
    return {"pixels": lik.pixels.copy(), "approx_points": lik.approx.copy(), "pixel_cov": cov,
            "sigma_px": None if lik.infer_px else float(lik.sigma_px),
            "sigma_scene": (np.where(lik.w_scene > 0, 1.0 / np.where(lik.w_scene > 0,
                                                                      lik.w_scene, 1.0),
                                     np.inf) * np.ones((lik.n, 3))) if given else None}
