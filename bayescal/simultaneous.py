"""Simultaneous calibration (paper section III): camera and laser cone in one least squares.

Unknowns: the seven identifiable parameters ``theta`` and, by default, every
laser point through its scene coordinates ``q_i = (x_i, y_i)`` (the point is
``(x_i, y_i, rho_i / tan(beta) - h)`` on the cone), i.e. ``7 + 2N`` unknowns
against ``2N`` pixel rows, up to ``3N`` scene rows and 8 weak prior rows.
This is the paper's complete model (eqs. 1 and 6) with the cone written as a
hard constraint: the point's azimuth is the pixel's (eqs. 4-5) through eq. (1).

The solver is Levenberg-Marquardt with the points eliminated by a Schur
complement (each point couples only to ``theta``), so an iteration costs O(N)
and the 580-point room solves in a fraction of a second. The weak priors
(design value +- tolerance, :func:`bayescal.priors.default_prior`) are what keep
the large room from collapsing to ``h -> 0`` (DESIGN fact 3); ``phi`` is fixed
at its prior mean since the data cannot see it (DESIGN fact 1).
"""

from __future__ import annotations

import numpy as np

from .model import OUTLIER_PRIOR, OUTLIER_SCALE, LaserLikelihood
from .parameters import (
    IDENTIFIABLE_NAMES,
    PARAM_NAMES,
    SensorParams,
    from_identifiable,
    identifiable_jacobian,
    to_identifiable,
)
from .priors import Prior
from .results import (
    CalibrationResult,
    ConvergenceError,
    covariance_8_from_identifiable,
    identifiability_report,
)

__all__ = ["calibrate_simultaneous", "solve_map", "MapSolution"]


class MapSolution:
    """Raw output of :func:`solve_map` (internal; users get a CalibrationResult).

    Attributes
    ----------
    theta : ndarray, shape (7,)
    q : ndarray, shape (N, 2)
    cost : float
        Half the sum of squared whitened residuals (prior rows included).
    phi : float
        phi at the MAP (set by the priors alone).
    cov_theta : ndarray, shape (7, 7)
        Laplace covariance of theta (inverse Schur complement), unscaled.
    cov_theta_phi : ndarray, shape (8, 8)
        Laplace covariance of (theta, phi).
    cov_points : ndarray, shape (N, 3, 3)
        Laplace covariance of each 3D point (parameters' uncertainty included).
    """

    def __init__(self, **kw):
        self.__dict__.update(kw)


def _prior_rows(prior, psi):
    """Prior rows on the 8 paper parameters at ``psi = (theta, phi)`` and their Jacobian."""
    a = from_identifiable(psi[:7], psi[7])
    r, D = prior.residuals(a, jacobian=True)
    return r, D @ identifiable_jacobian(psi[:7], psi[7])


def _normal_equations(lik, prior, psi, q, sig, w, u):
    """Normal equations of the point-weighted cost ``sum_i u_i |R_i|^2 / 2 + prior``.

    ``B``, ``C`` and ``gq`` are returned unweighted: a point's weight scales its
    whole block, which leaves its own q-step unchanged and scales its Schur
    contribution to theta by ``u_i`` (see :func:`_schur_step`).
    """
    R, Jt, Jq = lik.residuals(psi[:7], q, sig, w, jacobian=True)
    rp, Jp = _prior_rows(prior, psi)
    A = Jp.T @ Jp
    A[:7, :7] += np.einsum("n,nki,nkj->ij", u, Jt, Jt)
    B = np.zeros((lik.n, 8, 2))
    B[:, :7] = np.einsum("nki,nkj->nij", Jt, Jq)
    C = np.einsum("nki,nkj->nij", Jq, Jq)
    gt = Jp.T @ rp
    gt[:7] += np.einsum("n,nki,nk->i", u, Jt, R)
    gq = np.einsum("nki,nk->ni", Jq, R)
    cost = 0.5 * (np.sum(u * np.sum(R * R, axis=1)) + rp @ rp)
    return cost, A, B, C, gt, gq, R


def _cost(lik, prior, psi, q, sig, w, u):
    R = lik.residuals(psi[:7], q, sig, w)
    rp = prior.residuals(from_identifiable(psi[:7], psi[7]))
    c = 0.5 * (np.sum(u * np.sum(R * R, axis=1)) + rp @ rp)
    return c if np.isfinite(c) else np.inf


def _schur_step(A, B, C, gt, gq, lam, u):
    Ad = A + lam * np.diag(np.diag(A))
    Cd = C.copy()
    Cd[:, [0, 1], [0, 1]] *= 1.0 + lam
    Cinv = np.linalg.inv(Cd)
    BC = np.einsum("nij,njk->nik", B, Cinv) * u[:, None, None]          # (N, 8, 2)
    S = Ad - np.einsum("nik,njk->ij", BC, B)
    rhs = -(gt - np.einsum("nik,nk->i", BC, gq))
    dt = np.linalg.solve(S, rhs)
    dq = -np.einsum("nij,nj->ni", Cinv, gq + np.einsum("nki,k->ni", B, dt))
    return dt, dq


def solve_map(lik, prior, theta0, q0, *, phi=None, sigma_px=None, w_scene=None,
              max_iter=200, ftol=1e-12, xtol=1e-10, weights=None):
    """Levenberg-Marquardt on (theta, phi) and the scene coordinates (noise levels fixed).

    ``phi`` is an unknown like the others, but only the prior rows see it: the
    solution sits on the phi/alpha ridge where the priors of phi, alpha_u and
    alpha_v balance, and the Laplace covariance carries that ridge.

    Parameters
    ----------
    lik : LaserLikelihood
    prior : Prior
    theta0 : ndarray, shape (7,)
    q0 : ndarray, shape (N, 2)
    phi : float, optional
        Starting phi (default: the prior mean).
    sigma_px : float
        Pixel noise used for whitening.
    w_scene : ndarray, shape (N, 3)
        Inverse scene standard deviations.
    weights : ndarray, shape (N,), optional
        Per-point weights ``u_i`` of the squared residuals (default 1): the
        M-step of the outlier mixture's EM, ``u_i = (1 - r_i) + r_i / c^2``.

    Returns
    -------
    MapSolution
    """
    phi = float(prior.dists["phi"].mean()) if phi is None else float(phi)
    sig = np.asarray(sigma_px, dtype=float)
    theta = np.append(np.asarray(theta0, dtype=float), phi)
    q = np.array(q0, dtype=float)
    u = np.ones(lik.n) if weights is None else np.asarray(weights, dtype=float)
    lam, nfev, converged, message = 1e-3, 1, False, "maximum number of iterations reached"
    cost, A, B, C, gt, gq, R = _normal_equations(lik, prior, theta, q, sig, w_scene, u)
    if not np.isfinite(cost):
        raise ValueError("the starting point puts some laser points outside the model's "
                         "domain (non-finite residuals); give a better init")
    n_done = 0
    for n_done in range(1, max_iter + 1):  # noqa: B007 (n_done is reported after the loop)
        improved = False
        for _ in range(30):
            try:
                dt, dq = _schur_step(A, B, C, gt, gq, lam, u)
            except np.linalg.LinAlgError:
                lam *= 10
                continue
            new_cost = _cost(lik, prior, theta + dt, q + dq, sig, w_scene, u)
            nfev += 1
            if new_cost < cost:
                improved = True
                break
            lam *= 4.0
        if not improved:
            converged, message = True, "no further decrease of the cost (at a minimum)"
            break
        small_step = (np.all(np.abs(dt) <= xtol * (np.abs(theta) + xtol))
                      and np.all(np.abs(dq) <= xtol * (np.abs(q) + 1.0)))
        theta, q = theta + dt, q + dq
        rel = (cost - new_cost) / max(new_cost, 1e-300)
        cost, A, B, C, gt, gq, R = _normal_equations(lik, prior, theta, q, sig, w_scene, u)
        lam = max(lam / 3.0, 1e-12)
        if rel < ftol or small_step:
            converged, message = True, "converged (relative cost decrease or step below tolerance)"
            break
    # Laplace covariance at the solution (undamped Schur complement)
    Cinv = np.linalg.inv(C)
    BC = np.einsum("nij,njk->nik", B, Cinv) * u[:, None, None]
    S = A - np.einsum("nik,njk->ij", BC, B)
    cov_full = np.linalg.inv(S)                      # (theta, phi)
    _, Jp = _prior_rows(prior, theta)
    info_data = (S - Jp.T @ Jp)[:7, :7]              # what the data alone say about theta
    cov_t = cov_full[:7, :7]
    return MapSolution(theta=theta[:7], q=q, cost=float(cost), cov_theta=cov_t,
                       cov_theta_phi=cov_full, Cinv=Cinv, B=B[:, :7], R=R, A=A, nfev=nfev,
                       n_iter=n_done, converged=converged, message=message, phi=float(theta[7]),
                       info_data=info_data, weights=u,
                       cov_points=_point_covariances(theta[:7], q, Cinv, B[:, :7], cov_t, u))


def _point_covariances(theta, q, Cinv, B, cov_t, u):
    """3x3 covariance of each point from the joint Laplace covariance of (theta, q).

    A point of weight ``u_i`` has its own block ``u_i C_i``: its conditional
    covariance is ``C_i^-1 / u_i`` (an outlier's point is barely determined).
    """
    from .laser import cone_point_theta

    _, Gq, Gt = cone_point_theta(theta, q, jacobian=True)       # (N,3,2), (N,3,7)
    K = -np.einsum("nij,nkj,kl->nil", Cinv, B, cov_t)            # cov(q_i, theta): (N,2,7)
    cov_q = Cinv / u[:, None, None] + np.einsum("nij,nkj,kl,nlm,nmp->nip", Cinv, B, cov_t, B, Cinv)
    out = (np.einsum("nia,nab,njb->nij", Gq, cov_q, Gq)
           + np.einsum("nia,nab,njb->nij", Gq, K, Gt)
           + np.einsum("nia,nab,njb->nij", Gt, np.swapaxes(K, 1, 2), Gq)
           + np.einsum("nia,ab,njb->nij", Gt, cov_t, Gt))
    return out


def _resolve_init(init, prior):
    if init is None:
        return prior.mean()
    if isinstance(init, SensorParams):
        return init
    raise TypeError(f"init must be a SensorParams or None, got {type(init).__name__}")


def calibrate_simultaneous(pixels, approx_points, *, sigma_px, sigma_scene, prior=None,
                           init=None, estimate_points=True, absolute_sigma=True,
                           max_iter=200, raise_on_failure=True, outliers=True,
                           outlier_scale=OUTLIER_SCALE, outlier_prior=OUTLIER_PRIOR):
    """Calibrate camera and laser cone together from laser pixels and approximate points.

    Parameters
    ----------
    pixels : array_like, shape (N, 2)
        Laser pixels ``(u, v)``, px.
    approx_points : array_like, shape (N, 3)
        Approximate 3D positions of the laser points in frame C, mm.
    sigma_px : float or None
        Pixel noise standard deviation, px; ``None`` estimates it (alternating
        with the fit, from the pixel residuals).
    sigma_scene : float, array_like broadcastable to (N, 3), or None
        Standard deviation of the approximate points' error, mm (``inf`` on
        an axis = no information, e.g. z derived from the nominal cone). A
        relative error is passed as e.g. ``0.05 * abs(approx_points)``.
        ``None`` estimates ``kappa`` in ``sigma_scene_i = kappa * rho_i``.
    prior : dict, optional
        ``{name: scipy.stats frozen distribution}`` for any of the eight
        parameters; the rest keep :func:`~bayescal.priors.default_prior`.
    init : SensorParams, optional
        Starting values (default: the prior means).
    estimate_points : bool, optional
        Estimate the N points with the parameters (default, the paper's
        ``3N + 8`` unknowns written as ``2N + 7`` identifiable ones). With
        False the points are taken as exact (``approx_points``), only their
        pixel rows enter, and the cone is fitted through them.
    absolute_sigma : bool, optional
        If True (default) the covariance uses the given noise levels as they
        are; if False it is scaled by the reduced chi-square (the classical
        least-squares convention).
    max_iter : int, optional
    raise_on_failure : bool, optional
        Raise :class:`~bayescal.ConvergenceError` (carrying the flagged result)
        when the solver does not converge; otherwise return it with
        ``converged=False``.
    outliers : bool, optional
        Per-point outlier mixture (default True): each point is an inlier with
        probability ``1 - w`` or an outlier whose residuals have
        ``outlier_scale`` times the noise; solved by EM (weighted Schur LM).
        ``result.outlier_prob`` (N,) gives each point's outlier probability.
        On clean data it changes nothing that matters (``docs/robustness.md``).
        Ignored with ``estimate_points=False``.
    outlier_scale : float, optional
        Noise inflation of the outlier component (default 100).
    outlier_prior : tuple of float, optional
        Beta(a, b) prior of the outlier fraction ``w`` (default (1, 19)).

    Returns
    -------
    CalibrationResult
        ``params``; ``points`` (N, 3) the jointly estimated laser points
        (``estimate_points=True``) or the triangulated pixels; ``covariance``
        (8, 8) with ``phi``'s prior variance on the phi/alpha ridge;
        ``extras["point_covariance"]`` (N, 3, 3); ``extras["map"]``.

    Examples
    --------
    >>> import bayescal as bc
    >>> ds = bc.simulate_room(range_mm=1000, sigma_px=0.5, approx_error=0.01,
    ...                       approx_model="gaussian", rng=0)
    >>> res = bc.calibrate_simultaneous(ds.pixels, ds.approx_points, sigma_px=0.5,
    ...                                 sigma_scene=ds.sigma_scene)
    >>> res.converged
    True
    """
    lik = LaserLikelihood(pixels, approx_points, sigma_px=sigma_px, sigma_scene=sigma_scene,
                          outliers=outliers and estimate_points, outlier_scale=outlier_scale,
                          outlier_prior=outlier_prior)
    n = lik.n
    if n < 4:
        raise ValueError(f"need at least 4 laser points, got N={n}")
    prior = prior if isinstance(prior, Prior) else Prior(prior)
    init = _resolve_init(init, prior)
    az = np.arctan2(lik.pixels[:, 1] - init.v0, lik.pixels[:, 0] - init.u0)
    if np.abs(np.mean(np.exp(1j * az))) > 0.99:
        raise ValueError("pixels: all laser pixels lie at (nearly) one azimuth around the "
                         f"principal point ({init.u0:g}, {init.v0:g}); the cone and the principal "
                         "point cannot be separated: use points spread around the laser ring")
    theta0 = to_identifiable(init.to_array())
    q0 = lik.initial_q(theta0)
    if not estimate_points:
        return _calibrate_fixed_points(lik, prior, init, absolute_sigma, raise_on_failure)

    fit = _fit_map(lik, prior, theta0, q0, max_iter)
    return _make_result(lik, prior, fit, absolute_sigma, raise_on_failure)


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
    """MAP of the (mixture) model: LM on (theta, q), alternating with the noise levels and,
    with outliers, with the EM responsibilities ``r`` and the outlier fraction ``w``.

    EM for the outlier mixture: the E-step computes each point's outlier probability
    with the points integrated out (:meth:`LaserLikelihood.outlier_prob`); the M-step is
    the least squares with per-point weights ``(1 - r_i) + r_i / c^2`` (the outlier
    component is the same Gaussian with c times the noise) and the logit-scale mode
    ``w = (sum r + a) / (N + a + b)``. The first E-step is taken at the start with the
    noise scaled to the median point's residual (annealing), so that a gross error
    never enters the first fit at full weight.
    """
    a, b = lik.outlier_prior
    fit = _MapFit(sig=1.0 if lik.infer_px else lik.sigma_px, kappa=0.05, sol=None,
                  w=a / (a + b), r=np.zeros(lik.n), n_rounds=0)
    u = np.ones(lik.n)
    if lik.outliers:
        fit.r = _initial_outlier_prob(lik, fit, theta0, q0)
        u = _weights(lik, fit.r)
    rounds = max_rounds if lik.outliers else 1 + 3 * lik.n_noise
    for k in range(rounds):
        fit.sol = solve_map(lik, prior, theta0, q0, sigma_px=fit.sig, w_scene=fit.w_scene(lik),
                            max_iter=max_iter, weights=u)
        fit.n_rounds = k + 1
        theta0, q0 = fit.sol.theta, fit.sol.q
        old = (fit.sig, fit.kappa)
        if lik.n_noise:
            fit.sig, fit.kappa = _fit_noise(lik, fit)
        if not lik.outliers:
            continue
        r = lik.outlier_prob(np.concatenate([fit.sol.theta, fit.extra(lik)]), fit.sol.q,
                             n_iter=2)
        r = np.where(np.isfinite(r), r, 1.0)
        change = np.max(np.abs(r - fit.r))
        fit.r, fit.w = r, (np.sum(r) + a) / (lik.n + a + b)
        u = _weights(lik, r)
        noise_change = max(abs(np.log(fit.sig / old[0])), abs(np.log(fit.kappa / old[1])))
        if change < r_tol and noise_change < 1e-4 and k > 0:
            break
    return fit


def _weights(lik, r):
    """EM weights of the squared residuals, ``(1 - r) + r / c^2``, shape (N,)."""
    return (1.0 - r) + r / lik.outlier_scale**2


def _initial_outlier_prob(lik, fit, theta0, q0):
    """Outlier probabilities at the start, with the noise scaled to the median point.

    At the prior mean every point misfits by several noise sd; scaling the noise by
    ``T = sqrt(median m_i / median chi2(dof_i))`` (``m_i`` the point's squared whitened
    residual at its own best q, ``dof_i = n_rows_i - 2``) makes the typical point an
    inlier and leaves the gross errors far out.
    """
    from scipy.stats import chi2

    extra = fit.extra(lik)
    m = lik.min_residual(np.concatenate([theta0, extra]), q0)
    ok = np.isfinite(m)
    if not np.any(ok):
        return np.zeros(lik.n)
    T2 = max(1.0, float(np.median(m[ok] / chi2.median(np.maximum(lik._n_rows[ok] - 2, 1)))))
    _, r = lik._mix(extra, np.zeros(lik.n), np.where(ok, m / T2, np.inf), laplace=True)
    return np.where(ok, r, 1.0)


def _fit_noise(lik, fit):
    """Maximise the collapsed likelihood (points integrated out) over the inferred noise.

    The joint maximum over points and noise degenerates (each point can absorb its two
    pixel rows, driving sigma_px to 0); integrating the points out keeps their degrees
    of freedom (the REML-like behaviour of the flat noise prior). With outliers the
    likelihood is the mixture's at the current outlier fraction.
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

    def f(e):
        v = lik.laplace(np.concatenate([sol.theta, e, tail]), sol.q, n_iter=3)[0]
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
    from .laser import cone_point_theta

    n = lik.n
    sol, sig, w = fit.sol, fit.sig, np.broadcast_to(fit.w_scene(lik), (n, 3))
    noise = {"sigma_px": sig, "kappa": fit.kappa if lik.infer_scene else None}
    if lik.outliers:
        noise["outlier_frac"] = float(fit.w)
    R = sol.R
    # degrees of freedom of the data rows only: the 8 prior rows carry no noise and
    # phi is fixed by them alone, so neither enters the noise estimate
    n_res = 2 * n + int(np.count_nonzero(w))
    n_unk = 7 + 2 * n
    # outliers (probability r) leave the noise statistics: each point counts 1 - r
    keep = 1.0 - fit.r
    n_res_in = float(np.sum(keep * (2 + np.count_nonzero(w, axis=1))))
    chi2 = float(np.sum(keep * np.sum(R * R, axis=1)))
    red = chi2 / max(n_res_in - 7 - 2 * np.sum(keep), 1)
    scale = 1.0 if absolute_sigma else red
    cov7 = sol.cov_theta * scale
    J = identifiable_jacobian(sol.theta, sol.phi)
    cov8 = J @ (sol.cov_theta_phi * scale) @ J.T
    cov8 = 0.5 * (cov8 + cov8.T)
    params = SensorParams.from_array(from_identifiable(sol.theta, sol.phi))
    points = cone_point_theta(sol.theta, sol.q)
    pix_rms = float(np.sqrt(np.sum(keep[:, None] * (R[:, :2] * sig) ** 2)
                            / max(2 * np.sum(keep), 1e-300)))
    mask = w > 0
    scene_res = np.where(mask, R[:, 2:] / np.where(mask, w, 1.0), 0.0)
    scene_rms = float(np.sqrt(np.sum(keep[:, None] * scene_res**2)
                              / max(np.sum(keep[:, None] * mask), 1e-300)))
    sigma_hat = float(sig * np.sqrt(red))
    # identifiability of the 8 paper parameters from the data alone (points reduced out
    # by the Schur complement, priors left out): square-root rows of that information
    e, V = np.linalg.eigh(0.5 * (sol.info_data + sol.info_data.T))
    root = np.sqrt(np.clip(e, 0, None))[:, None] * V.T
    dtheta_da = np.linalg.inv(identifiable_jacobian(sol.theta, sol.phi))[:7]   # (7, 8)
    report = identifiability_report(root @ dtheta_da, PARAM_NAMES)
    result = CalibrationResult(
        method="simultaneous", params=params, points=points, covariance=cov8,
        covariance_identifiable=cov7,
        residual_rms={"pixel_px": pix_rms, "scene_mm": scene_rms},
        sigma_px_estimated=sigma_hat, n_residuals=n_res, n_unknowns=n_unk,
        converged=bool(sol.converged and np.all(np.isfinite(sol.theta))), message=sol.message,
        nfev=sol.nfev, identifiability=report,
        extras={"point_covariance": sol.cov_points * scale, "map": sol, "noise": noise,
                "theta": sol.theta, "identifiable_names": IDENTIFIABLE_NAMES,
                "reduced_chi2": red, "em_rounds": fit.n_rounds},
        outlier_prob=fit.r.copy() if lik.outliers else None)
    if not result.converged and raise_on_failure:
        raise ConvergenceError(f"simultaneous calibration did not converge: {sol.message}",
                               result=result)
    return result


def _calibrate_fixed_points(lik, prior, init, absolute_sigma, raise_on_failure):
    """Points taken as exact: pixel rows of eq. (1) and the cone through the points."""
    from scipy.optimize import least_squares

    from .camera import project_theta
    from .laser import triangulate_theta

    if lik.infer_px or lik.infer_scene:
        raise ValueError("estimate_points=False needs sigma_px and sigma_scene given (not None)")
    sig = lik.sigma_px
    P = lik.approx
    phi = float(prior.dists["phi"].mean())
    # scene sd along the cone normal, per point
    rho = np.hypot(P[:, 0], P[:, 1])

    def fun(t):
        uv, _ = project_theta(t, P)
        b = t[6]
        nrm = np.stack([np.cos(b) * P[:, 0] / rho, np.cos(b) * P[:, 1] / rho,
                        np.full(len(P), -np.sin(b))], -1)
        with np.errstate(divide="ignore"):
            var_n = np.sum(nrm**2 / lik.w_scene**2, axis=1)       # inf where an axis is blind
        s_n = 1.0 / np.sqrt(var_n)
        dist = rho * np.cos(b) - (P[:, 2] + t[5]) * np.sin(b)
        rp = prior.residuals(from_identifiable(t, phi))
        return np.concatenate([((uv - lik.pixels) / sig).ravel(), dist * s_n, rp])

    t0 = to_identifiable(init.to_array())
    opt = least_squares(fun, t0, x_scale="jac", method="lm", xtol=1e-12, ftol=1e-12)
    J = opt.jac
    data_rows = opt.fun[:-8]                          # the last 8 rows are the priors
    n_res, n_unk = len(data_rows), 7
    red = float(data_rows @ data_rows) / max(n_res - n_unk, 1)
    cov7 = np.linalg.inv(J.T @ J) * (1.0 if absolute_sigma else red)
    cov8 = covariance_8_from_identifiable(opt.x, phi, cov7, float(prior.dists["phi"].var()))
    params = SensorParams.from_array(from_identifiable(opt.x, phi))
    pts, _ = triangulate_theta(opt.x, lik.pixels)
    uv, _ = project_theta(opt.x, P)
    dtheta_da = np.linalg.inv(identifiable_jacobian(opt.x, phi))[:7]
    result = CalibrationResult(
        method="simultaneous", params=params, points=pts, covariance=cov8,
        covariance_identifiable=cov7,
        residual_rms={"pixel_px": float(np.sqrt(np.mean((uv - lik.pixels) ** 2)))},
        sigma_px_estimated=float(sig * np.sqrt(red)), n_residuals=n_res, n_unknowns=n_unk,
        converged=bool(opt.success), message=str(opt.message), nfev=int(opt.nfev),
        identifiability=identifiability_report(J @ dtheta_da, PARAM_NAMES),
        extras={"theta": opt.x, "reduced_chi2": red})
    if not result.converged and raise_on_failure:
        raise ConvergenceError(f"simultaneous calibration did not converge: {opt.message}",
                               result=result)
    return result
