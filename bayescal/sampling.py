"""Posterior sampling: a collapsed emcee sampler over the identifiable parameters.

The joint posterior over the 8 parameters and the N laser points has
``7 + 2N`` free dimensions (``phi`` is not seen by the data); emcee does not mix
there (DESIGN fact 5). The points are independent given the parameters, so:

1. **MAP**: :func:`bayescal.calibrate_simultaneous` (same likelihood, same priors)
   gives the start and the Laplace covariance.
2. **Collapsed chain**: emcee samples ``psi = (theta, [log sigma_px], [log kappa])``
   under ``log p(theta) + sum_i log int p(data_i | theta, q_i) dq_i``, each
   point's integral by a Gauss-Newton/Laplace step vectorized over
   walkers x points (:meth:`bayescal.model.LaserLikelihood.laplace`).
3. **Convergence**: emcee's integrated autocorrelation time ``tau``; the
   chain runs in chunks until its post-burn-in length exceeds ``50 tau`` for
   every coordinate and the effective sample size reaches ``min_ess``, or
   ``max_steps`` is hit (then a :class:`NotConvergedWarning` or, with
   ``on_unconverged="raise"``, a :class:`NotConvergedError` carrying ``tau``).
4. **phi and the points**: for each kept sample, ``phi`` is drawn from its
   exact conditional (quadrature), and each point from its Laplace Gaussian,
   then corrected by independence Metropolis-Hastings steps against the exact
   conditional density (so a non-Gaussian conditional is still sampled
   correctly).
"""

from __future__ import annotations

import warnings

import numpy as np

from ._validation import resolve_rng
from .model import NOISE_BOUNDS, LaserLikelihood
from .moves import IndependenceMove
from .parameters import from_identifiable
from .priors import Prior

__all__ = ["sample_posterior", "sample_joint", "NotConvergedWarning", "NotConvergedError",
           "NoiseAtBoundWarning",
           "default_moves", "NOISE_BOUNDS"]

class NotConvergedWarning(UserWarning):
    """The chain is shorter than 50 autocorrelation times (results may be biased)."""


class NoiseAtBoundWarning(UserWarning):
    """An inferred noise level's posterior piles up at its prior's lower bound."""


class NotConvergedError(RuntimeError):
    """The chain did not converge; ``.tau`` holds the autocorrelation times, ``.posterior``
    the (unconverged) result."""

    def __init__(self, message, tau=None, posterior=None):
        super().__init__(message)
        self.tau = tau
        self.posterior = posterior


def default_moves(mean=None, cov=None):
    """emcee moves used by default.

    With a proposal ``mean`` and ``cov`` (from the Laplace approximation or a
    tuning run): :class:`~bayescal.moves.IndependenceMove` (70 %) mixed with
    :class:`emcee.moves.DEMove` (30 %). Without: DEMove (80 %) and StretchMove
    (20 %). ``DESnookerMove`` is deliberately absent: in emcee 3.1.6 it samples
    the wrong distribution (DESIGN fact 6). Each move here is tested on N(0, I).
    """
    import emcee

    if mean is None:
        return [(emcee.moves.DEMove(), 0.8), (emcee.moves.StretchMove(), 0.2)]
    return [(IndependenceMove(mean, cov), 0.7), (emcee.moves.DEMove(), 0.3)]


def ring_scale(theta):
    """``sin(beta) / (xi - cos(beta))``: the laser ring's asymptotic radius per unit gamma.

    A laser point far away images at ``gamma * sin(beta) / (xi - cos(beta))`` px from
    the principal point; at large range the data pin this radius, not gamma, xi and
    beta one by one, so the sampler works with ``R_u = gamma_u * ring_scale`` and
    ``R_v = gamma_v * ring_scale`` in place of ``gamma_u``, ``gamma_v``.
    """
    xi, beta = theta[..., 0], theta[..., 6]
    with np.errstate(divide="ignore", invalid="ignore"):
        return np.where(xi - np.cos(beta) > 0, np.sin(beta) / (xi - np.cos(beta)), np.nan)


def to_sampling(psi):
    """Sampling coordinates: psi with (gamma_u, gamma_v) replaced by the ring radii."""
    s = np.array(psi, dtype=float)
    k = ring_scale(s)
    s[..., 1] *= k
    s[..., 2] *= k
    return s


def from_sampling(s):
    """Inverse of :func:`to_sampling`."""
    psi = np.array(s, dtype=float)
    k = ring_scale(psi)
    psi[..., 1] /= k
    psi[..., 2] /= k
    return psi


def _sampling_jacobian(psi, eps=1e-7):
    """d to_sampling / d psi by central differences, (ndim, ndim)."""
    psi = np.asarray(psi, float)
    d = len(psi)
    J = np.empty((d, d))
    for k in range(d):
        h = eps * max(1.0, abs(psi[k]))
        e = np.zeros(d)
        e[k] = h
        J[:, k] = (to_sampling(psi + e) - to_sampling(psi - e)) / (2 * h)
    return J


class _CollapsedTarget:
    """Vectorized log posterior with the points integrated out, in sampling coordinates.

    Called with sampling coordinates (:func:`to_sampling`); the density includes the
    Jacobian ``|d psi / d s| = ring_scale^-2`` of the change of variables.
    """

    def __init__(self, lik, prior, q_start, n_iter):
        self.lik, self.prior, self.q_start, self.n_iter = lik, prior, q_start, n_iter

    def log_prior(self, psi):
        return self.prior.logpdf_theta(psi[..., :7]) + self.lik.log_prior_extra(psi[..., 7:])

    def __call__(self, s):
        s = np.atleast_2d(s)
        psi = from_sampling(s)
        with np.errstate(invalid="ignore", divide="ignore"):
            lp = self.log_prior(psi) - 2.0 * np.log(ring_scale(psi))
        out = np.full(len(psi), -np.inf)
        ok = np.isfinite(lp)
        if np.any(ok):
            ll, _, _ = self.lik.laplace(psi[ok], self.q_start, n_iter=self.n_iter)
            out[ok] = lp[ok] + ll
        return np.where(np.isfinite(out), out, -np.inf)


def _seeded_sampler(nwalkers, ndim, fn, rng, moves):
    import emcee

    sampler = emcee.EnsembleSampler(nwalkers, ndim, fn, vectorize=True, moves=moves)
    # emcee draws from a legacy RandomState: seed it from our Generator
    sampler.random_state = np.random.RandomState(
        np.random.MT19937(rng.integers(2**32))).get_state()
    return sampler


def _tau(chain):
    """Integrated autocorrelation time per coordinate, chain (steps, walkers, dim)."""
    import emcee

    return emcee.autocorr.integrated_time(chain, tol=0, quiet=True)


def run_until_converged(sampler, p0, *, min_ess, tau_factor, max_steps, chunk, progress,
                        burn_factor=5.0):
    """Run emcee in chunks until ``len > tau_factor * tau`` and ESS >= ``min_ess``.

    Returns
    -------
    dict
        ``tau``, ``burn``, ``n_steps``, ``converged``, ``ess``.
    """
    state = p0
    total = 0
    info = {}
    pbar = None
    if progress:
        from tqdm.auto import tqdm

        pbar = tqdm(total=max_steps, desc="emcee (collapsed)", unit="step", leave=False)
    try:
        while total < max_steps:
            n = min(chunk, max_steps - total)
            state = sampler.run_mcmc(state, n, progress=False)
            total += n
            if pbar is not None:
                pbar.update(n)
            chain = sampler.get_chain()
            tau = _tau(chain[total // 5:])          # drop the first fifth as a provisional burn
            # a coordinate with no movement in the window has an undefined tau: not converged
            tau = np.where(np.isfinite(tau), tau, np.inf)
            burn = int(min(np.ceil(burn_factor * np.max(tau)), total // 2))
            kept = total - burn
            ess = sampler.nwalkers * kept / tau
            converged = kept > tau_factor * np.max(tau)
            info = {"tau": tau, "burn": burn, "n_steps": total, "converged": bool(converged),
                    "ess": ess}
            if pbar is not None:
                pbar.set_postfix(tau=f"{np.max(tau):.1f}", ess=f"{np.min(ess):.0f}")
            if converged and np.min(ess) >= min_ess:
                break
            # grow the next chunk to what the current tau says is still needed
            need_len = max(tau_factor * np.max(tau), min_ess * np.max(tau) / sampler.nwalkers)
            need = need_len + burn - total if np.isfinite(need_len) else chunk
            chunk = int(np.clip(need, 50, max(chunk, 50) * 4))
    finally:
        if pbar is not None:
            pbar.close()
    return info


def _gauss_draw(mean, L, rng):
    """Draw from N(mean, L L^T) per point; returns the draw and its log density + const."""
    z = rng.standard_normal(mean.shape)
    return mean + np.einsum("...ij,...j->...i", L, z), -0.5 * np.sum(z * z, axis=-1)


def _draw_points(lik, psi, q_start, rng, *, n_mh, n_iter, batch=256):
    """Draw every point's scene coordinates given each psi sample (Laplace + IMH)."""
    S = len(psi)
    out = np.empty((S, lik.n, 2))
    acc = []
    for lo in range(0, S, batch):
        p = psi[lo:lo + batch]
        _, qm, C = lik.laplace(p, q_start, n_iter=n_iter)
        L = np.linalg.cholesky(np.linalg.inv(C))                         # (b, N, 2, 2)
        q, lg = _gauss_draw(qm, L, rng)
        lp = lik.point_log_density(p, q)
        for _ in range(n_mh):
            q2, lg2 = _gauss_draw(qm, L, rng)
            lp2 = lik.point_log_density(p, q2)
            log_r = (lp2 - lg2) - (lp - lg)
            accept = np.log(rng.random(log_r.shape)) < log_r
            q = np.where(accept[..., None], q2, q)
            lp = np.where(accept, lp2, lp)
            lg = np.where(accept, lg2, lg)
            acc.append(accept.mean())
        out[lo:lo + batch] = q
    return out, float(np.mean(acc)) if acc else float("nan")


def sample_posterior(pixels, approx_points, *, sigma_px, sigma_scene, prior=None, rng=None,
                     n_walkers=None, min_ess=1000, tau_factor=50, max_steps=20000,
                     n_samples=2000, init=None, moves=None, progress=True,
                     on_unconverged="warn", n_point_mh=2, n_iter=1, n_tune=150):
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
        ``2 * ndim + 2``: with the tuned independence proposal the chain length,
        not the ensemble size, limits the run, so few walkers are cheapest).
    min_ess : float, optional
        Target effective sample size of every sampled coordinate.
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
        emcee moves for both runs (default :func:`default_moves`: tuned
        independence proposal mixed with differential evolution).
    n_tune : int, optional
        Steps of the tuning run that sets the proposal (discarded).
    progress : bool, optional
        Show a progress bar.
    on_unconverged : {"warn", "raise"}
        What to do when ``max_steps`` is reached before convergence.
    n_point_mh : int, optional
        Independence Metropolis-Hastings corrections per point draw.
    n_iter : int, optional
        Gauss-Newton iterations of the per-point Laplace step.

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
    from .posterior import Posterior
    from .simultaneous import calibrate_simultaneous

    if on_unconverged not in ("warn", "raise"):
        raise ValueError(f"on_unconverged must be 'warn' or 'raise', got {on_unconverged!r}")
    rng = resolve_rng(rng)
    prior = prior if isinstance(prior, Prior) else Prior(prior)
    lik = LaserLikelihood(pixels, approx_points, sigma_px=sigma_px, sigma_scene=sigma_scene)
    ndim = 7 + len(lik.extra_names)
    n_walkers = 2 * ndim + 2 if n_walkers is None else int(n_walkers)
    if n_walkers < 2 * ndim:
        raise ValueError(f"n_walkers must be at least 2 * ndim = {2 * ndim} for emcee's "
                         f"red-blue moves, got {n_walkers}")
    if int(n_samples) < 1:
        raise ValueError(f"n_samples must be a positive integer, got {n_samples!r}")

    map_res = calibrate_simultaneous(lik.pixels, lik.approx, sigma_px=sigma_px,
                                     sigma_scene=sigma_scene, prior=prior, init=init)
    sol = map_res.extras["map"]
    noise = map_res.extras["noise"]
    lik.set_reference_noise(sigma_px=noise["sigma_px"], kappa=noise["kappa"])
    psi_map = list(sol.theta)
    if lik.infer_px:
        psi_map.append(np.log(noise["sigma_px"]))
    if lik.infer_scene:
        psi_map.append(np.log(noise["kappa"]))
    psi_map = np.array(psi_map)
    cov0 = np.zeros((ndim, ndim))
    cov0[:7, :7] = sol.cov_theta
    for k in range(7, ndim):
        cov0[k, k] = (1.0 / np.sqrt(lik.n)) ** 2          # ~ relative sd of a noise estimate
    target = _CollapsedTarget(lik, prior, sol.q, n_iter)
    J = _sampling_jacobian(psi_map)
    psi_map, cov0 = to_sampling(psi_map), J @ cov0 @ J.T     # sampling coordinates from here
    p0 = rng.multivariate_normal(psi_map, cov0, size=n_walkers)
    lp0 = target(p0)
    for _ in range(100):
        bad = ~np.isfinite(lp0)
        if not bad.any():
            break
        p0[bad] = rng.multivariate_normal(psi_map, cov0 * 0.01, size=int(bad.sum()))
        lp0[bad] = target(p0[bad])
    else:
        raise RuntimeError("could not place the walkers: the MAP start is outside the support")

    # tuning: two short emcee runs with an independence proposal (first from the Laplace
    # covariance, then from the first run's draws) and DE; the last two thirds of the
    # second run give the mean and covariance of the production run's frozen proposal
    n_tune = int(n_tune)
    state, mean, cov = p0, psi_map, cov0
    prod_moves = moves
    for scale in (1.5, 1.0):              # two tuning rounds, each refits the proposal
        if n_tune <= 0:
            break
        tune = _seeded_sampler(n_walkers, ndim, target, rng,
                               default_moves(mean, scale * cov) if moves is None else moves)
        state = tune.run_mcmc(state, n_tune, progress=False)
        if moves is None:
            ch = tune.get_chain(discard=n_tune // 3).reshape(-1, ndim)
            mean, cov = ch.mean(axis=0), np.cov(ch, rowvar=False)
    if moves is None:
        prod_moves = default_moves(mean, cov)
    sampler = _seeded_sampler(n_walkers, ndim, target, rng, prod_moves)
    info = run_until_converged(sampler, state, min_ess=min_ess, tau_factor=tau_factor,
                               max_steps=int(max_steps), chunk=200, progress=progress)
    chain = sampler.get_chain()
    flat = chain[info["burn"]:].reshape(-1, ndim)
    if len(flat) == 0:
        flat = chain[-1]
    idx = np.linspace(0, len(flat) - 1, min(int(n_samples), len(flat))).round().astype(int)
    psi = from_sampling(flat[idx])
    phi = prior.sample_phi(psi[:, :7], rng=rng)
    a = from_identifiable(psi[:, :7], phi)
    q, imh_acc = _draw_points(lik, psi, sol.q, rng, n_mh=n_point_mh, n_iter=n_iter + 2)
    pts = lik.points_3d(psi, q)
    post = Posterior(
        param_samples=a, point_samples=pts, noise_samples=psi[:, 7:],
        noise_names=lik.extra_names,
        pixels=lik.pixels, approx_points=lik.approx,
        sigma_px=sigma_px, sigma_scene=None if sigma_scene is None else
        np.broadcast_to(np.asarray(sigma_scene, float), lik.approx.shape).copy(),
        prior=prior, map_result=map_res, tau=info["tau"], ess=info["ess"],
        n_steps=info["n_steps"], burn=info["burn"], n_walkers=n_walkers,
        converged=info["converged"],
        acceptance=float(np.mean(sampler.acceptance_fraction)), imh_acceptance=imh_acc)
    for k, name in enumerate(post.noise_names):
        lo = NOISE_BOUNDS[name][0]
        if np.quantile(np.exp(post.noise_samples[:, k]), 0.05) < 2 * lo:
            warnings.warn(f"the posterior of the inferred {name} reaches its prior's lower "
                          f"bound {lo:g}: the data cannot separate the noise levels (too few "
                          f"points?); give {name if name == 'sigma_px' else 'sigma_scene'} "
                          f"explicitly", NoiseAtBoundWarning, stacklevel=2)
    if not info["converged"]:
        msg = (f"the chain did not converge within max_steps={max_steps}: it has "
               f"{info['n_steps'] - info['burn']} steps after burn-in, fewer than "
               f"{tau_factor} x tau = {tau_factor * np.max(info['tau']):.0f}")
        if on_unconverged == "raise":
            raise NotConvergedError(msg, tau=info["tau"], posterior=post)
        warnings.warn(msg, NotConvergedWarning, stacklevel=2)
    return post


def sample_joint(pixels, approx_points, *, sigma_px, sigma_scene, prior=None, rng=None,
                 n_walkers=None, n_steps=20000, init_from=None, progress=False):
    """Brute-force emcee over the full joint ``(theta, q_1..q_N)`` (validation only).

    This is the naive sampler the collapsed one replaces: ``7 + 2N`` dimensions,
    slow to mix (DESIGN fact 5). It exists to check the collapsed sampler on
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
    sampler = _seeded_sampler(n_walkers, ndim, logp, rng, None)
    sampler.run_mcmc(p0, int(n_steps), progress=progress)
    chain = sampler.get_chain()
    kept = chain[len(chain) // 2:].reshape(-1, ndim)
    return {"chain": chain, "theta": kept[:, :7], "q": kept[:, 7:].reshape(-1, n, 2),
            "tau": _tau(chain[len(chain) // 2:]),
            "acceptance": float(np.mean(sampler.acceptance_fraction))}
