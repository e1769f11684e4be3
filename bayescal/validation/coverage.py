"""Coverage and simulation-based calibration of the Bayesian posterior (docs/validation.md, rung 4).

Two experiments, both with the model right (``approx_model="gaussian"`` noise of
known standard deviation on every coordinate of the approximate points):

* **Coverage on fixed scenes.** One room (walls, true sensor = the paper's, N
  laser points) and M noise replications (fresh pixel noise, fresh
  approximate-point noise). For each replication :func:`bayescal.sample_posterior`
  gives equal-tailed credible intervals of the 7 identifiable parameters and of
  every point's 3 coordinates; the script counts how often they hold the truth at
  levels 0.5 ... 0.99, and the same for the MAP/Laplace intervals
  (``map +- z sd`` from the Laplace covariance). Per point it also records the
  normalised squared error ``(mean - truth)^T Cov^-1 (mean - truth)``, which
  follows chi-square(3) when the posterior is calibrated. Two rooms: small
  (1000 mm, 0.5 px, 1 %) and large (5000 mm, 0.1 px, 5 %).
* **Simulation-based calibration** (Talts et al. 2018). Truth drawn from the
  prior (:meth:`bayescal.Prior.sample`), fixed walls, data simulated, 99 thinned
  posterior draws; the rank of the truth among them is uniform on 0..99 when
  the posterior is right. Ranks of the 7 identifiable parameters and of phi,
  in 10 bins.

The approximate points' standard deviation is ``approx_error * |coordinate|``
floored at :data:`SCENE_FLOOR_MM` (a coordinate near 0 would otherwise carry a
near-exact scene row); the noise is drawn with that same floored value, so the
likelihood is exactly the data-generating one.

``studies/coverage.py`` runs both experiments and draws their figures
(:mod:`bayescal.plotting.validation`); ``tests/validation/test_validation.py`` runs them at
test size. Replications run inline, in local processes or on a Dask cluster
(:func:`bayescal.validation.executors.executor`).
"""

from __future__ import annotations

import functools
import time
import warnings

import numpy as np
from scipy import stats

from ..errors import InvalidValueError
from ..likelihood.priors import Prior, default_prior
from ..mcmc.sampling import NotConvergedWarning, sample_posterior
from ..scene.simulate import simulate_room
from ..sensor.parameters import IDENTIFIABLE_NAMES, SensorParams, to_identifiable
from .executors import executor

__all__ = ["ROOMS", "LEVELS", "SCENE_FLOOR_MM", "SAMPLER", "SBC_DRAWS", "SBC_BINS", "SBC_ROOM",
           "THETA_NAMES", "fixed_scene", "noisy_data", "coverage_replication", "sbc_simulation",
           "prior_theta_cov", "expected_z_sd", "expected_coverage", "drawn_prior",
           "run_coverage", "run_sbc", "binomial_band", "summarize_coverage", "summarize_sbc"]

#: the two fixed scenes of the coverage study
ROOMS = {
    "small": {"range_mm": 1000.0, "sigma_px": 0.5, "approx_error": 0.01},
    "large": {"range_mm": 5000.0, "sigma_px": 0.1, "approx_error": 0.05},
}
#: credible levels of the coverage curves
LEVELS = (0.5, 0.6, 0.7, 0.8, 0.9, 0.95, 0.99)
#: floor of the approximate points' standard deviation, mm
SCENE_FLOOR_MM = 1.0
#: sampler settings of the studies (smaller targets than the defaults, to fit the time)
SAMPLER = {"min_ess": 300, "n_samples": 400, "n_walkers": 32}
#: SBC: posterior draws per simulation (ranks take 100 values), bins of the histogram
SBC_DRAWS = 99
SBC_BINS = 10
SBC_ROOM = {"range_mm": 1000.0, "sigma_px": 0.5, "approx_error": 0.01}
THETA_NAMES = IDENTIFIABLE_NAMES


def fixed_scene(params, *, range_mm, n_points):
    """True laser points and noise-free pixels of the default room.

    Parameters
    ----------
    params : SensorParams
        True sensor.
    range_mm : float
        Room size, mm.
    n_points : int
        Laser points N.

    Returns
    -------
    points : ndarray, shape (N, 3)
        True points in frame C, mm (x, y on the walls, z on the true cone).
    pixels : ndarray, shape (N, 2)
        Their noise-free pixels, px.
    """
    ds = simulate_room(params, range_mm=range_mm, n_points=n_points, sigma_px=0.0,
                          approx_error=0.0, approx_model="gaussian", rng=0)
    return ds.points, ds.pixels_true


def noisy_data(points, pixels, *, sigma_px, approx_error, rng):
    """One noise replication: noisy pixels and approximate points.

    Returns
    -------
    pixels : ndarray, shape (N, 2)
    approx_points : ndarray, shape (N, 3)
    sigma_scene : ndarray, shape (N, 3)
        ``max(approx_error * |points|, SCENE_FLOOR_MM)``, mm: the standard
        deviation the approximate-point noise was drawn with.
    """
    sigma_scene = np.maximum(approx_error * np.abs(points), SCENE_FLOOR_MM)
    noisy = pixels + rng.normal(0.0, sigma_px, pixels.shape)
    approx = points + sigma_scene * rng.standard_normal(points.shape)
    return noisy, approx, sigma_scene


def _inside(samples, truth, levels):
    """Is ``truth`` inside each equal-tailed interval? samples (S, ...), truth (...)
    -> bool (L, ...)."""
    out = []
    for lev in levels:
        lo, hi = np.quantile(samples, [(1 - lev) / 2, (1 + lev) / 2], axis=0)
        out.append((truth >= lo) & (truth <= hi))
    return np.array(out)


def _inside_gauss(center, sd, truth, levels):
    z = np.abs(center - truth) / sd
    return np.array([z <= stats.norm.ppf((1 + lev) / 2) for lev in levels])


@functools.lru_cache(maxsize=4)
def prior_theta_cov(*, n=100_000, seed=0):
    """Prior covariance of the 7 identifiable parameters (Monte Carlo), shape (7, 7)."""
    return np.cov(to_identifiable(Prior().sample(n, rng=seed)), rowvar=False)


def expected_z_sd(post_cov, prior_cov):
    """Spread of the posterior z-scores when the truth is the prior mean (linear-Gaussian).

    With prior ``N(mu, P)`` and a Gaussian likelihood of information ``F``, the
    posterior covariance is ``S = (F + P^-1)^-1`` and the posterior mean minus
    ``mu`` is ``S F (mle - mu)``, of covariance ``S F S = S - S P^-1 S``. The
    z-score ``(mean_k - mu_k) / sqrt(S_kk)`` is therefore ``N(0, s_k^2)`` with
    ``s_k^2 = 1 - (S P^-1 S)_kk / S_kk``: 1 for a data-dominated parameter,
    less where the prior (jointly with the other parameters) still holds it.

    Parameters
    ----------
    post_cov, prior_cov : ndarray, shape (7, 7)

    Returns
    -------
    ndarray, shape (7,)
    """
    S = np.asarray(post_cov, float)
    M = S @ np.linalg.solve(prior_cov, S)
    return np.sqrt(np.clip(1.0 - np.diag(M) / np.diag(S), 1e-12, 1.0))


def expected_coverage(z_sd, levels=LEVELS):
    """Coverage of the level-``l`` interval ``mean +- z_l sd_post`` when z ~ N(0, z_sd^2).

    ``2 Phi(z_l / z_sd) - 1``: ``l`` for ``z_sd = 1``, more when the prior,
    centred on the truth, carries weight (see :func:`expected_z_sd`).

    Parameters
    ----------
    z_sd : ndarray, shape (...)

    Returns
    -------
    ndarray, shape (L, ...)
    """
    s = np.clip(np.asarray(z_sd, float), 1e-12, None)
    return np.array([2 * stats.norm.cdf(stats.norm.ppf((1 + lev) / 2) / s) - 1
                     for lev in levels])


def _nse(mean, cov, truth):
    d = mean - truth
    return np.einsum("ni,ni->n", d, np.linalg.solve(cov, d[..., None])[..., 0])


def drawn_prior(truth, rng):
    """Default-width normal priors whose centres are drawn around the truth.

    A user's design values are themselves a measurement of the sensor, off by about the
    prior's sd. Drawing the centre per replication (``truth + sd * N(0, 1)``) makes the
    prior a correctly specified piece of evidence, so credible intervals should cover at
    their nominal level for every parameter, including the prior-dominated ones; with
    the centre fixed at the truth they over-cover (``expected_z_sd``).
    """
    out = {}
    for name, dist in default_prior().items():
        sd = float(dist.std())
        out[name] = stats.norm(getattr(truth, name) + sd * rng.standard_normal(), sd)
    return out


def coverage_replication(room, n_points, seed, *, sampler=None, prior_centre="drawn"):
    """One noise replication of a fixed scene, summarised.

    Parameters
    ----------
    room : dict
        ``range_mm``, ``sigma_px``, ``approx_error`` (one of :data:`ROOMS`).
    n_points : int
        Laser points N.
    seed : int or numpy.random.SeedSequence
        Randomness of this replication (noise and sampler).
    sampler : dict, optional
        Keyword arguments of :func:`bayescal.sample_posterior` (default :data:`SAMPLER`).
    prior_centre : {"drawn", "truth"}
        ``"drawn"`` (default): priors centred on a draw around the truth
        (:func:`drawn_prior`), nominal coverage expected for every parameter;
        ``"truth"``: the default priors, centred on the truth (the paper's sensor),
        coverage expected per :func:`expected_coverage`.

    Returns
    -------
    dict
        ``theta_in`` (L, 7) and ``theta_in_map`` (L, 7) booleans (MCMC and
        Laplace intervals hold the truth, levels :data:`LEVELS`);
        ``sd_ratio`` (7,) posterior sd / prior sd; ``z_sd_expected`` (7,)
        (:func:`expected_z_sd`) and ``theta_expected`` (L, 7) the z-score spread
        and coverage expected with the truth at the prior mean; ``point_frac``
        (L,) and ``point_frac_map`` (L,) fractions of the 3N point coordinates
        covered; ``nse`` (N,) and ``nse_map`` (N,) normalised squared errors;
        ``z`` (7,) posterior z-scores ``(mean - truth) / sd``; ``converged``,
        ``max_tau``, ``seconds``.
    """
    sampler = dict(SAMPLER if sampler is None else sampler)
    rng = np.random.default_rng(seed)
    truth = SensorParams.paper()
    points, pixels = fixed_scene(truth, range_mm=room["range_mm"], n_points=n_points)
    pix, approx, s_scene = noisy_data(points, pixels, sigma_px=room["sigma_px"],
                                      approx_error=room["approx_error"], rng=rng)
    if prior_centre not in ("drawn", "truth"):
        raise InvalidValueError(f"prior_centre must be 'drawn' or 'truth', got {prior_centre!r}")
    prior = drawn_prior(truth, rng) if prior_centre == "drawn" else None
    t0 = time.perf_counter()
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", NotConvergedWarning)
        post = sample_posterior(pix, approx, sigma_px=room["sigma_px"], sigma_scene=s_scene,
                                   prior=prior, rng=rng, progress=False, **sampler)
    seconds = time.perf_counter() - t0
    theta_true = to_identifiable(truth.to_array())
    ts = post.theta_samples
    pcov = prior_theta_cov()
    ratio = ts.std(axis=0, ddof=1) / np.sqrt(np.diag(pcov))
    zsd = (np.ones(7) if prior_centre == "drawn"
           else expected_z_sd(np.cov(ts, rowvar=False), pcov))
    theta_map = to_identifiable(post.map_params)
    sd_map = np.sqrt(np.diag(post.laplace_cov7))
    pmap_sd = np.sqrt(np.einsum("nii->ni", post.map_point_covariance))
    return {
        "theta_in": _inside(ts, theta_true, LEVELS),
        "sd_ratio": ratio, "z_sd_expected": zsd, "theta_expected": expected_coverage(zsd),
        "theta_in_map": _inside_gauss(theta_map, sd_map, theta_true, LEVELS),
        "point_frac": _inside(post.point_samples, points, LEVELS).mean(axis=(1, 2)),
        "point_frac_map": _inside_gauss(post.map_points, pmap_sd, points, LEVELS)
        .mean(axis=(1, 2)),
        "nse": _nse(post.point_mean, post.point_covariance(), points),
        "nse_map": _nse(post.map_points, post.map_point_covariance, points),
        "z": (ts.mean(axis=0) - theta_true) / ts.std(axis=0, ddof=1),
        "z_map": (theta_map - theta_true) / sd_map,
        "converged": bool(post.converged), "max_tau": float(np.max(post.tau)),
        "seconds": seconds,
    }


def sbc_simulation(seed, *, n_points=40, room=None, sampler=None):
    """One simulation-based-calibration draw: truth from the prior, data, ranks.

    Parameters
    ----------
    seed : int or numpy.random.SeedSequence
    n_points : int, optional
        Laser points N (the walls are fixed; the points' x, y are where the
        cone meets them, z on the true cone).
    room : dict, optional
        Default :data:`SBC_ROOM`.
    sampler : dict, optional
        Keyword arguments of :func:`bayescal.sample_posterior`; ``n_samples``
        is forced to :data:`SBC_DRAWS`.

    Returns
    -------
    dict
        ``ranks`` (8,) int in 0..99: number of posterior draws below the truth
        for the 7 identifiable parameters then phi; ``converged``; ``seconds``.
    """
    room = SBC_ROOM if room is None else room
    sampler = dict(SAMPLER if sampler is None else sampler)
    sampler["n_samples"] = SBC_DRAWS
    rng = np.random.default_rng(seed)
    truth_a = Prior().sample(rng=rng)
    truth = SensorParams.from_array(truth_a)
    points, pixels = fixed_scene(truth, range_mm=room["range_mm"], n_points=n_points)
    pix, approx, s_scene = noisy_data(points, pixels, sigma_px=room["sigma_px"],
                                      approx_error=room["approx_error"], rng=rng)
    t0 = time.perf_counter()
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", NotConvergedWarning)
        post = sample_posterior(pix, approx, sigma_px=room["sigma_px"], sigma_scene=s_scene,
                                   rng=rng, progress=False, **sampler)
    draws = np.column_stack([post.theta_samples, post.param_samples[:, 1]])
    true8 = np.append(to_identifiable(truth_a), truth_a[1])
    return {"ranks": (draws < true8).sum(axis=0), "converged": bool(post.converged),
            "seconds": time.perf_counter() - t0}


def _pool_map(fn, args, workers, scheduler=None):
    with executor(workers=workers, scheduler=scheduler) as ex:
        return [f.result() for f in [ex.submit(fn, *a) for a in args]]


def run_coverage(room, *, n_reps, n_points, seed, workers=2, sampler=None, scheduler=None):
    """Run :func:`coverage_replication` ``n_reps`` times (independent seeds); list of dicts."""
    seeds = np.random.SeedSequence(seed).spawn(n_reps)
    args = [(room, n_points, s, sampler) for s in seeds]
    return _pool_map(_coverage_star, args, workers, scheduler)


def _coverage_star(room, n_points, seed, sampler):
    return coverage_replication(room, n_points, seed, sampler=sampler)


def run_sbc(*, n_sims, n_points, seed, workers=2, sampler=None, scheduler=None):
    """Run :func:`sbc_simulation` ``n_sims`` times; ranks (n_sims, 8) and flags."""
    seeds = np.random.SeedSequence(seed).spawn(n_sims)
    out = _pool_map(_sbc_star, [(s, n_points, sampler) for s in seeds], workers, scheduler)
    return {"ranks": np.array([o["ranks"] for o in out]),
            "converged": np.array([o["converged"] for o in out]),
            "seconds": np.array([o["seconds"] for o in out])}


def _sbc_star(seed, n_points, sampler):
    return sbc_simulation(seed, n_points=n_points, sampler=sampler)


def binomial_band(m, level, *, alpha=0.01):
    """Central ``1 - alpha`` band of the covered fraction over ``m`` independent intervals.

    Returns
    -------
    (lo, hi) : tuple of float
        Fractions: ``Binomial(m, level)`` quantiles ``alpha/2`` and ``1 - alpha/2``
        divided by ``m``.
    """
    d = stats.binom(m, level)
    return float(d.ppf(alpha / 2) / m), float(d.ppf(1 - alpha / 2) / m)


def summarize_coverage(reps):
    """Aggregate replications into coverage curves and chi-square(3) checks.

    Returns
    -------
    dict
        ``levels``; ``theta`` / ``theta_map`` (L, 7) empirical coverage;
        ``theta_expected`` (L, 7) its expectation with the truth at the prior
        mean, ``sd_ratio`` (7,) mean posterior sd / prior sd;
        ``points`` / ``points_map`` (L,) pooled coverage and ``points_se`` (L,)
        its standard error from the spread between replications (points of one
        replication are dependent); ``nse_mean`` and its ``nse_se``;
        ``nse_ks_p``: K-S p-value of one point per replication (point index
        ``m mod N``, independent across replications) against chi-square(3);
        same with ``_map``; ``z_mean``, ``z_sd`` per parameter;
        ``band90``, ``band95`` the 99 % binomial bands; ``n_converged``.
    """
    m = len(reps)
    out = {"levels": list(LEVELS), "m": m}
    for key in ("", "_map"):
        th = np.array([r["theta_in" + key] for r in reps])            # (M, L, 7)
        out["theta" + key] = th.mean(axis=0)
        pf = np.array([r["point_frac" + key] for r in reps])          # (M, L)
        out["points" + key] = pf.mean(axis=0)
        out["points_se" + key] = pf.std(axis=0, ddof=1) / np.sqrt(m)
        nse = np.array([r["nse" + key] for r in reps])                # (M, N)
        per_rep = nse.mean(axis=1)
        out["nse_mean" + key] = float(per_rep.mean())
        out["nse_se" + key] = float(per_rep.std(ddof=1) / np.sqrt(m))
        one = nse[np.arange(m), np.arange(m) % nse.shape[1]]
        out["nse_ks_p" + key] = float(stats.kstest(one, stats.chi2(3).cdf).pvalue)
        out["nse_pooled" + key] = nse.ravel()
        z = np.array([r["z" + key] for r in reps])
        out["z_mean" + key] = z.mean(axis=0)
        out["z_sd" + key] = z.std(axis=0, ddof=1)
    out["theta_expected"] = np.mean([r["theta_expected"] for r in reps], axis=0)
    out["sd_ratio"] = np.mean([r["sd_ratio"] for r in reps], axis=0)
    out["z_sd_expected"] = np.mean([r["z_sd_expected"] for r in reps], axis=0)
    out["band90"] = binomial_band(m, 0.9)
    out["band95"] = binomial_band(m, 0.95)
    out["n_converged"] = int(sum(r["converged"] for r in reps))
    out["max_tau"] = float(max(r["max_tau"] for r in reps))
    out["seconds_mean"] = float(np.mean([r["seconds"] for r in reps]))
    return out


def summarize_sbc(ranks, *, n_bins=SBC_BINS, n_draws=SBC_DRAWS):
    """Histogram the SBC ranks and compute chi-square(n_bins - 1) statistics.

    Parameters
    ----------
    ranks : ndarray of int, shape (S, P)
        Ranks in ``0..n_draws``.

    Returns
    -------
    counts : ndarray, shape (P, n_bins)
    chi2 : ndarray, shape (P,)
    p : ndarray, shape (P,)
        Upper-tail p-values of chi-square(n_bins - 1).
    """
    ranks = np.asarray(ranks)
    n_vals = n_draws + 1
    if n_vals % n_bins:
        raise InvalidValueError(f"n_draws + 1 = {n_vals} must be a multiple of n_bins = {n_bins}")
    b = ranks // (n_vals // n_bins)
    counts = np.stack([np.bincount(b[:, k], minlength=n_bins) for k in range(ranks.shape[1])])
    e = len(ranks) / n_bins
    chi2 = ((counts - e) ** 2 / e).sum(axis=1)
    return counts, chi2, stats.chi2(n_bins - 1).sf(chi2)


# -- figures and output ---------------------------------------------------------
