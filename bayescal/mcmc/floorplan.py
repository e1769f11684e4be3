"""Posterior sampling on a rough floor plan (the collapsed sampler with the plan likelihood).

:func:`sample_plan_posterior` is what :func:`bayescal.sample_posterior` calls when
its second argument is a :class:`~bayescal.FloorPlan`:

1. **MAP start**: :func:`bayescal.fit.plan_start.plan_map_start` gives
   ``psi_map = (theta[, pose], d_0, a_0, ..., d_{W-1}, a_{W-1}[, log sigma_px])``, the
   Laplace covariance of *all* these globals (sensor and walls jointly, from the
   inverse Schur complement of the least squares) and the point azimuths;
2. **collapsed sampling**: :func:`bayescal.mcmc.sampling.sample_collapsed` with the
   :class:`~bayescal.likelihood.floorplan.PlanLikelihood` (each point's azimuth integrated
   out by two truncated Laplace pieces, ``docs/floorplan.md`` section 2);
3. **assembly**: a :class:`~bayescal.results.posterior.Posterior` with ``wall_samples``
   (S, W, 2) and the plan.

:func:`benchmark_plan_posterior` times the whole call at the paper's N = 580.
"""

from __future__ import annotations

import time
import warnings

import numpy as np

from .._validation import resolve_rng
from ..errors import InvalidTypeError, InvalidValueError
from ..fit.plan_start import plan_map_start
from ..likelihood.outliers import OUTLIER_PRIOR, OUTLIER_SCALE
from ..likelihood.priors import as_prior
from ..results.posterior import Posterior
from ..scene.floorplan import FloorPlan
from ..sensor.parameters import from_identifiable
from .collapsed import check_walkers, posterior_outlier_prob, report_unconverged, sample_collapsed
from .ensemble import prime_allocator
from .steps import BUDGET_FACTOR, BURN_FLOOR

__all__ = ["sample_plan_posterior", "benchmark_plan_posterior", "SCENE_REQUIRED"]

#: default of ``sigma_scene`` in :func:`bayescal.sample_posterior`: required with
#: approximate points, absent with a plan
SCENE_REQUIRED = object()


def sample_plan_posterior(pixels, plan, *, sigma_px, prior=None, rng=None, n_walkers=None,
                          min_ess=1000, tau_factor=50, max_steps=20000, n_samples=2000,
                          init=None, moves=None, progress=True, on_unconverged="warn",
                          n_point_mh=2, n_iter=1, n_tune=None, sigma_scene=SCENE_REQUIRED,
                          outliers=True, outlier_scale=OUTLIER_SCALE,
                          outlier_prior=OUTLIER_PRIOR, pixel_cov=None, model="aligned",
                          camera=None, budget=BUDGET_FACTOR):
    """Sample the posterior of the sensor, the walls of a rough plan and every laser point.

    Parameters
    ----------
    pixels : array_like, shape (N, 2)
        Laser pixels, px.
    plan : FloorPlan
        The room's walls as measured roughly (priors of ``d_k``, ``a_k``).
    sigma_px : float or None
        Pixel noise, px; ``None`` infers it (log-uniform prior on
        ``NOISE_BOUNDS["sigma_px"]``).
    prior, rng, n_walkers, min_ess, tau_factor, max_steps, n_samples, init, moves,
    progress, on_unconverged, n_point_mh, n_iter, camera :
        As in :func:`bayescal.sample_posterior`.
    n_tune : int, optional
        Steps per round of the proposal tuning (default: the likelihood's
        ``tune_steps`` where it has one, 80 with ``model="misaligned"``, else the
        sampler's).
    sigma_scene : not accepted
        The plan carries its own sds; giving it is a ``TypeError``.
    outliers, outlier_scale, outlier_prior :
        The per-point outlier mixture (default on; ``docs/robustness.md``, "Floor
        plans"): ``logit w`` is sampled (``noise_names`` ends with
        ``"outlier_frac"``) and ``post.outlier_prob`` (N,) is each point's
        posterior outlier probability.
    pixel_cov : array_like, shape (N, 2, 2), optional
        Per-point pixel covariances, px^2: the noise of pixel i is ``sigma_px^2
        pixel_cov_i`` (``sigma_px`` a scale on them, ``None``: inferred), as in
        :func:`bayescal.calibrate_simultaneous`.
    model : {"aligned", "misaligned"}
        The laser cone; ``"misaligned"`` samples its tilt and offset too (the pose's four
        numbers after theta in psi; ``post.laser_samples`` (S, 4)).
    budget : float or None
        Time budget, as in :func:`bayescal.sample_posterior` (default 3: the chain stops,
        not converged and saying why, after 3 times the steps its stopping rule projected).

    Returns
    -------
    Posterior
        ``param_samples`` (S, 8), ``point_samples`` (S, N, 3), ``wall_samples``
        (S, W, 2) of ``(d_k mm, a_k rad)``, ``noise_samples`` (S, 1) of
        ``log sigma_px`` when inferred (then ``logit w`` with outliers; the pose's four
        first with ``model="misaligned"``, ``laser_samples`` (S, 4));
        ``outlier_prob`` (N,) or None; ``approx_points`` is NaN (the plan
        replaces them) and ``plan`` the given plan.
    """
    if not isinstance(plan, FloorPlan):
        raise InvalidTypeError(f"plan must be a FloorPlan, got {type(plan).__name__}")
    if sigma_scene is not SCENE_REQUIRED:
        raise InvalidTypeError("with a FloorPlan, sigma_scene does not apply (the plan carries its "
                               "own sds); leave it out")
    if on_unconverged not in ("warn", "raise"):
        raise InvalidValueError(f"on_unconverged must be 'warn' or 'raise', got {on_unconverged!r}")
    if int(n_samples) < 1:
        raise InvalidValueError(f"n_samples must be a positive integer, got {n_samples!r}")
    ndim = 7 + 4 * (model == "misaligned") + 2 * plan.n_walls + (sigma_px is None) \
        + bool(outliers)
    check_walkers(n_walkers, ndim)
    rng = resolve_rng(rng)
    prime_allocator()                  # the first call of a process as fast as the next
    prior = as_prior(prior, camera)
    psi_map, cov_map, q_map, map_res = plan_map_start(pixels, plan, sigma_px=sigma_px,
                                                      prior=prior, init=init,
                                                      outliers=outliers,
                                                      outlier_scale=outlier_scale,
                                                      outlier_prior=outlier_prior,
                                                      pixel_cov=pixel_cov, model=model)
    lik = map_res.extras.pop("likelihood")
    if n_tune is None:                  # the likelihood's own tuning length, if it has one
        n_tune = getattr(lik, "tune_steps", None)
    run = sample_collapsed(lik, prior, psi_map, cov_map, q_map, rng=rng, n_walkers=n_walkers,
                           min_ess=min_ess, tau_factor=tau_factor, max_steps=max_steps,
                           n_samples=n_samples, moves=moves, progress=progress,
                           n_point_mh=n_point_mh, n_iter=n_iter,
                           n_tune=n_tune, budget=budget,
                           burn_floor=getattr(lik, "burn_floor", BURN_FLOOR))
    post = _assemble(lik, prior, map_res, run, rng, sigma_px=sigma_px)
    post.pixel_cov = lik.pixel_cov              # per-point covariances for its model check
    report_unconverged(run["diagnostics"], post, what="the floor-plan chain",
                       max_steps=max_steps, on_unconverged=on_unconverged, stacklevel=3)
    return post


def _assemble(lik, prior, map_res, run, rng, *, sigma_px):
    """phi draws, walls and points; the Posterior object."""
    psi, diag = run["psi"], run["diagnostics"]
    geo, walls, _ = lik.split(psi)
    phi = prior.sample_phi(geo[:, :7], rng=rng)
    nt, n_w = lik.n_geo, 2 * lik.n_walls
    # the pose (misaligned model) and the noise levels: the extras other than the walls
    extra = np.r_[7:nt, nt + n_w:psi.shape[1]]
    return Posterior(
        param_samples=from_identifiable(geo[:, :7], phi),
        point_samples=lik.points_3d(psi, run["q"]), noise_samples=psi[:, extra],
        noise_names=tuple(lik.extra_names[k - 7] for k in extra),
        pixels=lik.pixels, approx_points=np.full((lik.n, 3), np.nan), sigma_px=sigma_px,
        sigma_scene=None, prior=prior, map_result=map_res, tau=diag.tau, ess=diag.ess,
        n_steps=diag.n_steps, burn=diag.burn, n_walkers=diag.n_walkers,
        converged=diag.converged, acceptance=diag.acceptance,
        imh_acceptance=run["imh_acceptance"], diagnostics=diag, wall_samples=walls,
        plan=lik.plan, outlier_prob=posterior_outlier_prob(lik, psi, run["q"]))


def benchmark_plan_posterior(*, range_mm=1000.0, n_points=580, sigma_px=0.5,
                             approx_error=0.05, n_repeats=3, min_ess=1000, rng=0,
                             outliers=True):
    """Time :func:`sample_plan_posterior` to ``min_ess`` effective samples.

    Simulates the room (``approx_model="wall"``, its ``ds.floor_plan``) once per
    repeat with seeds drawn from ``rng`` and times the whole call (MAP, tuning,
    production run, point draws). The floor-plan row of ``docs/performance.md``
    (``make bench``) times the same call differently: one room (data seed 3),
    sampler seeds 0, 1, 2, like the other N = 580 rows, so that it is comparable
    with them.

    Parameters
    ----------
    range_mm, n_points, sigma_px, approx_error : float or int
        Room, as :func:`bayescal.simulate_room`.
    n_repeats : int
    min_ess : float
    rng : numpy.random.Generator, int or None
    outliers : bool
        The outlier mixture (default on, as in :func:`sample_plan_posterior`).

    Returns
    -------
    dict
        ``seconds`` (n_repeats,), ``median_s``, ``min_ess`` reached (n_repeats,),
        ``max_tau`` (n_repeats,), ``n_steps`` (n_repeats,), ``converged`` (n_repeats,).
    """
    from ..scene.simulate import simulate_room

    rng = resolve_rng(rng)
    out = {"seconds": [], "min_ess": [], "max_tau": [], "n_steps": [], "converged": []}
    for _ in range(int(n_repeats)):
        seed = int(rng.integers(2**31))
        ds = simulate_room(range_mm=range_mm, n_points=n_points, sigma_px=sigma_px,
                           approx_error=approx_error, approx_model="wall", rng=seed)
        t0 = time.perf_counter()
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            post = sample_plan_posterior(ds.pixels, ds.floor_plan, sigma_px=sigma_px,
                                         rng=seed + 1, min_ess=min_ess, progress=False,
                                         outliers=outliers)
        out["seconds"].append(time.perf_counter() - t0)
        out["min_ess"].append(float(np.min(post.ess)))
        out["max_tau"].append(float(np.max(post.tau)))
        out["n_steps"].append(post.n_steps)
        out["converged"].append(post.converged)
    out = {k: np.asarray(v) for k, v in out.items()}
    out["median_s"] = float(np.median(out["seconds"]))
    return out
