"""Posterior sampling: a collapsed emcee sampler over the identifiable parameters.

The joint posterior over the 8 parameters and the N laser points has ``7 + k N``
free dimensions (``phi`` is not seen by the data); emcee does not mix there
(``docs/bayes.md`` section 3). The points are independent given the globals
``psi = (theta, extras)``, so :func:`sample_collapsed` samples ``psi`` with every
point integrated out by a Laplace step, then draws the points. Its steps
(:mod:`bayescal.sampler_steps`):

1. **MAP start** (:func:`sample_posterior` only): :func:`bayescal.calibrate_simultaneous`
   gives ``psi_map``, its Laplace covariance and the points ``q_map``;
2. **proposal fit**: adaptive importance sampling fits a Student-t to the collapsed
   posterior (sampling coordinates, :func:`~bayescal.sampler_steps.to_sampling`);
3. **walker placement**: the walkers start from the fit's weighted draws;
4. **production run**: emcee with the fitted independence proposal (80 %) and
   differential evolution (20 %), in chunks until the kept chain is longer than
   ``tau_factor`` autocorrelation times and the honest ESS (ensemble-mean based,
   :func:`bayescal.diagnostics.ensemble_ess`) reaches ``min_ess``;
5. **draws**: ``phi`` from its exact conditional, each point from its Laplace
   Gaussian corrected by independence Metropolis-Hastings
   (:func:`bayescal.model.draw_points`);
6. **assembly**: a :class:`~bayescal.posterior.Posterior` carrying a
   :class:`~bayescal.diagnostics.ChainDiagnostics`.

Any likelihood providing ``n``, ``extra_names``, ``log_prior_extra``, ``laplace``,
``point_log_density`` and ``points_3d`` can be sampled by :func:`sample_collapsed`.
"""

from __future__ import annotations

import warnings

import numpy as np

from ._validation import resolve_rng
from .diagnostics import ChainDiagnostics, integrated_time
from .floorplan import FloorPlan
from .model import NOISE_BOUNDS, LaserLikelihood, draw_points
from .moves import HMCMove, IndependenceMove
from .parameters import from_identifiable
from .plan_sampling import SCENE_REQUIRED, sample_plan_posterior
from .priors import Prior
from .sampler_steps import (
    HMC_LEAPFROG,
    CollapsedTarget,
    from_sampling,
    ring_scale,
    run_until_converged,
    sampling_jacobian,
    seeded_sampler,
    to_sampling,
    tune_proposal,
)

__all__ = ["sample_posterior", "sample_collapsed", "sample_joint", "NotConvergedWarning",
           "NotConvergedError", "NoiseAtBoundWarning", "default_moves", "NOISE_BOUNDS",
           "ring_scale", "to_sampling", "from_sampling"]

#: shares of the HMC and independence moves in the production run (the rest: DEMove)
HMC_WEIGHT = 0.3
IMH_WEIGHT = 0.6
#: HMC trajectory length in whitened units (sets the leapfrog count from the tuned step)
HMC_PATH = 1.5



class NotConvergedWarning(UserWarning):
    """The chain did not meet its convergence rule (results may be biased)."""


class NoiseAtBoundWarning(UserWarning):
    """An inferred noise level's posterior piles up at its prior's lower bound."""


class NotConvergedError(RuntimeError):
    """The chain did not converge; ``.tau`` holds the autocorrelation times, ``.posterior``
    the (unconverged) result."""

    def __init__(self, message, tau=None, posterior=None):
        super().__init__(message)
        self.tau = tau
        self.posterior = posterior


def default_moves(mean=None, cov=None, *, value_and_grad=None, step_size=0.3,
                  n_leapfrog=None):
    """emcee moves used by default.

    With a proposal ``mean`` and ``cov`` and a gradient ``value_and_grad`` (the
    collapsed target's): :class:`~bayescal.moves.HMCMove` (``HMC_WEIGHT``, mass
    matrix ``cov^-1``, leapfrog step ``step_size`` in whitened units),
    :class:`~bayescal.moves.IndependenceMove` (``IMH_WEIGHT``, cheap, jumps
    between distant parts where the proposal fits) and :class:`emcee.moves.DEMove`
    (the rest). Without a gradient: the independence proposal (80 %) and DEMove
    (20 %). Without a proposal: DEMove (80 %) and StretchMove (20 %).
    ``DESnookerMove`` is deliberately absent: in emcee 3.1.6 it samples the wrong
    distribution (``docs/bayes.md`` section 3). Each move here is tested on N(0, I).
    """
    import emcee

    if mean is None:
        return [(emcee.moves.DEMove(), 0.8), (emcee.moves.StretchMove(), 0.2)]
    if value_and_grad is None:
        return [(IndependenceMove(mean, cov, scale=1.1), 0.8),
                (emcee.moves.DEMove(), 0.2)]
    n_leapfrog = HMC_LEAPFROG if n_leapfrog is None else int(n_leapfrog)
    moves = [(HMCMove(value_and_grad, cov, step_size=step_size, n_steps=n_leapfrog),
              HMC_WEIGHT),
             (IndependenceMove(mean, cov, scale=1.1), IMH_WEIGHT),
             (emcee.moves.DEMove(), 1.0 - HMC_WEIGHT - IMH_WEIGHT)]
    return [(m, w) for m, w in moves if w > 0]


def _moves_text(moves):
    if moves is None:
        return "default"
    return ", ".join(f"{type(m).__name__} {w:.0%}" for m, w in moves)


def _start(target, s_map, cov_s, rng, n_walkers, n_tune, moves):
    """Walker placement and proposal tuning (steps 2-3), in sampling coordinates."""
    p0 = rng.multivariate_normal(s_map, cov_s, size=n_walkers)
    lp0 = target(p0)
    for _ in range(100):
        bad = ~np.isfinite(lp0)
        if not bad.any():
            break
        p0[bad] = rng.multivariate_normal(s_map, cov_s * 0.01, size=int(bad.sum()))
        lp0[bad] = target(p0[bad])
    else:
        raise RuntimeError("could not place the walkers: the MAP start is outside the support")
    if n_tune <= 0:
        return {"mean": s_map, "cov": cov_s, "state": p0, "acceptance": [], "step_size": 0.3}
    return tune_proposal(target, p0, s_map, cov_s, rng, n_steps=n_tune, moves=moves,
                         gradient=target.has_gradient)


def _thin(chain, burn, n_samples):
    """``n_samples`` states thinned evenly from the kept chain (steps, walkers, d)."""
    flat = chain[burn:].reshape(-1, chain.shape[-1])
    if len(flat) == 0:
        flat = chain[-1]
    idx = np.linspace(0, len(flat) - 1, min(int(n_samples), len(flat))).round().astype(int)
    return flat[idx]


def sample_collapsed(lik, prior, psi_map, cov_psi_map, q_map, *, rng=None, n_walkers=None,
                     min_ess=1000, tau_factor=50, max_steps=20000, n_samples=2000,
                     moves=None, progress=True, n_point_mh=2, n_iter=1, n_tune=None):
    """Sample the globals ``psi`` with the points integrated out, then draw the points.

    Parameters
    ----------
    lik : likelihood
        Any object of the collapsed-sampler protocol (``n``, ``extra_names``,
        ``log_prior_extra``, ``laplace``, ``point_log_density``, ``points_3d``).
    prior : Prior
        Prior of the paper parameters (theta's prior with phi integrated out).
    psi_map : array_like, shape (d,)
        Start: theta (7,) then the extra globals, as ``lik.laplace`` takes them.
    cov_psi_map : array_like, shape (d, d)
        Laplace covariance at ``psi_map`` (a rough one will do: it is refitted).
    q_map : array_like, shape (N, k)
        Latent point coordinates at the MAP (start of the Laplace steps).
    rng, n_walkers, min_ess, tau_factor, max_steps, n_samples, moves, progress,
    n_point_mh, n_iter :
        As in :func:`sample_posterior`.
    n_tune : int, optional
        Steps per tuning round (default 60 with a gradient, else 150).

    Returns
    -------
    dict
        ``psi`` (S, d) samples, ``q`` (S, N, k) point draws, ``diagnostics``
        (:class:`~bayescal.diagnostics.ChainDiagnostics`), ``imh_acceptance``.
    """
    rng = resolve_rng(rng)
    ndim = len(psi_map)
    n_walkers = 2 * ndim + 2 if n_walkers is None else int(n_walkers)
    target = CollapsedTarget(lik, prior, q_map, n_iter)
    if n_tune is None:                      # HMC mixes fast: short tuning rounds suffice
        n_tune = 60 if target.has_gradient and moves is None else 150
    n_tune = int(n_tune)
    J = sampling_jacobian(psi_map)
    s_map, cov_s = to_sampling(psi_map), J @ np.asarray(cov_psi_map, float) @ J.T
    fit = _start(target, s_map, cov_s, rng, n_walkers, n_tune, moves)
    p0 = fit["state"]
    vg = target.value_and_grad if target.has_gradient else None
    # a trajectory of ~1.5 whitened units: more leapfrog steps where the step had to shrink
    n_leap = int(np.clip(round(HMC_PATH / fit["step_size"]), HMC_LEAPFROG, 3 * HMC_LEAPFROG))
    prod_moves = default_moves(fit["mean"], fit["cov"], value_and_grad=vg,
                               step_size=fit["step_size"], n_leapfrog=n_leap) \
        if moves is None else moves
    sampler = seeded_sampler(n_walkers, ndim, target, rng, prod_moves)
    info = run_until_converged(sampler, p0, min_ess=min_ess, tau_factor=tau_factor,
                               max_steps=int(max_steps), chunk=100, progress=progress)
    diag = ChainDiagnostics(
        names=("xi", "gamma_u", "gamma_v", "u0", "v0", "h", "beta") + tuple(lik.extra_names),
        tau=info["tau"], ess=info["ess"], n_steps=info["n_steps"], burn=info["burn"],
        n_walkers=n_walkers, acceptance=float(np.mean(sampler.acceptance_fraction)),
        converged=info["converged"], tau_factor=float(tau_factor), min_ess=float(min_ess),
        moves=_moves_text(prod_moves),
        extra={"tuning_acceptance": fit["acceptance"], "n_evaluations": int(target.n_calls),
               "hmc_step_size": fit["step_size"]})
    psi = from_sampling(_thin(sampler.get_chain(), info["burn"], n_samples))
    # ~5e5 (sample, point) pairs per vectorized call bound the temporaries' memory
    q, imh_acc = draw_points(lik, psi, q_map, rng, n_mh=n_point_mh, n_iter=n_iter + 2,
                             batch=max(1, 500_000 // max(lik.n, 1)))
    return {"psi": psi, "q": q, "diagnostics": diag, "imh_acceptance": imh_acc}


def sample_posterior(pixels, approx_points, *, sigma_px, sigma_scene=SCENE_REQUIRED, prior=None,
                     rng=None, n_walkers=None, min_ess=1000, tau_factor=50, max_steps=20000,
                     n_samples=2000, init=None, moves=None, progress=True,
                     on_unconverged="warn", n_point_mh=2, n_iter=1, n_tune=None,
                     outliers=True):
    """Sample the posterior over the 8 sensor parameters and every laser point.

    Parameters
    ----------
    pixels : array_like, shape (N, 2)
        Laser pixels, px.
    approx_points : array_like, shape (N, 3)
        Approximate 3D laser points in frame C, mm.
    sigma_px : float or None
        Pixel noise, px; ``None`` infers it (log-uniform prior on
        ``NOISE_BOUNDS["sigma_px"]``).
    sigma_scene : float, array_like broadcastable to (N, 3), or None
        Error of the approximate points, mm (``inf`` = axis not informative;
        relative errors as e.g. ``0.05 * abs(approx_points)``); ``None`` infers
        ``kappa`` in ``sigma_scene_i = kappa * rho_i`` (log-uniform prior on
        ``NOISE_BOUNDS["kappa"]``).
    prior : dict, optional
        ``{name: scipy.stats frozen distribution}`` for any of the 8 names;
        the rest keep :func:`~bayescal.priors.default_prior`.
    rng : numpy.random.Generator, int or None
        Randomness of walkers, emcee and point draws: same seed, same chains.
    n_walkers : int, optional
        emcee walkers, at least ``2 * ndim`` for the red-blue moves (default
        ``2 * ndim + 2``: the ``tau_factor`` rule fixes the chain length in
        steps whatever the ensemble size, so few walkers are cheapest).
    min_ess : float, optional
        Target effective sample size of every sampled coordinate, computed
        honestly for an ensemble (:func:`bayescal.diagnostics.ensemble_ess`).
    tau_factor : float, optional
        Convergence rule: post-burn-in chain longer than ``tau_factor * tau``.
    max_steps : int, optional
        Hard limit on chain length.
    n_samples : int, optional
        Number of joint samples (parameters and points) kept, thinned evenly
        from the converged chain.
    init : SensorParams, optional
        Start of the MAP search (default the prior means).
    moves : list, optional
        emcee moves of the production run (default :func:`default_moves`: the
        fitted independence proposal mixed with differential evolution).
    n_tune : int, optional
        Steps per round of the proposal and step-size tuning (3 rounds, discarded;
        default 60, or 150 for a likelihood without a gradient).
    progress : bool, optional
        Show a progress bar.
    on_unconverged : {"warn", "raise"}
        What to do when ``max_steps`` is reached before convergence.
    n_point_mh : int, optional
        Independence Metropolis-Hastings corrections per point draw.
    n_iter : int, optional
        Gauss-Newton iterations of the per-point Laplace step.
    outliers : bool, optional
        Per-point outlier mixture (``docs/robustness.md``): each row is an
        inlier or, with probability ``w`` (Beta(1, 19) prior, sampled), an
        outlier with 100x the noise; ``post.outlier_prob`` (N,) gives each
        row's posterior probability of being one. On clean data it moves the
        posterior by a few hundredths of a sd (``tests/test_sampling.py``).
        ``False``: the pure model. Not available yet with a
        :class:`~bayescal.FloorPlan` (ignored there).

    Returns
    -------
    Posterior

    Examples
    --------
    >>> import bayescal as bc
    >>> ds = bc.simulate_room(range_mm=1000, n_points=60, sigma_px=0.5,
    ...                       approx_error=0.02, approx_model="gaussian", rng=0)
    >>> post = bc.sample_posterior(ds.pixels, ds.approx_points, sigma_px=0.5,
    ...                            sigma_scene=ds.sigma_scene, rng=1, progress=False)
    >>> post.param_samples.shape[1], post.point_samples.shape[1:]
    (8, (60, 3))
    """
    if isinstance(approx_points, FloorPlan):          # walls in place of points
        # the floor-plan likelihood has no outlier mixture yet (docs/floorplan.md)
        kw = {k: v for k, v in locals().items()
              if k not in ("pixels", "approx_points", "outliers")}
        return sample_plan_posterior(pixels, approx_points, **kw)
    if sigma_scene is SCENE_REQUIRED:
        raise TypeError("sample_posterior() missing required keyword argument 'sigma_scene' "
                        "(needed with approximate points)")
    from .simultaneous import calibrate_simultaneous

    if on_unconverged not in ("warn", "raise"):
        raise ValueError(f"on_unconverged must be 'warn' or 'raise', got {on_unconverged!r}")
    rng = resolve_rng(rng)
    prior = prior if isinstance(prior, Prior) else Prior(prior)
    lik = LaserLikelihood(pixels, approx_points, sigma_px=sigma_px, sigma_scene=sigma_scene,
                          outliers=outliers)
    ndim = 7 + len(lik.extra_names)
    if n_walkers is not None and int(n_walkers) < 2 * ndim:
        raise ValueError(f"n_walkers must be at least 2 * ndim = {2 * ndim} for emcee's "
                         f"red-blue moves, got {n_walkers}")
    if int(n_samples) < 1:
        raise ValueError(f"n_samples must be a positive integer, got {n_samples!r}")
    map_res = calibrate_simultaneous(lik.pixels, lik.approx, sigma_px=sigma_px,
                                     sigma_scene=sigma_scene, prior=prior, init=init,
                                     outliers=outliers)
    psi_map, cov_map, q_map = _map_start(lik, map_res)
    run = sample_collapsed(lik, prior, psi_map, cov_map, q_map, rng=rng, n_walkers=n_walkers,
                           min_ess=min_ess, tau_factor=tau_factor, max_steps=max_steps,
                           n_samples=n_samples, moves=moves, progress=progress,
                           n_point_mh=n_point_mh, n_iter=n_iter, n_tune=n_tune)
    post = _assemble(lik, prior, map_res, run, rng, sigma_px=sigma_px, sigma_scene=sigma_scene)
    _check_noise_bounds(post)
    diag = run["diagnostics"]
    if not diag.converged:
        msg = (f"the chain did not converge within max_steps={max_steps}: it has "
               f"{diag.n_steps - diag.burn} steps after burn-in (need more than "
               f"{diag.tau_factor:g} x tau = {diag.tau_factor * np.max(diag.tau):.0f}) and a "
               f"minimum ESS of {np.min(diag.ess):.0f} (need {diag.min_ess:g})")
        if on_unconverged == "raise":
            raise NotConvergedError(msg, tau=diag.tau, posterior=post)
        warnings.warn(msg, NotConvergedWarning, stacklevel=2)
    return post


def _map_start(lik, map_res):
    """psi at the MAP (theta then inferred log noise), its covariance and the MAP points."""
    sol, noise = map_res.extras["map"], map_res.extras["noise"]
    lik.set_reference_noise(sigma_px=noise["sigma_px"], kappa=noise["kappa"])
    psi_map = list(sol.theta)
    if lik.infer_px:
        psi_map.append(np.log(noise["sigma_px"]))
    if lik.infer_scene:
        psi_map.append(np.log(noise["kappa"]))
    if lik.outliers:
        w = float(np.clip(noise["outlier_frac"], 1e-4, 0.5))
        psi_map.append(np.log(w / (1.0 - w)))
    ndim = len(psi_map)
    cov = np.zeros((ndim, ndim))
    cov[:7, :7] = sol.cov_theta
    for k in range(7, ndim):
        cov[k, k] = 1.0 / lik.n                 # ~ squared relative sd of a noise estimate
    if lik.outliers:                            # logit w: ~ Beta(1, 19) prior's spread
        cov[-1, -1] = 1.0
    return np.array(psi_map), cov, sol.q


def _assemble(lik, prior, map_res, run, rng, *, sigma_px, sigma_scene):
    """phi draws and the Posterior object (step 6)."""
    from .posterior import Posterior

    psi, diag = run["psi"], run["diagnostics"]
    phi = prior.sample_phi(psi[:, :7], rng=rng)
    return Posterior(
        param_samples=from_identifiable(psi[:, :7], phi),
        point_samples=lik.points_3d(psi, run["q"]), noise_samples=psi[:, 7:],
        noise_names=lik.extra_names, pixels=lik.pixels, approx_points=lik.approx,
        sigma_px=sigma_px, sigma_scene=None if sigma_scene is None else
        np.broadcast_to(np.asarray(sigma_scene, float), lik.approx.shape).copy(),
        prior=prior, map_result=map_res, tau=diag.tau, ess=diag.ess,
        n_steps=diag.n_steps, burn=diag.burn, n_walkers=diag.n_walkers,
        converged=diag.converged, acceptance=diag.acceptance,
        imh_acceptance=run["imh_acceptance"], diagnostics=diag,
        outlier_prob=_outlier_prob(lik, psi, run["q"]))


def _outlier_prob(lik, psi, q, batch=256):
    """Posterior probability (N,) that each row is an outlier: the mean over draws of its
    conditional probability given the globals (None without the mixture)."""
    if not getattr(lik, "outliers", False):
        return None
    total = np.zeros(lik.n)
    for lo in range(0, len(psi), batch):
        p = lik.outlier_prob(psi[lo:lo + batch], q[lo:lo + batch])
        total += np.nan_to_num(p, nan=1.0).sum(axis=0)     # no inlier fit: an outlier
    return total / len(psi)


def _check_noise_bounds(post):
    for k, name in enumerate(post.noise_names):
        if name not in NOISE_BOUNDS:
            continue
        lo = NOISE_BOUNDS[name][0]
        if np.quantile(np.exp(post.noise_samples[:, k]), 0.05) < 2 * lo:
            warnings.warn(f"the posterior of the inferred {name} reaches its prior's lower "
                          f"bound {lo:g}: the data cannot separate the noise levels (too few "
                          f"points?); give {name if name == 'sigma_px' else 'sigma_scene'} "
                          f"explicitly", NoiseAtBoundWarning, stacklevel=3)


def sample_joint(pixels, approx_points, *, sigma_px, sigma_scene, prior=None, rng=None,
                 n_walkers=None, n_steps=20000, init_from=None, progress=False):
    """Brute-force emcee over the full joint ``(theta, q_1..q_N)`` (validation only).

    This is the naive sampler the collapsed one replaces: ``7 + 2N`` dimensions,
    slow to mix (``docs/bayes.md`` section 3). It exists to check the collapsed sampler on
    small problems and as the benchmark baseline. Noise levels must be given.

    Returns
    -------
    dict
        ``chain`` (steps, walkers, 7 + 2N); ``theta`` (S, 7) and ``q`` (S, N, 2),
        the second half of the chain flattened; ``tau``; ``acceptance``.
    """
    from .simultaneous import calibrate_simultaneous

    rng = resolve_rng(rng)
    prior = prior if isinstance(prior, Prior) else Prior(prior)
    lik = LaserLikelihood(pixels, approx_points, sigma_px=sigma_px, sigma_scene=sigma_scene)
    if lik.n_noise:
        raise ValueError("sample_joint needs sigma_px and sigma_scene given")
    n = lik.n
    ndim = 7 + 2 * n
    n_walkers = 2 * ndim + 2 if n_walkers is None else int(n_walkers)
    res = calibrate_simultaneous(lik.pixels, lik.approx, sigma_px=sigma_px,
                                 sigma_scene=sigma_scene, prior=prior)
    sol = res.extras["map"]
    center = np.concatenate([sol.theta, sol.q.ravel()])
    # joint Laplace covariance would need the full matrix; a block start is enough
    sd = np.concatenate([np.sqrt(np.diag(sol.cov_theta)),
                         np.sqrt(np.einsum("nii->ni", sol.Cinv)).ravel()])

    def logp(x):
        x = np.atleast_2d(x)
        theta, q = x[:, :7], x[:, 7:].reshape(len(x), n, 2)
        lp = prior.logpdf_theta(theta)
        ok = np.isfinite(lp)
        out = np.full(len(x), -np.inf)
        if ok.any():
            out[ok] = lp[ok] + lik.log_joint(theta[ok], q[ok])
        return np.where(np.isfinite(out), out, -np.inf)

    p0 = center + 0.5 * sd * rng.standard_normal((n_walkers, ndim))
    sampler = seeded_sampler(n_walkers, ndim, logp, rng, None)
    sampler.run_mcmc(p0, int(n_steps), progress=progress)
    chain = sampler.get_chain()
    kept = chain[len(chain) // 2:].reshape(-1, ndim)
    return {"chain": chain, "theta": kept[:, :7], "q": kept[:, 7:].reshape(-1, n, 2),
            "tau": integrated_time(chain[len(chain) // 2:]),
            "acceptance": float(np.mean(sampler.acceptance_fraction))}
