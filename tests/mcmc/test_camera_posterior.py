"""The camera posterior: converged by its rule, and agreeing with the least-squares Laplace
fit it starts from (the same noise model, near-Gaussian on simulated boards)."""

import numpy as np
import pytest

import bayescal as bc


@pytest.mark.slow
def test_posterior_agrees_with_least_squares():
    """Means within 0.25 sd and sds within 25 % of the Laplace ones: with ESS >= 300 the
    Monte Carlo error of a mean is ~0.06 sd and of an sd ~4 %, so these bands leave room
    for the Laplace approximation's own error (observed: 0.03 sd and 3 %)."""
    views, _ = bc.simulate_views(n_views=4, rng=21)
    lsq = bc.calibrate_camera(views, noise="per-view")
    post = bc.sample_camera_posterior(views, rng=0, lsq=lsq, noise="per-view", min_ess=300,
                                      tau_factor=30, n_tune=40)
    assert post.converged and post.diagnostics.converged
    assert post.method == "posterior" and post.samples.shape[1] == 5 + 4
    sd = np.sqrt(np.diag(lsq.covariance()))
    assert np.all(np.abs(post.k - lsq.k) / sd < 0.25), (post.k - lsq.k) / sd
    ratio = np.sqrt(np.diag(post.covariance())) / sd
    assert np.all(np.abs(ratio - 1) < 0.25), ratio
    assert post.covariance(noise=True).shape == (9, 9)
    assert "converged" in post.summary()


@pytest.mark.slow
def test_default_posterior_keeps_the_fit_centre_and_the_sandwich_spread():
    """The default (weighted fit, sandwich covariance): the chain samples the per-view
    model and its draws are adjusted to the least-squares covariance; the mean stays
    within 0.25 sd of the fit (Monte Carlo error ~0.06 sd at ESS 300)."""
    views, _ = bc.simulate_views(n_views=4, view_field=0.15, rng=22)
    lsq = bc.calibrate_camera(views)
    post = bc.sample_camera_posterior(views, rng=1, lsq=lsq, min_ess=300, tau_factor=30,
                                      n_tune=40)
    assert post.converged and post.diagnostics.extra["adjusted_to_least_squares"]
    sd = np.sqrt(np.diag(lsq.covariance()))
    assert np.all(np.abs(post.k - lsq.k) / sd < 0.25)
    np.testing.assert_allclose(post.covariance(), lsq.covariance(), rtol=1e-8, atol=1e-12)
    assert post.samples.shape[1] == 5 + 4 + 1 and post.tau == pytest.approx(lsq.tau)


def test_bad_run_options_fail_first():
    views, _ = bc.simulate_views(n_views=2, rng=0)
    with pytest.raises(ValueError, match="min_ess"):
        bc.sample_camera_posterior(views, min_ess=-1)


def test_laplace_proposal_is_exact_on_a_gaussian(rng):
    """One Newton step with the central-difference Hessian lands on the mode of a Gaussian
    log density and returns its covariance (exact for a quadratic, up to rounding)."""
    from bayescal.mcmc.camera import laplace_proposal

    d = 4
    A = rng.normal(size=(d, d))
    cov = A @ A.T + d * np.eye(d)
    mean = rng.normal(size=d)
    P = np.linalg.inv(cov)

    def logp(x):
        z = np.atleast_2d(x) - mean
        return -0.5 * np.einsum("ni,ij,nj->n", z, P, z)

    m, c = laplace_proposal(logp, mean + rng.normal(size=d), 2.0 * cov)
    np.testing.assert_allclose(m, mean, atol=1e-8)
    np.testing.assert_allclose(c, cov, rtol=1e-6)
    assert laplace_proposal(lambda x: -logp(x), mean, cov) is None     # not a maximum


def test_proposal_check_takes_an_odd_number_of_draws(rng):
    """The acceptance estimate pairs the draws; an odd count (n_walkers above 200) leaves
    the last one out, and on its own target the independence move accepts everything."""
    from bayescal.mcmc.camera import _imh_check
    from bayescal.mcmc.moves import IndependenceMove

    d, mean, cov = 3, np.zeros(3), np.eye(3)
    imh = IndependenceMove(mean, cov, scale=1.0, df=1e6)
    x, lp, acc = _imh_check(lambda x: imh.log_q(x), imh, np.random.RandomState(1), 201)
    assert x.shape == (201, d) and lp.shape == (201,) and acc == pytest.approx(1.0)


@pytest.mark.parametrize("fits, proposal", [(None, "Laplace at the mode"), (1.01, "tuned")])
def test_the_sampler_uses_the_laplace_proposal_where_it_fits(monkeypatch, fits, proposal):
    """Simulated views take the Laplace proposal at the mode; where its check fails (forced
    here) the tuning rounds run instead, and the chain converges either way."""
    import bayescal.mcmc.camera as camera

    if fits is not None:
        monkeypatch.setattr(camera, "LAPLACE_FITS", fits)
    views, _ = bc.simulate_views(n_views=3, rng=4)
    post = bc.sample_camera_posterior(views, rng=2, min_ess=200, tau_factor=20, n_tune=30)
    assert post.converged and post.diagnostics.extra["proposal"] == proposal
