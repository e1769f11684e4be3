"""The sampler never crashes on its own tuning: a degenerate start or a collapsed ensemble
gives a regularized proposal, or a NotConvergedError that says what is wrong."""

import numpy as np
import pytest

import bayescal as bc
from bayescal.likelihood.points import LaserLikelihood
from bayescal.mcmc.collapsed import sample_collapsed
from bayescal.mcmc.ensemble import spd_covariance
from bayescal.mcmc.steps import tune_proposal


def test_usable_covariance_is_returned_as_it_is():
    cov = np.array([[2.0, 0.3], [0.3, 1.0]])
    assert spd_covariance(cov) is cov


def test_singular_covariance_is_regularized():
    v = np.array([1.0, 2.0, -1.0])
    cov = np.outer(v, v)                       # rank one: a walker line
    out = spd_covariance(cov)
    np.linalg.cholesky(out)                    # drawable
    e = np.linalg.eigvalsh(out)
    assert e.min() == pytest.approx(1e-8 * e.max(), rel=1e-6)
    np.testing.assert_allclose(out @ v, cov @ v, rtol=1e-6)   # the spread it had is kept


def test_unusable_estimate_falls_back_or_says_why():
    fb = np.eye(2)
    assert spd_covariance(np.full((2, 2), np.nan), fb) is fb
    assert spd_covariance(-np.eye(2), fb) is fb
    with pytest.raises(bc.NotConvergedError, match="not finite"):
        spd_covariance(np.array([[np.nan, 0.0], [0.0, 1.0]]))
    with pytest.raises(bc.NotConvergedError, match="collapsed"):
        spd_covariance(np.zeros((3, 3)))


@pytest.fixture(scope="module")
def small_fit():
    ds = bc.simulate_room(range_mm=1000, n_points=60, sigma_px=0.3, approx_error=0.02,
                          approx_model="gaussian", rng=4)
    lik = LaserLikelihood(ds.pixels, ds.approx_points, sigma_px=0.3,
                          sigma_scene=ds.sigma_scene)
    res = bc.calibrate_simultaneous(ds.pixels, ds.approx_points, sigma_px=0.3,
                                    sigma_scene=ds.sigma_scene)
    return lik, res.extras["map"]


def test_singular_laplace_start_still_samples(small_fit):
    """A Laplace covariance with a lost direction (a fit at a bound) used to stop the
    sampler with emcee's 'cov must be symmetric positive definite'."""
    lik, sol = small_fit
    cov = sol.cov_theta.copy()
    cov[5, :] = cov[:, 5] = 0.0                 # h's row and column lost
    run = sample_collapsed(lik, bc.Prior(), sol.theta, cov, sol.q, rng=0, min_ess=100,
                           n_samples=50, max_steps=300, progress=False)
    assert np.all(np.isfinite(run["psi"])) and np.ptp(run["psi"][:, 5]) > 0


def test_non_finite_laplace_start_is_a_clear_error(small_fit):
    lik, sol = small_fit
    cov = np.full_like(sol.cov_theta, np.nan)
    with pytest.raises(bc.NotConvergedError, match="Laplace covariance at the least-squares"):
        sample_collapsed(lik, bc.Prior(), sol.theta, cov, sol.q, rng=0, min_ess=100,
                         n_samples=50, progress=False)


def test_collapsed_ensemble_is_spread_again():
    """Forced collapse: every walker on one point (emcee itself refuses such a start)."""
    def target(x):
        return -0.5 * np.sum(np.atleast_2d(x) ** 2, axis=1)

    out = tune_proposal(target, np.full((8, 3), 0.5), np.zeros(3), np.eye(3),
                        np.random.default_rng(0), n_steps=30, n_rounds=2)
    np.linalg.cholesky(out["cov"])
    assert np.ptp(np.asarray(out["state"].coords), axis=0).min() > 0


def test_collapse_with_no_way_out_is_a_clear_error():
    """A target finite at one point only: no spread helps, and the sampler says so."""
    def target(x):
        x = np.atleast_2d(x)
        return np.where(np.all(x == 0.0, axis=1), 0.0, -np.inf)

    with pytest.raises(bc.NotConvergedError, match="collapsed onto one point"):
        tune_proposal(target, np.zeros((8, 3)), np.zeros(3), np.eye(3),
                      np.random.default_rng(0), n_steps=12, n_rounds=2)
