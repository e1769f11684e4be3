"""The steps of the collapsed sampler: coordinates, target, proposal fit, walkers, run.

:func:`bayescal.mcmc.sampling.sample_collapsed` calls them in order:

1. :class:`~bayescal.mcmc.coordinates.Coordinates`: sampling coordinates (ring radii in
   place of gamma, ``H = h * depth_scale`` in place of h, ``docs/bayes.md`` section 3;
   re-exported here);
2. :class:`CollapsedTarget`: the log posterior with the points integrated out;
3. :func:`tune_proposal`: short emcee runs (HMC, independence, DE) refit the
   proposal and mass matrix and adapt the HMC step (:func:`fit_proposal`,
   adaptive importance sampling, is kept for experiments: it failed on
   prior-held ridges, ``docs/bayes.md`` section 3);
4. :func:`run_until_converged`: emcee in chunks until the honest ESS rule holds.
"""

from __future__ import annotations

import numpy as np

from ..stats.chains import ensemble_ess, integrated_time
from .coordinates import (
    _ASYMPTOTIC,
    Coordinates,
    depth_scale,
    from_sampling,
    log_jacobian,
    ring_scale,
    sampling_jacobian,
    to_sampling,
)
from .ensemble import spd_covariance, spread_walkers

#: leapfrog steps per HMC move (tuning and production runs)
HMC_LEAPFROG = 5


def default_walkers(ndim):
    """Default ensemble size: ``min(2 ndim + 2, max(24, ndim + 3))``.

    The stopping rule fixes the chain's length in steps (``tau_factor`` times tau)
    whatever the ensemble size, and the moves that do the mixing (independence,
    HMC) act on each walker alone: every walker beyond what the ESS target needs
    (ESS ~ walkers x 50 at the rule, so ~20 for 1000) only costs time. Small
    problems keep emcee's ``2 ndim + 2``; the 21-dimensional floor-plan posterior
    gets 24 walkers instead of 44 (1.7x faster at the same tau,
    ``docs/floorplan.md`` section 10). :func:`de_move` then runs with fewer
    walkers than emcee's red-blue rule of thumb.
    """
    return int(min(2 * ndim + 2, max(24, ndim + 3)))


def min_walkers(ndim):
    """Fewest walkers accepted: ``ndim + 2`` (the ensemble must span the sampled space:
    emcee's initial-state check and the proposal's covariance fits need it)."""
    return int(ndim) + 2


def de_move():
    """emcee's DEMove, allowed with fewer than ``2 ndim`` walkers.

    Differential evolution proposes ``x + gamma (x_a - x_b)`` from two walkers of the
    other half of the ensemble: a symmetric proposal, exact for any ensemble size.
    With fewer than ``2 ndim`` walkers one step spans only a subspace, which emcee
    warns about (``live_dangerously``); here it is the minority move beside
    per-walker independence and HMC moves, which span every direction.
    """
    import emcee

    return emcee.moves.DEMove(live_dangerously=True)


def imh_df(ndim):
    """Degrees of freedom of the independence proposal's Student-t: ``max(5, ndim)``.

    Heavy tails keep the independence move safe where the posterior's tails are
    heavier than the fit's, but they cost acceptance in many dimensions even when
    the fit is perfect: against N(0, I_21), t_5 accepts 48 % and t_21 ~70 %. With
    df growing with the dimension the 21-dimensional floor-plan posterior mixed
    1.6x faster per step (``docs/floorplan.md`` section 10).
    """
    return max(5.0, float(ndim))

__all__ = ["ring_scale", "depth_scale", "Coordinates", "log_jacobian", "to_sampling",
           "from_sampling", "sampling_jacobian", "CollapsedTarget", "fit_proposal", "tune_proposal",
           "seeded_sampler", "run_until_converged", "imh_df", "default_walkers",
           "min_walkers", "de_move", "BUDGET_FACTOR", "IMH_FITS"]


class CollapsedTarget:
    """Vectorized log posterior with the points integrated out, in sampling coordinates.

    Parameters
    ----------
    lik : likelihood
        Provides ``laplace(psi, q0, n_iter=...)`` and ``log_prior_extra(extra)``.
    prior : Prior
        Prior of theta (``logpdf_theta``).
    q_start : ndarray, shape (N, k)
        Start of each point's Gauss-Newton step (the MAP's points).
    n_iter : int
        Gauss-Newton iterations per evaluation.
    coords : Coordinates, optional
        Sampling coordinates (default: the asymptotic ring).

    Called with sampling coordinates ``s`` (W, d); returns log densities (W,),
    ``-inf`` outside the support. The density includes the Jacobian
    ``|d psi / d s|`` (:func:`log_jacobian`) of the change of variables.
    """

    def __init__(self, lik, prior, q_start, n_iter, coords=None):
        self.lik, self.prior, self.q_start, self.n_iter = lik, prior, q_start, n_iter
        self.coords = _ASYMPTOTIC if coords is None else coords
        self.n_calls, self.n_grad_calls = 0, 0

    def log_prior(self, psi):
        """Log prior of psi (..., d) (theta's prior plus the extra globals')."""
        return self.prior.logpdf_theta(psi[..., :7]) + self.lik.log_prior_extra(psi[..., 7:])

    def __call__(self, s):
        s = np.atleast_2d(s)
        self.n_calls += len(s)
        psi, log_jac = self.coords.from_sampling_log_jacobian(s)
        with np.errstate(invalid="ignore", divide="ignore"):
            lp = self.log_prior(psi) + log_jac
        out = np.full(len(psi), -np.inf)
        ok = np.isfinite(lp)
        if np.any(ok):
            out[ok] = lp[ok] + self._log_marginal(psi[ok])
        return np.where(np.isfinite(out), out, -np.inf)


    def _log_marginal(self, psi):
        """The likelihood's log marginal; its ``log_marginal`` where it has one (cheaper)."""
        fn = getattr(self.lik, "log_marginal", None)
        if callable(fn):
            return fn(psi, self.q_start, n_iter=self.n_iter)
        return self.lik.laplace(psi, self.q_start, n_iter=self.n_iter)[0]

    @property
    def has_gradient(self):
        """Whether the likelihood offers ``grad_log_marginal`` (else gradient moves are off)."""
        return callable(getattr(self.lik, "grad_log_marginal", None))

    def _prior_value_and_grad(self, psi, eps):
        """Log prior (W,) at psi (W, d) and its gradient (W, d) in psi by forward differences
        (step ``eps * max(1, |psi|)``): theta's prior over theta's 7 entries only, the
        extras' (cheap) over theirs; each in one call for the rows and their shifted
        copies."""
        W, d = psi.shape
        h = eps * np.maximum(1.0, np.abs(psi))                     # (W, d)
        E = np.eye(d)[:, None, :] * h[None]                        # (d, W, d)
        x = np.concatenate([psi[None], psi[None] + E])             # (1 + d, W, d)
        with np.errstate(invalid="ignore", divide="ignore"):
            th = self.prior.logpdf_theta(x[:8, :, :7])
            ex = self.lik.log_prior_extra(np.concatenate([x[:1], x[8:]])[..., 7:])
            diff = np.empty((d, W))
            diff[:7] = th[1:] - th[0]
            diff[7:] = ex[1:] - ex[0]
        return th[0] + ex[0], diff.T / h

    def value_and_grad(self, s, eps=1e-8):
        """Log density (W,) and its gradient (W, d) in sampling coordinates.

        The likelihood part is analytic (``lik.grad_log_marginal``); the prior (cheap) by
        forward differences in psi (:meth:`_prior_value_and_grad`); both chained through ``d
        psi / d s`` (:meth:`~bayescal.mcmc.coordinates.Coordinates.inverse_jacobian`, whose
        shifted copies give the change-of-variables term's gradient in ``s`` too). The
        value is exactly :meth:`__call__`'s. NaN gradient where the value is ``-inf``.
        """
        s = np.atleast_2d(np.asarray(s, float))
        W, d = s.shape
        self.n_calls += W
        self.n_grad_calls += W
        # dpsi[w, k, j] = d psi_j / d s_k; the log Jacobian and its gradient in s
        psi, dpsi, lj, g_lj = self.coords.inverse_jacobian(s, log_jacobian=True)
        lp, g_prior = self._prior_value_and_grad(psi, eps)
        lp = lp + lj                                    # as __call__ adds them
        out = np.full(W, -np.inf)
        grad = np.full((W, d), np.nan)
        ok = np.isfinite(lp)
        if np.any(ok):
            ll, g_psi = self.lik.grad_log_marginal(psi[ok], self.q_start, n_iter=self.n_iter)
            out[ok] = lp[ok] + ll
            grad[ok] = np.einsum("wkj,wj->wk", dpsi[ok], g_psi + g_prior[ok]) + g_lj[ok]
        bad = ~np.isfinite(out)
        out[bad] = -np.inf
        grad[bad] = np.nan
        return out, grad

def _t_draws(mean, L, df, n, rng):
    """n draws of the multivariate t_df(mean, L L^T) and their log density (up to const)."""
    z = rng.standard_normal((n, len(mean)))
    w = rng.chisquare(df, size=n) / df
    x = mean + (z / np.sqrt(w)[:, None]) @ L.T
    m = np.sum(np.linalg.solve(L, (x - mean).T) ** 2, axis=0)
    return x, -0.5 * (df + len(mean)) * np.log1p(m / df) - np.sum(np.log(np.diag(L)))


def fit_proposal(target, mean, cov, rng, *, n_draws, n_rounds=4, df=5.0, inflate=2.0):
    """Fit a Student-t to the target by adaptive importance sampling.

    Each round draws ``n_draws`` points from ``t_df(mean, cov)``, weights them by
    ``target / proposal`` and replaces mean and covariance by the weighted
    moments. The first round's covariance is ``inflate * cov`` so that a too
    narrow Laplace covariance (a curved or skewed, prior-held ridge) is
    corrected from outside. No chain is run: the draws are independent, so the
    fit does not inherit a sticky chain's autocorrelation.

    Returns
    -------
    dict
        ``mean`` (d,), ``cov`` (d, d), ``draws`` (n, d) and normalised ``weights``
        (n,) of the last round, ``ess_weights`` per round (importance-sampling
        effective sizes) and ``logw_sd`` (sd of the last round's log weights: ~0
        when the proposal fits, ~1 at 40 % independence acceptance).
    """
    mean = np.asarray(mean, float)
    cov = inflate * np.asarray(cov, float)
    ess_w, logw_sd = [], float("nan")
    for _ in range(int(n_rounds)):
        L = np.linalg.cholesky(cov + 1e-12 * np.diag(np.diag(cov)))
        x, lq = _t_draws(mean, L, df, int(n_draws), rng)
        logw = target(x) - lq
        ok = np.isfinite(logw)
        if ok.sum() < 2 * len(mean) + 2:
            break
        w = np.zeros(len(x))
        w[ok] = np.exp(logw[ok] - logw[ok].max())
        w /= w.sum()
        ess_w.append(float(1.0 / np.sum(w * w)))
        logw_sd = float(np.std(logw[ok]))
        new_mean = w @ x
        xc = x - new_mean
        new_cov = (w[:, None] * xc).T @ xc
        if ess_w[-1] < 2 * len(mean) + 2 or np.any(np.linalg.eigvalsh(new_cov) <= 0):
            cov = 2.0 * cov                        # weights degenerate: widen and retry
            continue
        mean, cov = new_mean, new_cov
    return {"mean": mean, "cov": cov, "draws": x, "weights": w, "ess_weights": ess_w,
            "logw_sd": logw_sd}


#: independence acceptance of the first tuning round (its proposal: the Laplace fit) from
#: which on a posterior counts as near-Gaussian and the sampler leaves HMC out (each HMC
#: move costs 5-15 gradient evaluations, an independence move one density evaluation).
#: Measured: per-point posteriors at N = 580 accept 34-43 %, at N = 20 000 23 % (without
#: HMC there 137 s of CPU against 201 s with it), the misaligned floor plan 8-12 % (it
#: needs HMC to converge); docs/performance.md
IMH_FITS = 0.15


def tune_proposal(target, p0, mean, cov, rng, *, n_steps, n_rounds=3, moves=None,
                  gradient=False, step_size=0.3, imh_fits=IMH_FITS):
    """Fit the proposal (and the HMC step) from short emcee runs, each using the previous fit.

    Round r runs ``n_steps`` steps with the independence proposal ``t(mean, cov)``
    (inflated 1.5x in the first round, whose ``cov`` is the Laplace one) mixed with
    DEMove and, with ``gradient=True``, :class:`~bayescal.mcmc.moves.HMCMove` (mass
    matrix ``cov^-1``, step size adapted towards 75 % acceptance, carried over
    rounds). Each round refits mean and covariance from the last two thirds of
    its chain: as the proposal and the mass matrix improve, the chain mixes
    faster and the next fit is better. These chains are discarded.

    With ``gradient=True`` the first round runs without HMC (independence 90 %, DE
    10 %: one density evaluation per step) and decides: where its independence
    acceptance reaches ``imh_fits`` the posterior is near-Gaussian, the later rounds and
    the production run go without HMC (``use_hmc`` False); below, the first round's
    draws are not trusted for the fit (they barely moved), and the later rounds add HMC.

    Returns
    -------
    dict
        ``mean``, ``cov``, ``state`` (the last walker positions), ``acceptance``
        per round, ``imh_acceptance`` per round, ``step_size`` (the adapted HMC step,
        or the input), ``use_hmc`` (whether the production run should use HMC).
    """
    from .moves import HMCMove, IndependenceMove

    state, acc, imh_acc, prev = p0, [], [], None
    ndim = len(mean)
    use_hmc = bool(gradient) and moves is None
    for r in range(int(n_rounds)):
        imh = IndependenceMove(mean, (1.5 if r == 0 else 1.0) * cov, scale=1.1,
                               df=imh_df(ndim))
        hmc = None
        if moves is not None:
            mv = moves
        elif use_hmc and r > 0:
            hmc = HMCMove(target.value_and_grad, cov, step_size=step_size,
                          n_steps=HMC_LEAPFROG, adapt=True)
            mv = [(hmc, 0.3), (imh, 0.6), (de_move(), 0.1)]
        else:
            mv = [(imh, 0.9), (de_move(), 0.1)] if use_hmc else [(imh, 0.7), (de_move(), 0.3)]
        tune = seeded_sampler(len(p0), ndim, target, rng, mv)
        state = tune.run_mcmc(spread_walkers(state, target, cov, rng), int(n_steps),
                              progress=False)
        acc.append(float(np.mean(tune.acceptance_fraction)))
        imh_acc.append(float(imh.acceptance))
        if hmc is not None:
            step_size = hmc.step_size
        if use_hmc and r == 0:
            if imh.acceptance >= imh_fits:
                use_hmc = False                     # near-Gaussian: no HMC from here on
            else:
                continue                            # a sticky round: keep the Laplace fit
        ch = tune.get_chain(discard=int(n_steps) // 3).reshape(-1, ndim)
        # pool with the previous round's draws (valid posterior draws too, after their
        # burn-in): twice the draws for the covariance of many coordinates
        ch, prev = (ch if prev is None else np.concatenate([prev, ch])), ch
        new_cov = np.cov(ch, rowvar=False)
        if np.all(np.linalg.eigvalsh(new_cov) > 0):     # else a collapsed round: keep the last
            mean, cov = ch.mean(axis=0), spd_covariance(new_cov, cov)
    return {"mean": mean, "cov": cov, "state": state, "acceptance": acc,
            "imh_acceptance": imh_acc, "step_size": float(step_size), "use_hmc": use_hmc}


def seeded_sampler(nwalkers, ndim, fn, rng, moves):
    """emcee EnsembleSampler (vectorized) whose legacy RandomState is seeded from ``rng``."""
    import emcee

    sampler = emcee.EnsembleSampler(nwalkers, ndim, fn, vectorize=True, moves=moves)
    sampler.random_state = np.random.RandomState(
        np.random.MT19937(rng.integers(2**32))).get_state()
    return sampler


#: smallest burn-in, as a fraction of the chain: the start (the last tuning state) can sit
#: off the stationary spread along a ridge for longer than the stationary tau suggests
#: (a likelihood near-Gaussian in the sampling coordinates may ask for less:
#: ``run_until_converged(burn_floor=...)``)
BURN_FLOOR = 0.25


def _assess(chain, tau_factor, burn_factor, coords=None, burn_floor=BURN_FLOOR):
    """Burn-in, honest ESS and tau of a chain (T, W, d) in sampling coordinates; the verdict.

    The burn-in is ``burn_factor`` times the provisional tau, at least ``burn_floor``
    of the chain and at most half of it. ESS is that of the parameters
    (``from_sampling``: what the user averages); tau, for the ``tau_factor`` rule, is
    the larger of the parameter's and its sampling coordinate's (``W T / ESS`` each),
    so neither is cut short.
    """
    total = len(chain)
    tau_w = integrated_time(chain[total // 5:])      # first fifth: provisional burn-in
    burn = int(min(max(np.ceil(burn_factor * np.max(tau_w)), int(burn_floor * total)),
                   total // 2)) if np.all(np.isfinite(tau_w)) else total // 2
    kept = chain[burn:]
    _, tau_s = ensemble_ess(kept)
    ess, tau_p = ensemble_ess((coords or _ASYMPTOTIC).from_sampling(kept))
    tau = np.maximum(tau_s, tau_p)
    converged = bool(np.all(np.isfinite(tau)) and total - burn > tau_factor * np.max(tau))
    return burn, ess, tau, converged


#: a chain may take this many times the steps its stopping rule first projected
BUDGET_FACTOR = 3.0


def run_until_converged(sampler, p0, *, min_ess, tau_factor, max_steps, chunk, progress,
                        burn_factor=5.0, coords=None, budget=None, burn_floor=BURN_FLOOR):
    """Run emcee in chunks until ``kept > tau_factor * tau`` and the honest ESS >= ``min_ess``.

    The progress bar shows the percentage of the stopping rule met so far: the
    smaller of ``min ESS / min_ess`` and ``kept steps / (tau_factor * max tau)``.

    **Budget.** After 200 steps the rule projects the steps it needs; a healthy chain
    meets it near that projection. With ``budget`` the run stops, not converged, once
    it has taken ``budget`` times that projection (at least ``budget * 200`` steps)
    and still misses the rule: its autocorrelation time
    grew on the way, typically rows switching between inlier and outlier, or several
    modes. ``info["stopped"]`` then says so (``None`` to run to ``max_steps``).

    Returns
    -------
    dict
        ``tau``, ``ess`` (per coordinate, :func:`bayescal.stats.chains.ensemble_ess`),
        ``burn``, ``n_steps``, ``converged`` (the 50-tau part of the rule and the
        ESS target both met), ``stopped`` (why the budget stopped it, or None).
    """
    state, total, info, pbar, first = p0, 0, {}, None, None
    if progress:
        from tqdm.auto import tqdm

        pbar = tqdm(total=100, desc="stopping rule", unit="%", leave=False)
    try:
        while total < max_steps:
            n = min(chunk, max_steps - total)
            state = sampler.run_mcmc(state, n, progress=False)
            total += n
            burn, ess, tau, long_enough = _assess(sampler.get_chain(), tau_factor, burn_factor,
                                                 coords, burn_floor)
            done = long_enough and np.min(ess) >= min_ess
            info = {"tau": tau, "burn": burn, "n_steps": total, "converged": bool(done),
                    "ess": ess, "stopped": None}
            if pbar is not None:
                with np.errstate(invalid="ignore", divide="ignore"):
                    frac = min(np.min(ess) / min_ess, (total - burn) / (tau_factor * np.max(tau)))
                pbar.n = int(100 * np.clip(np.nan_to_num(frac), 0.0, 1.0))
                pbar.set_postfix(steps=total, ess=f"{np.min(ess):.0f}", tau=f"{np.max(tau):.1f}")
                pbar.refresh()
            if done:
                break
            # grow the next chunk to what the current tau says is still needed
            need_len = max(tau_factor * np.max(tau), min_ess * np.max(tau) / sampler.nwalkers)
            need = need_len + burn - total if np.isfinite(need_len) else chunk
            if first is None and total >= 200:        # tau from >= 200 steps, not fewer
                first = (max(need_len + burn, total) if np.isfinite(need_len) else total,
                         float(np.max(tau)))
            if budget is not None and first is not None and total >= budget * first[0]:
                info["stopped"] = (
                    f"stopped by its time budget after {total} steps, {budget:g} times the "
                    f"{first[0]:.0f} the stopping rule first projected: the autocorrelation "
                    f"time grew from {first[1]:.3g} to {np.max(tau):.3g} steps (rows switching "
                    "between inlier and outlier, or several modes: see outlier_prob and the "
                    "least-squares fit)")
                break
            chunk = int(np.clip(1.2 * need, 50, max(chunk, 50) * 4))
            if budget is not None and first is not None:    # end on the budget, not past it
                chunk = int(max(min(chunk, budget * first[0] - total), 1))
    finally:
        if pbar is not None:
            pbar.close()
    return info
