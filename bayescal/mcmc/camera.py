"""The camera's posterior from board views: emcee over the intrinsics and the noise levels,
every view's pose integrated out by Laplace.

The sampled coordinates are ``(xi, gamma_u, gamma_v, u0, v0, log sigma_k ..., log tau)``
(one ``log sigma`` for the plain model, no ``tau`` without the systematic term). For each
walker, each view's pose starts from the least-squares pose moved by its linear response
to the intrinsics (``-C^-1 B^T dk`` of the Schur blocks) and takes one Gauss-Newton
step (a second changes the log density by < 0.01 on 10 simulated views); the view's pose
integral is then Laplace's (:meth:`BoardLikelihood.log_marginal`, all walkers and views
in one numpy call), as the collapsed sampler integrates laser points.

The proposal: one Newton step from the least-squares result
(:func:`~bayescal.calibrate_camera`, the same noise model) with the target's own
finite-difference Hessian (:func:`laplace_proposal`) gives the mode and the Laplace
covariance of the collapsed posterior; an independence Student-t from them (90 % of the
moves, ``df = 2 ndim``, not inflated) and differential evolution (10 %) sample it. Where
200 draws of that proposal say it would accept less than :data:`LAPLACE_FITS`, the
sampler falls back to :func:`~bayescal.mcmc.steps.tune_proposal`'s rounds from the
least-squares covariance. The stopping rule is :mod:`bayescal.mcmc.steps`'
``tau_factor`` x tau and ESS rule.

Priors: flat in the intrinsics (``xi > 0``), flat in ``log sigma_k``, flat in ``tau >= 0``.

With the default least squares (views weighted by their own noise, the covariance under
the full noise model: a sandwich), the chain samples the model the fit weighted by
(``noise="per-view"``) and its draws of the intrinsics are then moved about their mean so
that their covariance is the least-squares one (the "open-faced sandwich" adjustment of
a posterior from a working likelihood): the posterior keeps the fit's centre and the
noise model's spread, and ``tau`` is the least-squares (REML) value, not sampled.
"""

from __future__ import annotations

import numpy as np

from .._validation import resolve_rng
from ..errors import InvalidValueError
from ..fit.camera import (
    _noise_values,
    _schur,
    calibrate_camera,
    camera_normal_equations,
)
from ..image.views import as_views
from ..likelihood.boards import NOISE_MODELS, BoardLikelihood
from ..results.camera import CameraResult
from ..sensor.board import CAMERA_NAMES
from ..stats.chains import ChainDiagnostics
from .collapsed import check_run_options, default_moves, report_unconverged
from .ensemble import prime_allocator, spd_covariance
from .moves import IndependenceMove
from .steps import (
    de_move,
    default_walkers,
    run_until_converged,
    seeded_sampler,
    tune_proposal,
)

__all__ = ["sample_camera_posterior", "CameraTarget"]


class _Identity:
    """Sampling coordinates are the reported ones for the ESS (log noise levels included)."""

    @staticmethod
    def from_sampling(s):
        return s


class CameraTarget:
    """Vectorised log posterior of ``(intrinsics, log noise)`` with the poses integrated out.

    Parameters
    ----------
    lik : BoardLikelihood
    k_map : ndarray, shape (5,)
    poses_map : ndarray, shape (K, 6)
    response : ndarray, shape (K, 6, 5)
        Linear response of each pose to the intrinsics at the MAP.
    model : str
        The noise model.
    n_steps : int
        Gauss-Newton steps per view and evaluation.
    """

    has_gradient = False

    def __init__(self, lik, k_map, poses_map, response, model, *, n_steps=1):
        self.lik, self.k_map, self.poses_map = lik, k_map, poses_map
        self.response, self.model, self.n_steps = response, model, int(n_steps)

    def _noise(self, s):
        eta = s[:, 5:]
        per_view, systematic = NOISE_MODELS[self.model]
        K = self.lik.K
        sig = np.exp(eta[:, :K]) if per_view else np.repeat(np.exp(eta[:, :1]), K, axis=1)
        t2 = np.exp(2 * eta[:, -1]) if systematic else np.zeros(len(s))
        return sig ** 2, t2

    def __call__(self, s):
        s = np.atleast_2d(np.asarray(s, float))
        k = s[:, :5]
        s2, t2 = self._noise(s)
        poses = self.poses_map + np.einsum("kij,wj->wki", self.response, k - self.k_map)
        with np.errstate(all="ignore"):
            if self.n_steps == 1:                   # the same value, without the pose update
                lm = self.lik.log_marginal(k, poses, s2, t2)
            else:
                lm, _ = self.lik.pose_laplace(k, poses, s2, t2, n_steps=self.n_steps)
        lp = lm.sum(axis=-1)
        if NOISE_MODELS[self.model][1]:
            lp = lp + s[:, -1]                      # flat in tau: Jacobian of log tau
        lp = np.where((k[:, 0] > 0) & np.all(np.isfinite(s), axis=1), lp, -np.inf)
        return np.where(np.isfinite(lp), lp, -np.inf)


#: importance-sampling estimate of the independence move's acceptance from which the
#: Laplace proposal at the target's mode is used as it is (no tuning rounds). Measured:
#: 0.79-0.83 on the five shared real views, ~0.8 on 10 simulated ones (docs/performance.md)
LAPLACE_FITS = 0.4
#: draws that estimate it
N_CHECK = 200
#: the independence proposal's degrees of freedom per dimension, and DEMove's share
IMH_DF_PER_DIM, DE_WEIGHT = 2.0, 0.1


def _fd_points(x, h):
    """Points of a central finite-difference gradient and Hessian about ``x`` (step ``h``)."""
    d = len(x)
    E = np.eye(d) * h
    i, j = np.triu_indices(d, 1)
    pair = [E[i] + E[j], E[i] - E[j], -E[i] + E[j], -E[i] - E[j]]
    return x + np.concatenate([np.zeros((1, d)), E, -E] + pair)


def _fd_hessian(values, h):
    """Gradient and Hessian from the values at :func:`_fd_points` (one vectorised call)."""
    d = len(h)
    f0, fp, fm = values[0], values[1:d + 1], values[d + 1:2 * d + 1]
    i, j = np.triu_indices(d, 1)
    a, b, c, e = values[2 * d + 1:].reshape(4, -1)
    H = np.diag((fp - 2 * f0 + fm) / h ** 2)
    H[i, j] = H[j, i] = (a - b - c + e) / (4 * h[i] * h[j])
    return (fp - fm) / (2 * h), H


def laplace_proposal(target, s0, cov0):
    """Mode and covariance of the collapsed target from one Newton step at ``s0``.

    The gradient and Hessian are central differences with half the ``cov0`` sd as step
    (an average curvature over the bulk), all ``2 d^2 + 1`` points in one call of the
    vectorised target. Returns None where the Hessian is not negative definite.
    """
    h = 0.5 * np.sqrt(np.diag(cov0))
    with np.errstate(all="ignore"):
        g, H = _fd_hessian(target(_fd_points(s0, h)), h)
    if not (np.all(np.isfinite(H)) and np.all(np.isfinite(g))
            and np.all(np.linalg.eigvalsh(H) < 0)):
        return None
    return s0 - np.linalg.solve(H, g), spd_covariance(np.linalg.inv(-H), cov0)


def _imh_check(target, imh, rng, n):
    """Draws of the independence proposal, their log densities and its estimated acceptance
    (``E min(1, w' / w)`` over pairs of importance weights)."""
    x = imh.sample(n, rng)
    lp = target(x)
    logw = lp - imh.log_q(x)
    logw = np.where(np.isfinite(logw), logw, -np.inf)
    logw = logw[:len(logw) // 2 * 2]                       # pairs: an odd last draw is left
    with np.errstate(invalid="ignore", over="ignore"):
        ratio = np.nan_to_num(np.exp(logw[1::2] - logw[::2]), nan=0.0)   # both outside: 0
    return x, lp, float(np.mean(np.minimum(1.0, ratio)))


def _proposal(target, s0, cov0, rng, n_walkers, n_tune):
    """The production run's moves and start: the Laplace proposal at the target's mode where
    it fits (:data:`LAPLACE_FITS`), else :func:`~bayescal.mcmc.steps.tune_proposal`'s rounds
    from the least-squares covariance."""
    ndim = len(s0)
    lap = laplace_proposal(target, s0, cov0)
    if lap is not None:
        imh = IndependenceMove(*lap, scale=1.0, df=IMH_DF_PER_DIM * ndim)
        x, lp, acc = _imh_check(target, imh, np.random.RandomState(rng.integers(2 ** 32)),
                                max(N_CHECK, n_walkers))
        ok = np.flatnonzero(np.isfinite(lp))
        if acc >= LAPLACE_FITS and len(ok) >= n_walkers:
            return {"moves": [(imh, 1.0 - DE_WEIGHT), (de_move(), DE_WEIGHT)],
                    "state": x[ok[:n_walkers]], "acceptance": [acc],
                    "proposal": "Laplace at the mode"}
    p0 = rng.multivariate_normal(s0, cov0, size=n_walkers)
    bad = ~np.isfinite(target(p0))
    p0[bad] = s0
    tuned = tune_proposal(target, p0, s0, cov0, rng, n_steps=int(n_tune))
    return {"moves": default_moves(tuned["mean"], tuned["cov"]), "state": tuned["state"],
            "acceptance": tuned["acceptance"], "proposal": "tuned"}


def _adjusted(cam):
    """Whether the least squares was the weighted fit with a sandwich covariance."""
    return cam.info.get("estimator", "").startswith("per-view weighted")


def _start(views, noise, lsq, fit_options):
    """The least-squares fit, the target (the model the fit weighted by) and the proposal."""
    if lsq is not None and (list(lsq.view_names) != [v.name for v in views]
                            or lsq.noise != noise):
        raise InvalidValueError(
            f"lsq must be calibrate_camera's result on these views with "
            f"noise={noise!r}; got one on {lsq.view_names} with noise={lsq.noise!r}")
    cam = lsq if lsq is not None else calibrate_camera(views, noise=noise, **fit_options)
    lik = BoardLikelihood(views, degree=cam.info.get("degree", 2))
    model = "per-view" if _adjusted(cam) else cam.noise
    per_view, systematic = NOISE_MODELS[model]
    wsig = np.asarray(cam.info.get("weight_sigma", cam.sigma), float)
    sig = wsig if per_view else wsig[:1]
    eta = np.log(np.concatenate([sig, [max(cam.tau, 1e-3)] if systematic else []]))
    s2, t2 = _noise_values(eta, lik.K, model)
    P = camera_normal_equations(lik, cam.k, cam.poses, s2, t2)
    S, _, Cinv, B, _ = _schur(P)
    response = -np.einsum("kij,klj->kil", Cinv, B)
    target = CameraTarget(lik, cam.k, cam.poses, response, model)
    n = len(eta)
    cov = np.zeros((5 + n, 5 + n))
    cov[:5, :5] = np.linalg.inv(S)
    ncov = cam.noise_cov if model == cam.noise and cam.noise_cov is not None else None
    x = np.exp(eta)
    logcov = None if ncov is None else ncov / np.outer(x, x)
    if logcov is None or not (np.all(np.isfinite(logcov))
                              and np.all(np.linalg.eigvalsh(logcov) > 0)):
        # var(log sigma) ~ 1 / (2 dof): a view's 2M - 6 degrees of freedom (all views' less
        # the intrinsics for one level); tau's, one per view
        dof = (np.maximum(lik.n_obs - 6, 1) if per_view
               else [max(int(np.sum(lik.n_obs)) - 5 - 6 * lik.K, 1)])
        logcov = np.diag(1.0 / (2.0 * np.r_[dof, [lik.K] if systematic else []]))
    cov[5:, 5:] = logcov
    return cam, target, np.concatenate([cam.k, eta]), spd_covariance(cov)


def _adjust(flat, cam):
    """Draws of the intrinsics moved about their mean so that their covariance is the
    least-squares (sandwich) one: ``k* = mean + A (k - mean)``, ``A = L_lsq L_post^-1``."""
    k = flat[:, :5]
    mean = k.mean(axis=0)
    L_post = np.linalg.cholesky(np.cov(k, rowvar=False))
    A = np.linalg.cholesky(cam.cov) @ np.linalg.inv(L_post)
    return mean + (k - mean) @ A.T


def sample_camera_posterior(views, rng=None, *, noise="view-systematic", lsq=None,
                            n_walkers=None, min_ess=1000, tau_factor=50, max_steps=20000,
                            n_tune=60, n_samples=2000, progress=False,
                            on_unconverged="warn", **fit_options):
    """Posterior of the camera's intrinsics and noise levels from board views.

    Parameters
    ----------
    views : sequence of BoardView
    rng : Generator, int or None
    noise : str
        The noise model (as :func:`~bayescal.calibrate_camera`).
    lsq : CameraResult, optional
        A least-squares result on the same views and noise model to start from.
    n_walkers : int, optional
        Default :func:`~bayescal.mcmc.steps.default_walkers`.
    min_ess, tau_factor, max_steps : float, float, int
        Stopping rule: kept steps > ``tau_factor`` x tau and ESS >= ``min_ess``.
    n_tune : int
        Steps per tuning round of the proposal (only where the Laplace proposal at the
        mode does not fit, :data:`LAPLACE_FITS`).
    n_samples : int
        Draws kept in the result.
    progress : bool
    on_unconverged : {"warn", "raise"}
    **fit_options
        Passed to :func:`~bayescal.calibrate_camera` (``degree``, ``signs``, ...).

    Returns
    -------
    CameraResult
        ``method = "posterior"``; ``intrinsics`` the posterior mean, ``covariance()``
        from the draws, ``samples`` (n, 5 + noise levels, natural units: px),
        ``diagnostics`` and ``converged``.
    """
    check_run_options(n_walkers=n_walkers, min_ess=min_ess, tau_factor=tau_factor,
                      max_steps=max_steps, n_samples=n_samples, n_tune=n_tune,
                      on_unconverged=on_unconverged)
    rng = resolve_rng(rng)
    prime_allocator()                  # the first call of a process as fast as the next
    views = as_views(views)
    cam, target, s0, cov0 = _start(views, noise, lsq, fit_options)
    ndim = len(s0)
    nw = default_walkers(ndim) if n_walkers is None else int(n_walkers)
    tuned = _proposal(target, s0, cov0, rng, nw, n_tune)
    sampler = seeded_sampler(nw, ndim, target, rng, tuned["moves"])
    info = run_until_converged(sampler, tuned["state"], min_ess=min_ess, tau_factor=tau_factor,
                               max_steps=max_steps, chunk=max(200, 4 * int(n_tune)),
                               progress=progress, coords=_Identity())
    flat = sampler.get_chain()[info["burn"]:].reshape(-1, ndim).copy()
    adjusted = _adjusted(cam)
    if adjusted:
        flat[:, :5] = _adjust(flat, cam)
    K = len(cam.view_names)
    per_view = NOISE_MODELS[target.model][0]
    sig_draws = np.exp(flat[:, 5:5 + (K if per_view else 1)])
    values = [flat[:, :5], sig_draws]
    if NOISE_MODELS[cam.noise][1]:
        tau = np.exp(flat[:, -1]) if NOISE_MODELS[target.model][1] else np.full(len(flat),
                                                                                cam.tau)
        values.append(tau[:, None])
    values = np.concatenate(values, axis=1)
    idx = np.linspace(0, len(flat) - 1, min(int(n_samples), len(flat))).round().astype(int)
    names = list(CAMERA_NAMES) + cam.noise_names
    diag = ChainDiagnostics(names[:ndim], info["tau"], info["ess"], info["n_steps"],
                            info["burn"], nw, float(np.mean(sampler.acceptance_fraction)),
                            info["converged"], tau_factor, min_ess,
                            moves="independence t + DEMove",
                            extra={"tune_acceptance": tuned["acceptance"],
                                   "proposal": tuned["proposal"],
                                   "adjusted_to_least_squares": adjusted})
    mean = values.mean(axis=0)
    post = CameraResult(mean[:5], np.cov(values[:, :5], rowvar=False), cam.poses,
                        cam.residuals, cam.view_names, noise=cam.noise,
                        sigma=np.broadcast_to(mean[5:5 + sig_draws.shape[1]], (K,)),
                        tau=float(mean[-1]) if NOISE_MODELS[cam.noise][1] else 0.0,
                        image_size=cam.image_size, method="posterior", pose_cov=cam.pose_cov,
                        samples=values[idx], diagnostics=diag, info=dict(cam.info))
    report_unconverged(diag, post, what="the camera chain", max_steps=max_steps,
                       on_unconverged=on_unconverged, stacklevel=2)
    return post
