"""Statistical validation of the Bayesian posterior (docs/validation.md, rungs 3 and 4).

* Rung 3: the collapsed sampler (:func:`bayescal.sample_posterior`) against a
  long brute-force emcee run over the full joint (:func:`bayescal.mcmc.sampling.sample_joint`,
  same likelihood ``LaserLikelihood.log_joint``, same priors incl. the Jeffreys
  point prior): two-sample K-S tests on thinned draws.
* Rung 4: coverage of credible intervals on fixed scenes over M = 200 noise
  replications, chi-square(3) of the points' normalised squared errors, and
  simulation-based calibration with truths drawn from the prior.

The replication code lives in :mod:`bayescal.validation.coverage` so
the test and the study run the same experiment. Every slow test is marked
``@pytest.mark.slow`` (``make test-slow``); the fast ``*_smoke`` tests run the
same pipelines on tiny settings in a few seconds each.
"""

import warnings

import numpy as np
import pytest
from scipy import stats

import bayescal as bc
from bayescal.mcmc.sampling import sample_joint
from bayescal.sensor.laser import cone_point_theta
from bayescal.validation import coverage as cov

WORKERS = 2


# -- rung 3: collapsed sampler against brute force -----------------------------------
def _small_problem(n_points, seed):
    """N points of the 1000 mm room, 0.5 px, approximate points at 2 % (floored 1 mm)."""
    points, pixels = cov.fixed_scene(bc.SensorParams.paper(), range_mm=1000.0,
                                     n_points=n_points)
    pix, approx, s = cov.noisy_data(points, pixels, sigma_px=0.5, approx_error=0.02,
                                    rng=np.random.default_rng(seed))
    return pix, approx, s


def _thinned_joint(run, lag):
    """Draws of theta (S, 7) and points (S, N, 3) from the joint chain's second half,
    every ``lag`` steps, all walkers."""
    chain = run["chain"]
    kept = chain[len(chain) // 2::lag]                       # (steps', walkers, 7 + 2N)
    x = kept.reshape(-1, chain.shape[-1])
    theta, q = x[:, :7], x[:, 7:].reshape(len(x), -1, 2)
    return theta, cone_point_theta(theta[:, None, :], q)


def _collapsed(pix, approx, s, *, rng, min_ess, n_samples):
    with warnings.catch_warnings():
        warnings.simplefilter("error", bc.NotConvergedWarning)
        return bc.sample_posterior(pix, approx, sigma_px=0.5, sigma_scene=s, rng=rng,
                                   progress=False, min_ess=min_ess, n_samples=n_samples)


@pytest.mark.slow
def test_collapsed_matches_brute_force():
    # N = 6 points, 1000 mm room, 0.5 px, 2 % approximate points: the pixels still move
    # u0, v0 and beta well inside their priors (posterior sd / prior sd 0.02, 0.03, 0.3),
    # xi, h, gamma are partly prior-held (0.6-0.9), so the comparison exercises both the
    # per-point Laplace collapse (q moves with theta over a broad theta posterior) and the
    # phi-integrated prior. The joint has 7 + 12 = 19 dimensions, 40 walkers; its tau
    # was ~230-270 steps: 20000 steps, second half thinned every 2 tau (lag-2tau
    # autocorrelation ~0.02) gives ~700 nearly independent draws.
    pix, approx, s = _small_problem(6, seed=5)
    run = sample_joint(pix, approx, sigma_px=0.5, sigma_scene=s, rng=11, n_steps=20000)
    lag = int(np.ceil(2 * np.max(run["tau"])))
    assert 20000 // 2 > 25 * np.max(run["tau"]), f"joint chain too short: tau {run['tau']}"
    tj, pj = _thinned_joint(run, lag)
    # collapsed: ESS >= 2000, 1000 draws evenly thinned (<= ESS / 2: nearly independent)
    post = _collapsed(pix, approx, s, rng=12, min_ess=2000, n_samples=1000)
    tc, pc = post.theta_samples, post.point_samples
    pairs = [(f"theta[{k}]", tc[:, k], tj[:, k]) for k in range(7)]
    for i in (0, 3):
        for a, name in enumerate("xyz"):
            pairs.append((f"point {i} {name}", pc[:, i, a], pj[:, i, a]))
    # 13 two-sample K-S tests, Bonferroni: family false-failure rate 0.001 for independent
    # draws (fails once in 1000 runs if both samplers are right)
    alpha = 1e-3 / len(pairs)
    pvals = {name: stats.ks_2samp(a, b).pvalue for name, a, b in pairs}
    bad = {k: p for k, p in pvals.items() if p < alpha}
    assert not bad, f"collapsed and brute-force marginals differ (p < {alpha:.1e}): {bad}"


@pytest.mark.slow
def test_a_chain_stuck_in_a_tail_is_rerun_with_hmc():
    # rung 3's collapsed posterior with sampler seed 12: without HMC (tuning's independence
    # acceptance 0.27-0.40, "near-Gaussian") the chain stuck in a tail of the prior-held
    # xi, gamma, h (tau 9 -> 47) and its time budget stopped it; the rerun with HMC from its
    # last state converges (tau 11, ~16 s of CPU). Deterministic for the seed: no tolerance.
    pix, approx, s = _small_problem(6, seed=5)
    post = _collapsed(pix, approx, s, rng=12, min_ess=2000, n_samples=1000)
    rerun = post.diagnostics.extra["rerun_with_hmc"]
    assert post.converged and rerun is not None, post.diagnostics.extra
    assert rerun["max_tau"] > 2 * np.max(post.tau), (rerun, post.tau)
    assert "HMCMove" in post.diagnostics.moves


def test_collapsed_matches_brute_force_smoke():
    # 4 points, short chains: the two samplers' theta means agree within one posterior
    # sd for u0, v0, beta (the data-dominated ones). The joint starts at the MAP and keeps
    # ~600 x 32 / 250 ~ 75 effective draws, so its mean's Monte-Carlo error is ~0.12 sd: a
    # 1-sd gap is a > 8-sigma event for correct samplers, i.e. a real disagreement.
    pix, approx, s = _small_problem(4, seed=6)
    run = sample_joint(pix, approx, sigma_px=0.5, sigma_scene=s, rng=3, n_steps=1200)
    tj, pj = _thinned_joint(run, 1)
    assert run["chain"].shape == (1200, 2 * (7 + 8) + 2, 7 + 8)
    assert pj.shape[1:] == (4, 3)
    post = _collapsed(pix, approx, s, rng=4, min_ess=200, n_samples=200)
    tc = post.theta_samples
    sd = tc.std(axis=0, ddof=1)
    for k in (3, 4, 6):
        assert abs(tc[:, k].mean() - tj[:, k].mean()) < sd[k], bc.IDENTIFIABLE_NAMES[k]


# -- rung 4: coverage on fixed scenes ------------------------------------------------
N_REPS = 200
N_POINTS = 100


@pytest.mark.slow
# The large room is borderline today (docs/validation.md: xi, gamma, h covered 0.80-0.90 at
# the 90 % level in two check runs, with a ~0.3 sd bias shared by the MAP): this test may
# fail there, and that failure is the open problem, not a flaky tolerance.
@pytest.mark.parametrize("room", ["small", "large"])
def test_coverage_fixed_scene(room):
    reps = cov.run_coverage(cov.ROOMS[room], n_reps=N_REPS, n_points=N_POINTS,
                            seed=[2024, len(room)], workers=WORKERS)
    s = cov.summarize_coverage(reps)
    assert s["n_converged"] == N_REPS
    levels = list(cov.LEVELS)
    # 7 parameters x 2 levels binomial checks + 2 pooled point checks + NSE mean + NSE K-S
    # = 18 checks; Bonferroni at a family false-failure rate of 1 %: each at 0.01 / 18.
    # (The 99 % binomial band is each check's own 99 % band, 84-95 % and 90.5-98.5 % at M = 200;
    # the study reports against that one. 14 checks at 1 % each would fail ~1 run in 8.)
    #
    # The priors' centres are drawn around the truth in each replication
    # (cov.drawn_prior: the design values are themselves a measurement with the prior's
    # error), so every parameter, prior-dominated or not, should cover at its nominal
    # level: s["theta_expected"] is the nominal level. (With the centres fixed at the
    # truth, prior-dominated parameters over-cover by construction: see
    # cov.expected_z_sd and docs/validation.md.)
    alpha = 0.01 / 18
    z = stats.norm.ppf(1 - alpha / 2)
    fails = []
    for lev in (0.9, 0.95):
        j = levels.index(lev)
        for k, name in enumerate(bc.IDENTIFIABLE_NAMES):
            c, e = s["theta"][j, k], s["theta_expected"][j, k]
            lo, hi = cov.binomial_band(N_REPS, e, alpha=alpha)
            if not lo <= c <= hi:
                fails.append(f"{name} {lev:.0%} interval covers {c:.3f}, expected {e:.3f} "
                             f"(band [{lo}, {hi}])")
        # pooled over 3N point coordinates: dependent within a replication, so the
        # standard error comes from the spread of the per-replication fractions
        c, se = s["points"][j], s["points_se"][j]
        if abs(c - lev) > z * se:
            fails.append(f"points {lev:.0%} cover {c:.3f} +- {se:.3f}")
    # normalised squared errors: mean 3 (per-replication means are independent), and one
    # point per replication (index m mod N: independent draws) against chi-square(3)
    if abs(s["nse_mean"] - 3.0) > z * s["nse_se"]:
        fails.append(f"NSE mean {s['nse_mean']:.3f} +- {s['nse_se']:.3f}, expected 3")
    if s["nse_ks_p"] < alpha:
        fails.append(f"NSE K-S against chi-square(3): p = {s['nse_ks_p']:.2e}")
    assert not fails, "; ".join(fails)


def test_coverage_replication_smoke():
    small = {"min_ess": 100, "n_samples": 100, "n_walkers": 32}
    r = cov.coverage_replication(cov.ROOMS["small"], 30, 7, sampler=small)
    L = len(cov.LEVELS)
    assert r["theta_in"].shape == r["theta_in_map"].shape == r["theta_expected"].shape == (L, 7)
    # expected coverage is never below the nominal level (prior weight only adds)
    assert np.all(r["theta_expected"] >= np.array(cov.LEVELS)[:, None] - 1e-12)
    assert r["point_frac"].shape == (L,) and np.all((r["point_frac"] >= 0)
                                                     & (r["point_frac"] <= 1))
    # coverage can only grow with the level
    assert np.all(np.diff(r["point_frac"]) >= 0) and np.all(np.diff(r["point_frac_map"]) >= 0)
    assert r["nse"].shape == (30,) and np.all(r["nse"] >= 0)
    # a calibrated posterior puts |z| > 4.5 on one of 7 parameters with probability
    # 7 x 6.8e-6 = 5e-5; larger z means a broken pipeline
    assert np.all(np.abs(r["z"]) < 4.5), r["z"]
    summ = cov.summarize_coverage([r, r])
    assert summ["theta"].shape == (L, 7) and summ["m"] == 2


def test_expected_coverage_limits():
    # z-scores N(0, 1): nominal; z_sd -> 0 (prior only): always covered
    e = cov.expected_coverage(np.array([1.0, 1e-9]))
    np.testing.assert_allclose(e[:, 0], cov.LEVELS, atol=1e-12)
    np.testing.assert_allclose(e[:, 1], 1.0, atol=1e-12)
    # z_sd = 0.8: the 90 % interval covers P(|Z| < 1.6449 / 0.8)
    np.testing.assert_allclose(cov.expected_coverage(0.8, [0.9]), [0.96023], atol=1e-5)


def test_expected_z_sd_one_dimensional():
    # 1-D: prior variance 4, data variance 1 -> posterior 0.8; z sd^2 = 1 - 0.8/4 = 0.8;
    # a flat-ish prior gives 1
    np.testing.assert_allclose(cov.expected_z_sd(np.diag([0.8] * 7), np.diag([4.0] * 7)),
                               np.sqrt(0.8), rtol=1e-12)
    np.testing.assert_allclose(cov.expected_z_sd(np.eye(7), 1e12 * np.eye(7)), 1.0,
                               rtol=1e-9)


def test_binomial_band_matches_design():
    # the validation ladder: M = 200, 90 % intervals cover 84-95 %, 95 % intervals 90.5-98.5 %
    np.testing.assert_allclose(cov.binomial_band(200, 0.9), (0.84, 0.95), atol=1e-12)
    np.testing.assert_allclose(cov.binomial_band(200, 0.95), (0.905, 0.985), atol=1e-12)


# -- rung 4: simulation-based calibration ---------------------------------------------
N_SIMS = 200


@pytest.mark.slow
def test_sbc_ranks_uniform():
    # truth from the prior, fixed walls, N = 40 points in the 1000 mm room (0.5 px, 1 %);
    # 99 draws per simulation (ranks 0..99), 10 bins of 10 ranks
    out = cov.run_sbc(n_sims=N_SIMS, n_points=40, seed=77, workers=WORKERS)
    counts, chi2, p = cov.summarize_sbc(out["ranks"])
    assert counts.sum(axis=1).tolist() == [N_SIMS] * 8
    # 8 chi-square(9) tests, Bonferroni at a family false-failure rate of 1 %: each below
    # the 1 - 0.01/8 quantile, 27.29 (the plain 21.67 is one test's 99 % quantile;
    # the study reports against it)
    limit = stats.chi2(cov.SBC_BINS - 1).ppf(1 - 0.01 / 8)
    names = list(bc.IDENTIFIABLE_NAMES) + ["phi"]
    bad = {n: round(float(c), 2) for n, c in zip(names, chi2, strict=True) if c > limit}
    assert not bad, f"SBC rank histograms not uniform (chi2(9) > {limit:.2f}): {bad}"


def test_sbc_smoke():
    small = {"min_ess": 100, "n_samples": 50, "n_walkers": 32}
    r = cov.sbc_simulation(3, n_points=30, sampler=small)
    assert r["ranks"].shape == (8,)
    assert np.all((r["ranks"] >= 0) & (r["ranks"] <= cov.SBC_DRAWS))


def test_summarize_sbc_statistic():
    # perfectly uniform ranks give chi2 = 0; all ranks in one bin give S (B - 1)
    uniform = np.tile(np.arange(100), 2)[:, None] * np.ones((1, 3), int)
    counts, chi2, p = cov.summarize_sbc(uniform)
    np.testing.assert_array_equal(counts, 20)
    np.testing.assert_allclose(chi2, 0.0, atol=1e-12)
    np.testing.assert_allclose(p, 1.0, atol=1e-12)
    lumped = np.full((200, 1), 5)
    _, chi2, _ = cov.summarize_sbc(lumped)
    np.testing.assert_allclose(chi2, 200 * 9, rtol=1e-12)
    with pytest.raises(ValueError, match="multiple of n_bins"):
        cov.summarize_sbc(uniform, n_bins=7)
