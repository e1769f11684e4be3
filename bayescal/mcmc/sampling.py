"""Posterior sampling: a collapsed emcee sampler over the identifiable parameters.

The joint posterior over the 8 parameters and the N laser points has ``7 + k N``
free dimensions (``phi`` is not seen by the data); emcee does not mix there
(``docs/bayes.md`` section 3). The points are independent given the globals
``psi = (theta, extras)``, so :func:`sample_collapsed` samples ``psi`` with every
point integrated out by a Laplace step, then draws the points. Its steps
(:mod:`bayescal.mcmc.steps`):

1. **MAP start** (:func:`sample_posterior` only): :func:`bayescal.calibrate_simultaneous`
   gives ``psi_map``, its Laplace covariance and the points ``q_map``;
2. **proposal fit**: adaptive importance sampling fits a Student-t to the collapsed
   posterior (sampling coordinates, :func:`~bayescal.mcmc.steps.to_sampling`);
3. **walker placement**: the walkers start from the fit's weighted draws;
4. **production run**: emcee with the fitted independence proposal (80 %) and
   differential evolution (20 %), in chunks until the kept chain is longer than
   ``tau_factor`` autocorrelation times and the honest ESS (ensemble-mean based,
   :func:`bayescal.stats.chains.ensemble_ess`) reaches ``min_ess``;
5. **draws**: ``phi`` from its exact conditional, each point from its Laplace
   Gaussian corrected by independence Metropolis-Hastings
   (:func:`bayescal.likelihood.points.draw_points`);
6. **assembly**: a :class:`~bayescal.results.posterior.Posterior` carrying a
   :class:`~bayescal.stats.chains.ChainDiagnostics`.

Any likelihood providing ``n``, ``extra_names``, ``log_prior_extra``, ``laplace``,
``point_log_density`` and ``points_3d`` can be sampled by :func:`sample_collapsed`.
"""

from __future__ import annotations

import warnings

import numpy as np

from .._validation import check_positive, resolve_rng
from ..errors import InvalidTypeError, InvalidValueError
from ..fit.em import improbable_rows
from ..fit.simultaneous import check_model, point_likelihood
from ..fit.start import data_prior
from ..likelihood.points import NOISE_BOUNDS, LaserLikelihood
from ..likelihood.priors import Prior
from ..results.posterior import Posterior
from ..scene.floorplan import FloorPlan
from ..sensor.parameters import (
    IDENTIFIABLE_NAMES,
    PARAM_NAMES,
    from_identifiable,
    offset_variance,
)
from ..stats.chains import integrated_time
from .collapsed import (
    NoiseAtBoundWarning,
    NotConvergedError,
    NotConvergedWarning,
    check_run_options,
    check_walkers,
    default_moves,
    report_unconverged,
    sample_collapsed,
)
from .collapsed import posterior_outlier_prob as _outlier_prob
from .ensemble import prime_allocator
from .floorplan import SCENE_REQUIRED, sample_plan_posterior
from .steps import BUDGET_FACTOR, from_sampling, ring_scale, seeded_sampler, to_sampling

#: steps per tuning round for the aligned cone with approximate points: its posterior is
#: near-Gaussian in the sampling coordinates, and three rounds of 40 steps gave 13-18 %
#: fewer evaluations per effective sample than rounds of 60 on three rooms at N = 540-600
#: (3 sampler seeds each; rounds of 25 steps more: the proposal fitted from fewer draws
#: accepts less), docs/performance.md
ALIGNED_TUNE = 40
#: share of the independence move in its production run (the rest differential evolution):
#: 0.9 in place of 0.8 gave 6-22 % fewer evaluations per effective sample on the same rooms
ALIGNED_IMH_WEIGHT = 0.9
#: its Metropolis-Hastings corrections per point draw: one (others: two). The draws'
#: Laplace proposal is accepted 0.97-0.999 of the time, so the second correction changed
#: next to nothing and cost a third of the draws (docs/performance.md)
ALIGNED_POINT_MH = 1
#: its smallest burn-in, a fraction of the chain (other models: a quarter,
#: ``bayescal.mcmc.steps.BURN_FLOOR``): none, the burn-in is 5 tau. The chain starts from the
#: last tuning round's walkers, which ran on the same target; on the 1000 mm benchmark room,
#: the 1500 mm z-known room with sigma_px inferred and the 1000 mm z-known room (sampler
#: seed 7, min_ess=4000) the steps between 5 tau and a quarter of the chain had the means of
#: the rest within |z| <= 2.0 over the 25 coordinates; docs/performance.md
ALIGNED_BURN_FLOOR = 0.0

__all__ = ["sample_posterior", "sample_collapsed", "sample_joint", "NotConvergedWarning",
           "NotConvergedError", "NoiseAtBoundWarning", "default_moves", "NOISE_BOUNDS",
           "ring_scale", "to_sampling", "from_sampling"]

def sample_posterior(pixels, approx_points, *, sigma_px, sigma_scene=SCENE_REQUIRED, prior=None,
                     rng=None, n_walkers=None, min_ess=1000, tau_factor=50, max_steps=20000,
                     n_samples=2000, init=None, moves=None, progress=True,
                     on_unconverged="warn", n_point_mh=None, n_iter=1, n_tune=None,
                     outliers=True, model="aligned", pixel_cov=None, camera=None,
                     budget=BUDGET_FACTOR, offset_sd=0.0):
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
        ``{name: scipy.stats frozen distribution}`` for any of the 8 names (and,
        with ``model="misaligned"``, the pose's four); the rest keep
        :func:`~bayescal.likelihood.priors.default_prior`.
    rng : numpy.random.Generator, int or None
        Randomness of walkers, emcee and point draws: same seed, same chains.
    n_walkers : int, optional
        emcee walkers, at least ``ndim + 2`` (default
        :func:`~bayescal.mcmc.steps.default_walkers`: ``2 ndim + 2`` up to 24;
        the ``tau_factor`` rule fixes the chain length in steps whatever the
        ensemble size, so few walkers are cheapest; ``2 ndim + 2`` with your own
        ``moves``, which may be red-blue moves).
    min_ess : float, optional
        Target effective sample size of every sampled coordinate, computed
        honestly for an ensemble (:func:`bayescal.stats.chains.ensemble_ess`).
    tau_factor : float, optional
        Convergence rule: post-burn-in chain longer than ``tau_factor * tau``.
    max_steps : int, optional
        Hard limit on chain length.
    budget : float or None, optional
        Time budget: the chain stops, not converged (``on_unconverged`` says how it is
        reported, the message says why), after ``budget`` times the steps its stopping
        rule projected after 200 steps (default 3; a clean chain meets the rule near
        that projection, one whose autocorrelation time keeps growing does not: rows
        switching between inlier and outlier, several modes). A run the budget stops
        that went without HMC is first run again from its last state with HMC added
        (``post.diagnostics.extra["rerun_with_hmc"]``, ``docs/bayes.md`` section 3).
        ``None``: run to ``max_steps``. The same with a :class:`~bayescal.FloorPlan`.
    n_samples : int, optional
        Number of joint samples (parameters and points) kept, thinned evenly
        along each walker of the converged chain. The ESS reported is the chain's:
        fewer samples than its kept states carry somewhat less (at 2000 of ~3600,
        0.006-0.011 sd more error per mean, ``docs/validation.md`` rung 3b); ask for
        at least ``n_walkers * (n_steps - burn)`` to keep them all.
    init : SensorParams, optional
        Start of the MAP search (default the prior means).
    moves : list, optional
        emcee moves of the production run (default :func:`default_moves`: the
        fitted independence proposal mixed with differential evolution).
    n_tune : int, optional
        Steps per round of the proposal and step-size tuning (3 rounds, discarded;
        default 40 for the aligned cone with approximate points (:data:`ALIGNED_TUNE`),
        else 60, or 150 for a likelihood without a gradient and for a misaligned floor
        plan, whose mass matrix is fitted to 24 coordinates).
    progress : bool, optional
        Show a progress bar.
    on_unconverged : {"warn", "raise"}
        What to do when ``max_steps`` is reached before convergence.
    n_point_mh : int, optional
        Independence Metropolis-Hastings corrections per point draw (default
        :data:`ALIGNED_POINT_MH`, 1, for the aligned cone with approximate points, whose
        Laplace proposal the corrections accept 0.97-0.999 of the time; 2 otherwise).
    n_iter : int, optional
        Gauss-Newton iterations of the per-point Laplace step (the sampler's target;
        the point draws' proposal takes ``n_iter`` with the aligned cone and approximate
        points, ``n_iter + 1`` otherwise).
    outliers : bool, optional
        Per-point outlier mixture (``docs/robustness.md``): each row is an
        inlier or, with probability ``w`` (Beta(1, 19) prior, sampled), an
        outlier with 100x the noise; ``post.outlier_prob`` (N,) gives each
        row's posterior probability of being one. On clean data it moves the
        posterior by a few hundredths of a sd (``tests/mcmc/test_sampling.py``).
        ``False``: the pure model. The same with a :class:`~bayescal.FloorPlan`.
    model : {"aligned", "misaligned"}, optional
        The laser cone (see :func:`~bayescal.calibrate_simultaneous`): with
        ``"misaligned"`` its tilt and offset are sampled too (``post.laser_samples``
        (S, 4)), as four extra globals of the collapsed sampler (``docs/bayes.md``, "The
        misaligned model"). With approximate points or a FloorPlan.
    pixel_cov : array_like, shape (N, 2, 2), optional
        Per-point pixel covariances, px^2 (``bc.extract_laser(...).covariance``): the
        noise of pixel i is ``sigma_px^2 pixel_cov_i``, ``sigma_px`` a scale on them
        (1.0: as they are; ``None`` infers it with a FloorPlan, and is refused with
        approximate points), as in :func:`bayescal.calibrate_simultaneous`.
    camera : object, optional
        A camera calibrated beforehand (``bc.calibrate_camera(views)``, a camera
        posterior, or ``(mean, cov)``): the correlated normal prior of ``xi, gamma_u,
        gamma_v, u0, v0``, as in :func:`bayescal.calibrate_simultaneous`; the log
        prior of every sampled state carries it.
    offset_sd : float, optional
        Standard deviation (px, each axis) of a translation shared by every pixel
        (``bc.extract_laser(...).offset_sd``): a shift of ``(u0, v0)``, marginalised by
        adding independent draws of it to their samples (and its variance to the
        Laplace covariances), as :func:`bayescal.calibrate_simultaneous` does (exact
        with a wide prior on u0 and v0, conservative with a camera prior).

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
    if n_point_mh is None:
        n_point_mh = ALIGNED_POINT_MH if model == "aligned" \
            and not isinstance(approx_points, FloorPlan) else 2
    check_run_options(n_walkers=n_walkers, min_ess=min_ess, tau_factor=tau_factor,
                      max_steps=max_steps, n_samples=n_samples, n_point_mh=n_point_mh,
                      n_iter=n_iter, n_tune=n_tune, on_unconverged=on_unconverged)
    model = check_model(model)
    offset_sd = check_positive(offset_sd, "offset_sd", allow_zero=True)
    # no prior and no camera: the default centred on the design the data imply (the paper's
    # sensor unless they disagree: bayescal.fit.start.data_prior, as the least squares does)
    prior = data_prior(prior, camera, pixels, approx_points)[0]
    rng = resolve_rng(rng)
    prime_allocator()                  # the first call of a process as fast as the next
    if budget is not None and not (isinstance(budget, (int, float, np.number))
                                   and not isinstance(budget, bool) and budget >= 1):
        raise InvalidValueError(f"budget must be None or a number >= 1 (times the projected "
                                f"steps), got {budget!r}")
    if isinstance(approx_points, FloorPlan):          # walls in place of points
        kw = {k: v for k, v in locals().items()
              if k not in ("pixels", "approx_points", "camera", "offset_sd")}
        return _with_offset(sample_plan_posterior(pixels, approx_points, **kw), offset_sd, rng)
    if sigma_scene is SCENE_REQUIRED:
        raise InvalidTypeError("sample_posterior() missing required keyword argument 'sigma_scene' "
                               "(needed with approximate points)")
    from ..fit.simultaneous import calibrate_simultaneous

    lik = point_likelihood(model, pixels, approx_points, prior, sigma_px=sigma_px,
                           sigma_scene=sigma_scene, outliers=outliers, pixel_cov=pixel_cov)
    ndim = 7 + len(lik.extra_names)
    check_walkers(n_walkers, ndim)
    map_res = calibrate_simultaneous(lik.pixels, lik.approx, sigma_px=sigma_px,
                                     sigma_scene=sigma_scene, prior=prior, init=init,
                                     outliers=outliers, model=model, pixel_cov=pixel_cov)
    psi_map, cov_map, q_map = _map_start(lik, map_res)
    # the sampler's ring radius is taken at the points' median range (docs/bayes.md sec. 3)
    lik.reference_range = float(np.median(np.hypot(map_res.points[:, 0], map_res.points[:, 1])))
    aligned = model == "aligned"
    if n_tune is None and aligned and moves is None:
        n_tune = ALIGNED_TUNE
    # aligned: the draws' Laplace proposal from n_iter Gauss-Newton steps (the MH
    # corrections accept 0.97-0.999 of the draws either way, docs/performance.md)
    run = sample_collapsed(lik, prior, psi_map, cov_map, q_map, rng=rng, n_walkers=n_walkers,
                           min_ess=min_ess, tau_factor=tau_factor, max_steps=max_steps,
                           n_samples=n_samples, moves=moves, progress=progress,
                           n_point_mh=n_point_mh, n_iter=n_iter, n_tune=n_tune,
                           budget=budget, draw_iter=n_iter if aligned else None,
                           **(_aligned_run() if aligned else {}))
    post = _assemble(lik, prior, map_res, run, rng, sigma_px=sigma_px, sigma_scene=sigma_scene)
    cut = map_res.extras.get("cut_rows", np.zeros(0, int))
    if post.outlier_prob is not None and len(cut):   # the start's cut, if the posterior agrees
        bad = improbable_rows(lik, run["psi"].mean(axis=0), run["q"].mean(axis=0))[cut]
        post.outlier_prob[cut[bad]] = 1.0
    post.pixel_cov = None if pixel_cov is None else np.asarray(pixel_cov, float)   # its check
    _check_noise_bounds(post)
    report_unconverged(run["diagnostics"], post, what="the chain", max_steps=max_steps,
                       on_unconverged=on_unconverged, stacklevel=2)
    return _with_offset(post, offset_sd, rng)


def _aligned_run():
    """sample_collapsed's settings for the aligned cone with approximate points."""
    return {"imh_weight": ALIGNED_IMH_WEIGHT, "burn_floor": ALIGNED_BURN_FLOOR,
            "draw_stepped": True}


def _with_offset(post, offset_sd, rng):
    """``post`` with a translation shared by every pixel marginalised: independent draws of
    it (sd ``offset_sd`` px) added to the u0 and v0 samples, its variance to the Laplace
    covariances (a common pixel translation is a shift of the principal point)."""
    if offset_sd > 0:
        # new arrays, not in place: laplace_cov7 may be the MAP result's own covariance
        ip = PARAM_NAMES.index("u0")
        shift = np.zeros_like(post.param_samples)
        shift[:, ip:ip + 2] = rng.normal(0.0, offset_sd, (len(post.param_samples), 2))
        post.param_samples = post.param_samples + shift
        post.laplace_cov8 = post.laplace_cov8 + offset_variance(
            PARAM_NAMES, offset_sd, size=len(post.laplace_cov8))
        post.laplace_cov7 = post.laplace_cov7 + offset_variance(
            IDENTIFIABLE_NAMES, offset_sd, size=len(post.laplace_cov7))
    post.offset_sd = offset_sd
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
    ndim, nt = len(psi_map), len(sol.theta)          # nt: theta (7) and the pose (misaligned)
    cov = np.zeros((ndim, ndim))
    cov[:nt, :nt] = sol.cov_theta
    for k in range(nt, ndim):
        cov[k, k] = 1.0 / lik.n                 # ~ squared relative sd of a noise estimate
    if lik.outliers:                            # logit w: ~ Beta(1, 19) prior's spread
        cov[-1, -1] = 1.0
    return np.array(psi_map), cov, sol.q


def _assemble(lik, prior, map_res, run, rng, *, sigma_px, sigma_scene):
    """phi draws and the Posterior object (step 6)."""
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
    from ..fit.simultaneous import calibrate_simultaneous

    rng = resolve_rng(rng)
    prior = prior if isinstance(prior, Prior) else Prior(prior)
    lik = LaserLikelihood(pixels, approx_points, sigma_px=sigma_px, sigma_scene=sigma_scene)
    if lik.n_noise:
        raise InvalidValueError("sample_joint needs sigma_px and sigma_scene given")
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
