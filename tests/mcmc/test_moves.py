"""Every emcee move the sampler uses recovers N(0, I) in 7 dimensions (emcee's _test_normal).

Tolerances: the chain's mean and variance of each coordinate are compared with 0 and 1 using
effective sample sizes from emcee's integrated autocorrelation time (of x for the mean, of x^2
for the variance): a z-bound of 4 on each of the 14 statistics gives a false-failure rate of
about 14 x 6.3e-5 = 9e-4 per move (approximate: tau is itself estimated). The K-S test pools
the 7 coordinates of draws thinned by 3 tau (independent under N(0, I)) and uses p > 1e-4.
"""

import emcee
import numpy as np
import pytest
from scipy import stats

from bayescal.mcmc.moves import HMCMove, IndependenceMove
from bayescal.mcmc.sampling import default_moves
from bayescal.mcmc.steps import de_move

NDIM = 7
N_WALKERS = 32
# a deliberately wrong proposal: shifted mean, unequal variances, a correlation
BAD_MEAN = np.full(NDIM, 0.3)
BAD_COV = np.diag(np.linspace(0.6, 2.0, NDIM))
BAD_COV[0, 1] = BAD_COV[1, 0] = 0.3
Z = 4.0


def _log_normal(x):
    return -0.5 * np.sum(x * x, axis=-1)


def _normal_value_and_grad(x):
    return _log_normal(x), -np.asarray(x)


def _run(moves, n_steps, seed, n_walkers=N_WALKERS):
    rs = np.random.RandomState(seed)
    sampler = emcee.EnsembleSampler(n_walkers, NDIM, _log_normal, vectorize=True, moves=moves)
    sampler.random_state = rs.get_state()
    sampler.run_mcmc(rs.standard_normal((n_walkers, NDIM)), n_steps, progress=False)
    return sampler


MOVES = {
    "independence (mismatched proposal)": lambda: [IndependenceMove(BAD_MEAN, BAD_COV)],
    "DEMove": lambda: [emcee.moves.DEMove()],
    "StretchMove": lambda: [emcee.moves.StretchMove()],
    "default mixture (tuned)": lambda: default_moves(BAD_MEAN, BAD_COV),
    "default mixture (untuned)": lambda: default_moves(),
    "default mixture, 90 % independence": lambda: default_moves(BAD_MEAN, BAD_COV,
                                                                imh_weight=0.9),
    "HMC (mismatched mass matrix)": lambda: [HMCMove(_normal_value_and_grad, BAD_COV,
                                                     step_size=0.4, n_steps=5)],
    "default mixture with HMC": lambda: default_moves(BAD_MEAN, BAD_COV,
                                                      value_and_grad=_normal_value_and_grad,
                                                      step_size=0.4),
}


@pytest.mark.parametrize("name", list(MOVES) + ["DEMove, 9 walkers", "default, 9 walkers"])
def test_move_recovers_a_standard_normal(name):
    if name.endswith("9 walkers"):     # fewer than 2 ndim: the sampler's default_walkers rule
        moves = [de_move()] if name.startswith("DE") else default_moves(BAD_MEAN, BAD_COV)
        sampler = _run(moves, 4000, seed=11, n_walkers=NDIM + 2)
    else:
        sampler = _run(MOVES[name](), 2000, seed=11)
    chain = sampler.get_chain(discard=400)                  # (steps, walkers, 7)
    # HMC can be antithetic (tau < 1, even a negative estimate): count such draws as
    # independent (tau = 1), which only makes the bounds below more conservative
    tau = np.maximum(emcee.autocorr.integrated_time(chain, tol=0, quiet=True), 1.0)
    tau2 = np.maximum(emcee.autocorr.integrated_time(chain**2, tol=0, quiet=True), 1.0)
    n = chain.shape[0] * chain.shape[1]
    ess, ess2 = n / tau, n / tau2
    assert np.min(ess) > 400, f"{name}: too few effective samples ({np.min(ess):.0f})"
    x = chain.reshape(-1, NDIM)
    mean, var = x.mean(axis=0), x.var(axis=0)
    assert np.all(np.abs(mean) < Z / np.sqrt(ess)), f"{name}: mean {mean}"
    # Var(sample variance) of N(0, 1) draws = 2 / ESS(x^2)
    assert np.all(np.abs(var - 1.0) < Z * np.sqrt(2.0 / ess2)), f"{name}: variance {var}"
    thin = int(np.ceil(3 * np.max(tau)))
    draws = chain[::thin].ravel()
    assert draws.size > 1000
    assert stats.kstest(draws, stats.norm.cdf).pvalue > 1e-4


def test_desnooker_move_of_emcee_3_1_6_samples_the_wrong_distribution():
    """Fact 6 (docs/model.md, "Measured facts"): emcee 3.1.6's DESnookerMove scales the
    snooker direction by 1 / sqrt(|delta|) where 1 / |delta| (a unit vector) is meant, so the
    chain does not
    target N(0, I): its variances come out at 0.6-0.75. bayescal never uses it.

    This asserts what is true of the installed emcee. The pooled variance of 7 coordinates
    has sd ~0.02 here (ESS(x^2) ~ 700 per coordinate), so the 0.85 bound is ~10 sd above
    today's value and ~7 sd below a correct sampler's 1.0: if this test fails, the installed
    emcee has fixed the move (upstream fixed it after 3.1.6); update fact 6 in docs/model.md
    ("Measured facts") and bayescal.mcmc.sampling.default_moves' note, then turn this into a
    recovery test.
    """
    sampler = _run([emcee.moves.DESnookerMove()], 1000, seed=3)
    chain = sampler.get_chain(discard=300)
    var = chain.reshape(-1, NDIM).var(axis=0)
    assert np.mean(var) < 0.85, (
        f"DESnookerMove now gives variance {np.mean(var):.3f} on N(0, I) with emcee "
        f"{emcee.__version__}: the upstream fix has landed")
    assert np.mean(var) > 0.4                     # it is wrong, not broken beyond use


def test_independence_move_proposal_density_is_the_multivariate_t():
    move = IndependenceMove(BAD_MEAN, BAD_COV, df=5.0, scale=1.2)
    x = np.random.default_rng(0).standard_normal((5, NDIM))
    ref = stats.multivariate_t(loc=BAD_MEAN, shape=1.2**2 * BAD_COV, df=5.0).logpdf(x)
    np.testing.assert_allclose(move.log_q(x) + move.log_norm(), ref, rtol=1e-12)


def test_independence_move_draws_follow_its_proposal():
    """Draws of IndependenceMove.sample follow a t_5 (its 4th moment is infinite, so the
    spread is checked through the median of |x|). Standard errors: mean sqrt(5/3 / n); the
    sample median of |x| sqrt(1/4) / (sqrt(n) f(m)), f = 2 t_5 pdf. Bounds of 4.5 standard
    errors on 6 statistics: false-failure rate ~4e-5."""
    n = 200_000
    move = IndependenceMove(np.zeros(3), np.eye(3), df=5.0, scale=1.0)
    x = move.sample(n, np.random.RandomState(4))
    assert x.shape == (n, 3)
    np.testing.assert_allclose(np.mean(x, axis=0), 0.0, atol=4.5 * np.sqrt(5.0 / 3.0 / n))
    m = stats.t(5).ppf(0.75)
    se_median = 0.5 / (np.sqrt(n) * 2 * stats.t(5).pdf(m))
    np.testing.assert_allclose(np.median(np.abs(x), axis=0), m, rtol=0, atol=4.5 * se_median)


def test_independence_move_rejects_bad_arguments():
    with pytest.raises(ValueError, match=r"cov must have shape \(2, 2\)"):
        IndependenceMove(np.zeros(2), np.eye(3))
    with pytest.raises(ValueError, match="df must be positive"):
        IndependenceMove(np.zeros(2), np.eye(2), df=0.0)
    with pytest.raises(ValueError, match="symmetric positive definite"):
        IndependenceMove(np.zeros(2), np.array([[1.0, 2.0], [2.0, 1.0]]))


BANANA_B = 0.5


def _banana(x):
    """N(0, I) pushed through x2 -> x2 + b (x1^2 - 1): a curved ridge in (x1, x2).
    The map has unit Jacobian, so log p(x) = log N(y) with y2 = x2 - b (x1^2 - 1)."""
    x = np.asarray(x, float)
    y = x.copy()
    y[..., 1] = x[..., 1] - BANANA_B * (x[..., 0] ** 2 - 1)
    g = -y
    g[..., 0] = -y[..., 0] + y[..., 1] * 2 * BANANA_B * x[..., 0]
    return -0.5 * np.sum(y * y, axis=-1), g


def test_hmc_move_samples_a_banana():
    """HMC on a curved ridge (variance of x2 is 1 + 2 b^2 = 1.5, its mean 0): the chain's
    de-curved coordinates y must be N(0, I). Same tolerances as above (z-bound 4 on the 14
    means and variances, ~1e-3 false failures; K-S p > 1e-4 on thinned draws)."""
    rs = np.random.RandomState(5)
    move = HMCMove(_banana, np.eye(NDIM), step_size=0.3, n_steps=8)
    sampler = emcee.EnsembleSampler(N_WALKERS, NDIM, lambda x: _banana(x)[0], vectorize=True,
                                    moves=[move])
    sampler.random_state = rs.get_state()
    sampler.run_mcmc(rs.standard_normal((N_WALKERS, NDIM)), 1500, progress=False)
    x = sampler.get_chain(discard=300)
    y = x.copy()
    y[..., 1] = x[..., 1] - BANANA_B * (x[..., 0] ** 2 - 1)
    tau = np.maximum(emcee.autocorr.integrated_time(y, tol=0, quiet=True), 1.0)
    tau2 = np.maximum(emcee.autocorr.integrated_time(y**2, tol=0, quiet=True), 1.0)
    n = y.shape[0] * y.shape[1]
    flat = y.reshape(-1, NDIM)
    assert np.all(np.abs(flat.mean(axis=0)) < Z / np.sqrt(n / tau)), flat.mean(axis=0)
    assert np.all(np.abs(flat.var(axis=0) - 1) < Z * np.sqrt(2 * tau2 / n)), flat.var(axis=0)
    assert move.acceptance > 0.5
    thin = int(np.ceil(3 * np.max(tau)))
    assert stats.kstest(y[::thin, :, :2].ravel(), stats.norm.cdf).pvalue > 1e-4


def test_hmc_move_rejects_bad_arguments():
    with pytest.raises(ValueError, match="symmetric positive definite"):
        HMCMove(_normal_value_and_grad, np.array([[1.0, 2.0], [2.0, 1.0]]))
    with pytest.raises(ValueError, match="step_size must be positive"):
        HMCMove(_normal_value_and_grad, np.eye(2), step_size=0.0)
    with pytest.raises(ValueError, match="n_steps must be a positive integer"):
        HMCMove(_normal_value_and_grad, np.eye(2), n_steps=0)


def test_thinning_keeps_every_walker_evenly():
    # 100 kept steps x 18 walkers thinned to 1000 draws (~1.8 states per draw): each
    # walker gives 55-56 draws spread over its whole run. The step-major order kept the
    # same half of the walkers over long stretches (their means then scattered like an ESS
    # of about half the chain's).
    from bayescal.mcmc.collapsed import _thin

    steps, walkers, burn = 120, 18, 20
    chain = np.zeros((steps, walkers, 2))
    chain[..., 0] = np.arange(walkers)[None, :]              # which walker
    chain[..., 1] = np.arange(steps)[:, None]                # which step
    out = _thin(chain, burn, 1000)
    assert out.shape == (1000, 2)
    counts = np.bincount(out[:, 0].astype(int), minlength=walkers)
    assert counts.min() >= 55 and counts.max() <= 56, counts
    for w in range(walkers):
        s = out[out[:, 0] == w, 1]
        assert s.min() <= burn + 2 and s.max() >= steps - 3, (w, s.min(), s.max())
    # a chain shorter than its burn-in returns the last state of each walker
    np.testing.assert_array_equal(_thin(chain[:10], burn, 5)[:, 1], 9)
