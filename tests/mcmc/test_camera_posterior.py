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
    post = bc.sample_camera_posterior(views, rng=0, lsq=lsq, min_ess=300, tau_factor=30,
                                      n_tune=40)
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
