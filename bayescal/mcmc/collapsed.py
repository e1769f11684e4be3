"""The collapsed sampler's core: emcee over the globals with every point integrated out.

:func:`sample_collapsed` samples ``psi = (theta, extras)`` of any likelihood that
provides ``n``, ``extra_names``, ``log_prior_extra``, ``laplace``,
``point_log_density`` and ``points_3d`` (optionally ``grad_log_marginal``, which
allows the HMC move, used where the first tuning round finds the posterior far from
Gaussian: :data:`~bayescal.mcmc.steps.IMH_FITS`), from a MAP start and its Laplace
covariance; the steps are in :mod:`bayescal.mcmc.steps`, the walkthrough in ``docs/bayes.md``
section 3. Callers: :func:`bayescal.mcmc.sampling.sample_posterior` (approximate
points) and :func:`bayescal.mcmc.floorplan.sample_plan_posterior` (floor plan).
"""

from __future__ import annotations

import time
import warnings

import numpy as np

from .._validation import resolve_rng
from ..errors import (
    FitError,
    InvalidValueError,
    NoiseAtBoundWarning,
    NotConvergedError,
    NotConvergedWarning,
)
from ..likelihood.point_algebra import outlier_probs
from ..likelihood.point_draws import DRAW_ELEMENTS
from ..likelihood.points import draw_points
from ..stats.chains import ChainDiagnostics
from .ensemble import spd_covariance, spread_walkers
from .moves import HMCMove, IndependenceMove
from .steps import (
    BURN_FLOOR,
    HMC_LEAPFROG,
    IMH_FITS,
    CollapsedTarget,
    Coordinates,
    de_move,
    default_walkers,
    imh_df,
    min_walkers,
    run_until_converged,
    seeded_sampler,
    tune_proposal,
)

__all__ = ["sample_collapsed", "check_run_options", "check_walkers", "report_unconverged",
           "default_moves", "NotConvergedWarning", "NotConvergedError", "NoiseAtBoundWarning",
           "posterior_outlier_prob"]

#: shares of the HMC and independence moves in the production run (the rest: DEMove)
HMC_WEIGHT = 0.3
IMH_WEIGHT = 0.6
#: HMC trajectory length in whitened units (sets the leapfrog count from the tuned step)
HMC_PATH = 1.5
#: steps adapting the HMC step before a production run is re-run with HMC (discarded)
HMC_RETUNE = 40
#: Gauss-Newton iterations of the fused outlier probabilities from each point draw: those
#: of ``LaserLikelihood.outlier_prob``
OUTLIER_ITER = 4



def default_moves(mean=None, cov=None, *, value_and_grad=None, step_size=0.3,
                  n_leapfrog=None, weights=None, imh_weight=0.8):
    """emcee moves used by default.

    With a proposal ``mean`` and ``cov`` and a gradient ``value_and_grad`` (the
    collapsed target's): :class:`~bayescal.mcmc.moves.HMCMove` (``HMC_WEIGHT``, mass
    matrix ``cov^-1``, leapfrog step ``step_size`` in whitened units),
    :class:`~bayescal.mcmc.moves.IndependenceMove` (``IMH_WEIGHT``, cheap, jumps
    between distant parts where the proposal fits) and :class:`emcee.moves.DEMove`
    (the rest); ``weights`` (HMC, independence) replaces the two shares (a likelihood's
    ``move_weights``). Without a gradient: the independence proposal (``imh_weight``,
    default 80 %) and DEMove (the rest). Without a proposal: DEMove (80 %) and StretchMove (20 %).
    ``DESnookerMove`` is deliberately absent: in emcee 3.1.6 it samples the wrong
    distribution (``docs/bayes.md`` section 3). Each move here is tested on N(0, I).
    """
    import emcee

    if mean is None:
        return [(emcee.moves.DEMove(), 0.8), (emcee.moves.StretchMove(), 0.2)]
    if value_and_grad is None:
        return [(IndependenceMove(mean, cov, scale=1.1, df=imh_df(len(mean))), imh_weight),
                (de_move(), 1.0 - imh_weight)]
    n_leapfrog = HMC_LEAPFROG if n_leapfrog is None else int(n_leapfrog)
    w_hmc, w_imh = (HMC_WEIGHT, IMH_WEIGHT) if weights is None else weights
    moves = [(HMCMove(value_and_grad, cov, step_size=step_size, n_steps=n_leapfrog), w_hmc),
             (IndependenceMove(mean, cov, scale=1.1, df=imh_df(len(mean))), w_imh),
             (de_move(), 1.0 - w_hmc - w_imh)]
    return [(m, w) for m, w in moves if w > 1e-12]


def _moves_text(moves):
    if moves is None:
        return "default"
    return ", ".join(f"{type(m).__name__} {w:.0%}" for m, w in moves)


def _diagnostics(lik, info, sampler, fit, prod_moves, target, n_tune_calls, *, tau_factor,
                 min_ess):
    """The run's :class:`~bayescal.stats.chains.ChainDiagnostics` (``extra``: the tuning
    rounds' acceptances, evaluation counts, the production run's independence acceptance)."""
    return ChainDiagnostics(
        names=("xi", "gamma_u", "gamma_v", "u0", "v0", "h", "beta") + tuple(lik.extra_names),
        tau=info["tau"], ess=info["ess"], n_steps=info["n_steps"], burn=info["burn"],
        n_walkers=sampler.nwalkers, acceptance=float(np.mean(sampler.acceptance_fraction)),
        converged=info["converged"], tau_factor=float(tau_factor), min_ess=float(min_ess),
        moves=_moves_text(prod_moves),
        extra={"tuning_acceptance": fit["acceptance"], "n_evaluations": int(target.n_calls),
               "n_gradient_evaluations": int(target.n_grad_calls),
               "tuning_imh_acceptance": fit["imh_acceptance"],
               "hmc_step_size": fit["step_size"], "stopped": info.get("stopped"),
               "rerun_with_hmc": info.get("rerun_with_hmc"),
               "n_tuning_evaluations": int(n_tune_calls),
               "imh_acceptance": _imh_acceptance(prod_moves)})


def _imh_acceptance(moves):
    """The production run's independence acceptance (NaN without that move)."""
    acc = [m.acceptance for m, _ in moves if isinstance(m, IndependenceMove)]
    return float(acc[0]) if acc else float("nan")


def _start(target, s_map, cov_s, rng, n_walkers, n_tune, moves, n_rounds):
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
        raise FitError("could not place the walkers: the MAP start is outside the support")
    if n_tune <= 0:
        return {"mean": s_map, "cov": cov_s, "state": p0, "acceptance": [], "step_size": 0.3,
                "imh_acceptance": [], "use_hmc": target.has_gradient}
    # a likelihood may set its own line for leaving HMC out (misaligned plan: imh_fits)
    return tune_proposal(target, p0, s_map, cov_s, rng, n_steps=n_tune, moves=moves,
                         gradient=target.has_gradient, n_rounds=n_rounds,
                         imh_fits=getattr(target.lik, "imh_fits", IMH_FITS))


def _thin(chain, burn, n_samples):
    """``n_samples`` states thinned evenly from the kept chain (steps, walkers, d).

    Walker by walker: each walker's kept states in turn, evenly spaced along it. The
    walkers' independence moves make them nearly independent of one another while a
    walker's successive states are correlated, so dropping states along each walker
    loses less than dropping walkers within a step (the step-major order did that: at
    ~1.8 states per returned sample the returned means scattered over sampler seeds
    like an ESS ~0.5x the chain's, docs/validation.md rung 3b).
    """
    kept = chain[burn:] if len(chain) > burn else chain[-1:]
    flat = np.swapaxes(kept, 0, 1).reshape(-1, chain.shape[-1])
    idx = np.linspace(0, len(flat) - 1, min(int(n_samples), len(flat))).round().astype(int)
    return flat[idx]


def _count(value, name, minimum):
    if isinstance(value, (bool, np.bool_)) or not isinstance(value, (int, np.integer)) \
            or value < minimum:
        raise InvalidValueError(f"{name} must be an integer >= {minimum}, got {value!r}")


def check_run_options(*, n_walkers=None, min_ess=1000, tau_factor=50, max_steps=20000,
                      n_samples=2000, n_point_mh=2, n_iter=1, n_tune=None,
                      on_unconverged="warn"):
    """Validate the sampler's run options before any work; ValueError naming the option.

    Shared by :func:`bayescal.sample_posterior` (points or floor plan) and
    :func:`sample_collapsed`, so a typo fails at once, not after the MAP.
    """
    _count(max_steps, "max_steps", 1)
    _count(n_samples, "n_samples", 1)
    _count(n_point_mh, "n_point_mh", 0)
    _count(n_iter, "n_iter", 1)
    if n_walkers is not None:
        _count(n_walkers, "n_walkers", 2)
    if n_tune is not None:
        _count(n_tune, "n_tune", 0)
    for name, v in (("min_ess", min_ess), ("tau_factor", tau_factor)):
        if isinstance(v, bool) or not isinstance(v, (int, float, np.integer, np.floating)) \
                or not np.isfinite(v) or v <= 0:
            raise InvalidValueError(f"{name} must be a finite positive number, got {v!r}")
    if on_unconverged not in ("warn", "raise"):
        raise InvalidValueError(f"on_unconverged must be 'warn' or 'raise', got {on_unconverged!r}")


def check_walkers(n_walkers, ndim):
    """Raise ``ValueError`` unless ``n_walkers`` is None or at least ``ndim + 2``."""
    if n_walkers is not None and int(n_walkers) < min_walkers(ndim):
        raise InvalidValueError(
            f"n_walkers must be at least ndim + 2 = {min_walkers(ndim)} (the "
            f"walkers must span the {ndim} sampled coordinates), got {n_walkers}")


def report_unconverged(diag, posterior, *, what, max_steps, on_unconverged, stacklevel):
    """Warn (or raise :class:`NotConvergedError`) when the chain missed its rule.

    ``what`` names the chain in the message ("the chain", "the floor-plan chain");
    the numbers come from ``diag``, the :class:`~bayescal.stats.chains.ChainDiagnostics`.
    """
    if diag.converged:
        return
    stopped = diag.extra.get("stopped") if diag.extra else None
    limit = stopped if stopped else f"within max_steps={max_steps}"
    msg = (f"{what} did not converge ({limit}): it has " if stopped else
           f"{what} did not converge {limit}: it has ")
    msg += (
        f"{diag.n_steps - diag.burn} steps after burn-in (need more than "
        f"{diag.tau_factor:g} x tau = {diag.tau_factor * np.max(diag.tau):.0f}) and a "
        f"minimum ESS of {np.min(diag.ess):.0f} (need {diag.min_ess:g})")
    if on_unconverged == "raise":
        raise NotConvergedError(msg, tau=diag.tau, posterior=posterior)
    warnings.warn(msg, NotConvergedWarning, stacklevel=stacklevel + 1)


def _camera_holds_gamma(prior, cov_psi):
    """Whether a camera prior, not the laser data, holds ``gamma``: the Laplace sd of
    ``gamma_u`` at least half the camera's. The ring radii are then no longer what the
    data pin, and the sampler keeps ``gamma`` and ``h`` (``Coordinates(ring=False)``):
    with a camera 1000x tighter than the data the ring coordinates made tau 9-34 (1000
    mm room, 40 points), the identifiable ones 2.5-3."""
    cam = getattr(prior, "camera", None)
    return cam is not None and np.sqrt(cov_psi[1, 1]) >= 0.5 * np.sqrt(cam[1][1, 1])


def sample_collapsed(lik, prior, psi_map, cov_psi_map, q_map, *, rng=None, n_walkers=None,
                     min_ess=1000, tau_factor=50, max_steps=20000, n_samples=2000,
                     moves=None, progress=True, n_point_mh=2, n_iter=1, n_tune=None,
                     budget=None, draw_iter=None, imh_weight=None, tune_rounds=3,
                     burn_floor=BURN_FLOOR, draw_stepped=False):
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
    budget : float, optional
        Stop, not converged, after this many times the steps the stopping rule
        projected after 200 steps (:func:`~bayescal.mcmc.steps.run_until_converged`);
        None: run to ``max_steps``.
    draw_iter : int, optional
        Gauss-Newton iterations of the point draws' Laplace proposal (default
        ``n_iter + 1``; the Metropolis-Hastings corrections keep the draws exact).
    imh_weight : float, optional
        Share of the independence move in a production run without HMC (default
        :func:`default_moves`'); the rest is DEMove.
    tune_rounds : int, optional
        Tuning rounds (:func:`~bayescal.mcmc.steps.tune_proposal`).
    burn_floor : float, optional
        Smallest burn-in, a fraction of the chain (above it: 5 tau;
        :func:`~bayescal.mcmc.steps.run_until_converged`).
    draw_stepped : bool, optional
        The point draws' proposal precision one Gauss-Newton step before its mode, where
        the fused passes apply (:func:`~bayescal.likelihood.points.draw_points`).

    Returns
    -------
    dict
        ``psi`` (S, d) samples, ``q`` (S, N, k) point draws, ``diagnostics``
        (:class:`~bayescal.stats.chains.ChainDiagnostics`; its ``extra`` holds the
        evaluation counts, ``n_tuning_evaluations`` of them in the tuning rounds, the
        independence acceptance per tuning round and of the production run, and
        ``cpu_seconds``: this process's CPU time in the tuning rounds, the production
        run and the point draws), ``imh_acceptance`` (the point draws').
    """
    check_run_options(n_walkers=n_walkers, min_ess=min_ess, tau_factor=tau_factor,
                      max_steps=max_steps, n_samples=n_samples, n_point_mh=n_point_mh,
                      n_iter=n_iter, n_tune=n_tune)
    rng = resolve_rng(rng)
    ndim = len(psi_map)
    if n_walkers is None:       # a user's own moves may be red-blue: emcee's 2 ndim + 2
        n_walkers = default_walkers(ndim) if moves is None else 2 * ndim + 2
    n_walkers = int(n_walkers)
    # the ring radius at the points' median range (docs/bayes.md section 3)
    names = tuple(lik.extra_names)
    rho_ref = getattr(lik, "reference_range", None)
    pose = getattr(lik, "pose_coordinates", False) and rho_ref is not None
    coords = Coordinates(rho_ref,
                         7 + names.index("outlier_frac") if "outlier_frac" in names else None,
                         pose=pose, ring=not _camera_holds_gamma(prior, cov_psi_map))
    target = CollapsedTarget(lik, prior, q_map, n_iter, coords)
    if n_tune is None:
        # HMC mixes fast: short tuning rounds suffice (tune_proposal pools the last two
        # rounds' draws for the proposal's covariance, docs/bayes.md section 3)
        n_tune = 60 if target.has_gradient and moves is None else 150
    n_tune = int(n_tune)
    J = coords.jacobian(psi_map)
    s_map = coords.to_sampling(psi_map)
    cov_s = spd_covariance(J @ np.asarray(cov_psi_map, float) @ J.T,
                           what="Laplace covariance at the least-squares start")
    t0 = time.process_time()
    fit = _start(target, s_map, cov_s, rng, n_walkers, n_tune, moves, int(tune_rounds))
    p0 = spread_walkers(fit["state"], target, fit["cov"], rng)
    t1, n_tune_calls = time.process_time(), int(target.n_calls)
    # HMC only where the first tuning round's independence proposal fitted badly
    vg = target.value_and_grad if target.has_gradient and fit["use_hmc"] else None
    # a trajectory of ~1.5 whitened units: more leapfrog steps where the step had to shrink
    # (a likelihood whose posterior the independence proposal fits badly asks for more HMC)
    path = getattr(lik, "hmc_path", HMC_PATH)
    n_leap = int(np.clip(round(path / fit["step_size"]), HMC_LEAPFROG, 3 * HMC_LEAPFROG))
    prop_cov = spd_covariance(fit["cov"], cov_s)
    prod_moves = default_moves(fit["mean"], prop_cov, value_and_grad=vg,
                               weights=getattr(lik, "move_weights", None),
                               **({} if imh_weight is None else {"imh_weight": imh_weight}),
                               step_size=fit["step_size"], n_leapfrog=n_leap) \
        if moves is None else moves
    run_kw = {"min_ess": min_ess, "tau_factor": tau_factor, "max_steps": int(max_steps),
              "chunk": 100, "progress": progress, "coords": coords, "budget": budget,
              "burn_floor": burn_floor}
    sampler, prod_moves, info = _production(
        target, p0, prod_moves, rng, run_kw,
        rerun=(fit["mean"], prop_cov, fit["step_size"], lik)
        if vg is None and moves is None and target.has_gradient else None)
    t2 = time.process_time()
    diag = _diagnostics(lik, info, sampler, fit, prod_moves, target, n_tune_calls,
                        tau_factor=tau_factor, min_ess=min_ess)
    psi = coords.from_sampling(_thin(sampler.get_chain(), info["burn"], n_samples))
    # cache-sized batches of (sample, point) pairs (point_draws.DRAW_ELEMENTS)
    q, imh_acc = draw_points(lik, psi, q_map, rng, n_mh=n_point_mh,
                             n_iter=n_iter + 1 if draw_iter is None else int(draw_iter),
                             stepped=draw_stepped)
    # CPU seconds (this process) of the three phases: where a run's time goes
    diag.extra["cpu_seconds"] = {"tuning": t1 - t0, "production": t2 - t1,
                                 "points": time.process_time() - t2}
    return {"psi": psi, "q": q, "diagnostics": diag, "imh_acceptance": imh_acc}


def _production(target, p0, moves, rng, run_kw, rerun=None):
    """The production run (step 4): ``(sampler, moves, info)``. With ``rerun`` (the
    proposal's mean and covariance, the HMC step and the likelihood) a run the time budget
    stopped is run again with HMC (:func:`_hmc_rerun`): the independence proposal looked
    fine in tuning, but the chain stuck in a tail it under-covers (tau grew past the
    budget; docs/bayes.md section 3)."""
    sampler = seeded_sampler(*np.shape(getattr(p0, "coords", p0)), target, rng, moves)
    info = run_until_converged(sampler, p0, **run_kw)
    if rerun is None or not info.get("stopped"):
        return sampler, moves, info
    stopped = info
    sampler, moves, info = _hmc_rerun(target, sampler, *rerun[:3], rng, rerun[3], run_kw)
    info["rerun_with_hmc"] = {"n_steps": stopped["n_steps"],
                              "max_tau": float(np.max(stopped["tau"]))}
    return sampler, moves, info


def _hmc_rerun(target, sampler, mean, cov, step_size, rng, lik, run_kw):
    """The production run again, with HMC, from the last state of a run without it that the
    time budget stopped (:data:`HMC_RETUNE` steps adapt the HMC step first, discarded)."""
    state = sampler.get_last_sample().coords
    hmc = HMCMove(target.value_and_grad, cov, step_size=step_size, n_steps=HMC_LEAPFROG,
                  adapt=True)
    tune = seeded_sampler(len(state), state.shape[1], target, rng,
                          [(hmc, HMC_WEIGHT), (IndependenceMove(mean, cov, scale=1.1,
                                                                df=imh_df(len(mean))), IMH_WEIGHT),
                           (de_move(), 1.0 - HMC_WEIGHT - IMH_WEIGHT)])
    state = tune.run_mcmc(state, HMC_RETUNE, progress=False).coords
    path = getattr(lik, "hmc_path", HMC_PATH)
    n_leap = int(np.clip(round(path / hmc.step_size), HMC_LEAPFROG, 3 * HMC_LEAPFROG))
    prod = default_moves(mean, cov, value_and_grad=target.value_and_grad,
                         weights=getattr(lik, "move_weights", None),
                         step_size=hmc.step_size, n_leapfrog=n_leap)
    sampler = seeded_sampler(len(state), state.shape[1], target, rng, prod)
    return sampler, prod, run_until_converged(sampler, state, **run_kw)


def posterior_outlier_prob(lik, psi, q, batch=None, max_draws=500):
    """Posterior probability (N,) that each row is an outlier: the mean over draws of its
    conditional probability given the globals (None without the mixture).

    Shared by both posteriors (approximate points and floor plan); ``lik`` provides
    ``outlier_prob(psi, q)``, ``psi`` (S, d) and ``q`` (S, N, k) are the draws. At most
    ``max_draws`` evenly spaced draws are used: a mean of probabilities in [0, 1] over 500
    draws has a Monte-Carlo error below 0.5 / sqrt(500) = 0.02 even for independent draws,
    and each draw costs a likelihood evaluation. ``batch`` draws go in one vectorized call
    (default ~5e5 (draw, point) pairs: bounds the temporaries' memory at large N).
    """
    if not getattr(lik, "outliers", False):
        return None
    every = max(1, -(-len(psi) // max_draws))
    psi, q = psi[::every], q[::every]
    # the aligned cone's in fused passes, cache-sized (same numbers: point_algebra)
    fused = callable(getattr(lik, "_marginal_block", None)) \
        and outlier_probs(lik, psi[:1], q[:1], OUTLIER_ITER) is not None
    if batch is None:
        batch = DRAW_ELEMENTS if fused else 500_000
        batch = max(1, batch // max(lik.n, 1))
    total = np.zeros(lik.n)
    for lo in range(0, len(psi), int(batch)):
        p = outlier_probs(lik, psi[lo:lo + batch], q[lo:lo + batch], OUTLIER_ITER) if fused \
            else lik.outlier_prob(psi[lo:lo + batch], q[lo:lo + batch])
        total += np.nan_to_num(p, nan=1.0).sum(axis=0)     # no inlier fit: an outlier
    return total / len(psi)
