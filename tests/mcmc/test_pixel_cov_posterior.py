"""Per-point pixel covariances in the posterior: approximate points and floor plans."""

import sys
import warnings
from pathlib import Path

import numpy as np
import pytest

import bayescal as bc
from bayescal.fit.floorplan import calibrate_plan

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "likelihood"))
from test_plan_pixel_cov import ring_room  # noqa: E402

SHORT = dict(min_ess=40, max_steps=300, n_tune=30, n_samples=200, progress=False)


def _sample(pixels, scene, **kw):
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", bc.NotConvergedWarning)    # short chains
        return bc.sample_posterior(pixels, scene, rng=3, **SHORT, **kw)


class _Stop(Exception):
    pass


def _sampler_input(monkeypatch, module, pixels, scene, **kw):
    """What sample_posterior hands to the collapsed sampler: (lik, psi_map, cov_map, q_map).

    (Whole chains cannot be compared: the gradient moves amplify round-off, so chains of
    two likelihoods equal to 1e-13 part after a few dozen steps.)"""
    got = {}

    def stop(lik, prior, psi_map, cov_map, q_map, **_):
        got.update(lik=lik, start=(psi_map, cov_map, q_map))
        raise _Stop

    monkeypatch.setattr(module, "sample_collapsed", stop)
    with pytest.raises(_Stop):
        bc.sample_posterior(pixels, scene, progress=False, **kw)
    return got["lik"], got["start"]


def _same_target(a, b, psi):
    """Two likelihoods give the same collapsed log likelihood at the globals ``psi``."""
    (la, sa), (lb, sb) = a, b
    for x, y in zip(sa, sb, strict=True):
        np.testing.assert_allclose(y, x, rtol=1e-9, atol=1e-12)
    q = np.broadcast_to(sa[2], psi.shape[:1] + sa[2].shape)
    np.testing.assert_allclose(lb.laplace(psi, q)[0], la.laplace(psi, q)[0], rtol=1e-11)


def test_isotropic_covariance_gives_the_scalar_posterior(monkeypatch):
    from bayescal.mcmc import sampling

    ds = bc.simulate_room(range_mm=1000, n_points=60, sigma_px=0.5, approx_error=0.02,
                          approx_model="gaussian", rng=0)
    iso = np.broadcast_to(0.25 * np.eye(2), (ds.n_points, 2, 2))
    kw = dict(sigma_scene=ds.sigma_scene)
    a = _sampler_input(monkeypatch, sampling, ds.pixels, ds.approx_points, sigma_px=0.5, **kw)
    b = _sampler_input(monkeypatch, sampling, ds.pixels, ds.approx_points, sigma_px=1.0,
                       pixel_cov=iso, **kw)
    assert b[0].px_white is not None and a[0].px_white is None
    psi = a[1][0] + 0.1 * np.random.default_rng(0).multivariate_normal(
        np.zeros(len(a[1][0])), a[1][1], 20)
    _same_target(a, b, psi)


def test_isotropic_covariance_gives_the_scalar_floor_plan_posterior(monkeypatch):
    from bayescal.mcmc import floorplan

    ds = bc.simulate_room(range_mm=1000, n_points=60, sigma_px=0.5, approx_error=0.05,
                          approx_model="wall", rng=3)
    iso = np.broadcast_to(0.25 * np.eye(2), (ds.n_points, 2, 2))
    a = _sampler_input(monkeypatch, floorplan, ds.pixels, ds.floor_plan, sigma_px=0.5)
    b = _sampler_input(monkeypatch, floorplan, ds.pixels, ds.floor_plan, sigma_px=1.0,
                       pixel_cov=iso)
    assert b[0].px_white is not None and a[0].px_white is None
    psi = a[1][0] + np.random.default_rng(0).multivariate_normal(
        np.zeros(len(a[1][0])), a[1][1], 20)
    _same_target(a, b, psi)


def test_floor_plan_posterior_with_ring_covariances():
    """Tight across the ring, loose along it: the sampler starts at the least squares with
    the same covariances, and its mean stays within a posterior sd of that MAP."""
    ds, plan, cov, pixels = ring_room(n_points=120, rng=1)
    post = _sample(pixels, plan, sigma_px=1.0, pixel_cov=cov)
    lsq = calibrate_plan(pixels, plan, sigma_px=1.0, pixel_cov=cov)
    np.testing.assert_allclose(post.map_result.params.to_array(), lsq.params.to_array(),
                               rtol=1e-12)
    th = post.theta_samples
    z = (th.mean(axis=0) - lsq.extras["theta"]) / th.std(axis=0)
    assert np.all(np.abs(z) < 1.0), z
    # the scalar model with the across-ring sd would be far more confident along the ring
    scalar = calibrate_plan(pixels, plan, sigma_px=0.1)
    assert not np.allclose(scalar.params.to_array(), lsq.params.to_array(), rtol=1e-4)


def test_pixel_cov_shape_is_checked_by_the_sampler():
    ds = bc.simulate_room(range_mm=1000, n_points=40, sigma_px=0.5, rng=0)
    with pytest.raises(ValueError, match="pixel_cov must have shape"):
        bc.sample_posterior(ds.pixels, ds.approx_points, sigma_px=1.0, sigma_scene=10.0,
                            pixel_cov=np.ones((3, 2, 2)), progress=False)


def test_posterior_model_check_uses_the_covariances():
    """Pixel noise drawn from ring covariances (0.1 px across, 1 px along): the posterior's
    predictive check fits with the covariances and fails when they are dropped."""
    from test_plan_pixel_cov import ring_covariance

    ds = bc.simulate_room(range_mm=1000, n_points=120, sigma_px=0.0, approx_error=0.02,
                          approx_model="gaussian", rng=0)
    cov = ring_covariance(ds.params, ds.pixels_true, 0.1, 1.0)
    pixels = ds.pixels_true + np.einsum("nij,nj->ni", np.linalg.cholesky(cov),
                                        np.random.default_rng(5).standard_normal((120, 2)))
    post = _sample(pixels, ds.approx_points, sigma_px=1.0, sigma_scene=ds.sigma_scene,
                   pixel_cov=cov)
    assert post.model_check().fits
    post.pixel_cov = None                   # the same draws judged as 1 px isotropic noise
    assert not post.model_check().fits
