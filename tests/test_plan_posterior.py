"""The floor-plan posterior: sample_posterior(pixels, plan), wall draws, save/load, reconstruct."""

import warnings

import numpy as np
import pytest

import bayescal as bc
from bayescal.floorplan import FloorPlan


@pytest.fixture(scope="module")
def plan_post():
    ds = bc.simulate_room(range_mm=1000.0, n_points=60, sigma_px=0.5, approx_error=0.05,
                          approx_model="wall", rng=3)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", bc.NotConvergedWarning)   # short chain: shapes only
        post = bc.sample_posterior(ds.pixels, ds.floor_plan, sigma_px=0.5, rng=4, min_ess=50,
                                   max_steps=400, n_tune=40, n_samples=300, progress=False)
    return ds, post


def test_plan_posterior_shapes_and_walls(plan_post):
    ds, post = plan_post
    W, N = ds.floor_plan.n_walls, len(ds.pixels)
    assert post.param_samples.shape == (300, 8)
    assert post.point_samples.shape == (300, N, 3)
    assert post.wall_samples.shape == (300, W, 2)
    assert post.plan is ds.floor_plan
    assert post.noise_samples.shape == (300, 0)
    assert np.all(np.isnan(post.approx_points))
    assert post.diagnostics.names[7:9] == ("d_0", "a_0")
    # every drawn point lies on the wall its azimuth falls on (to rounding), given its draw
    walls = post.wall_samples[:5]
    P = post.point_samples[:5]
    t = np.arctan2(P[..., 1], P[..., 0])
    rho = np.hypot(P[..., 0], P[..., 1])
    best = np.min(np.abs(rho[..., None] * np.cos(t[..., None] - walls[:, None, :, 1])
                         - walls[:, None, :, 0]), axis=-1)
    assert np.max(best) < 1e-6 * np.max(rho)
    # the chain moved the walls off their plan values, by about their Laplace sd
    sd = np.sqrt(np.diag(post.map_result.extras["wall_covariance"])).reshape(W, 2)
    z = (post.wall_samples.mean(axis=0) - post.map_result.extras["walls"]) / sd
    # the MAP and the posterior mean differ by a fraction of an sd here (near-Gaussian walls);
    # 2 sd leaves room for a short chain's Monte-Carlo error
    assert np.all(np.abs(z) < 2.0)
    assert np.all(post.wall_samples.std(axis=0) > 0.3 * sd)


def test_plan_posterior_save_load_and_reconstruct(plan_post, tmp_path):
    ds, post = plan_post
    path = post.save(tmp_path / "plan.npz")
    back = bc.load_posterior(path)
    np.testing.assert_array_equal(back.wall_samples, post.wall_samples)
    np.testing.assert_array_equal(back.param_samples, post.param_samples)
    assert isinstance(back.plan, FloorPlan)
    np.testing.assert_array_equal(back.plan.param_nominal, post.plan.param_nominal)
    np.testing.assert_array_equal(back.plan.param_sd, post.plan.param_sd)
    rec = back.reconstruct(ds.pixels[:10], rng=0, max_samples=200)
    assert rec.mean.shape == (10, 3) and np.all(rec.valid)
    # new pixels triangulate on the cone near the calibration's own points
    err = np.linalg.norm(rec.mean - post.point_mean[:10], axis=-1)
    assert np.all(err < 4 * np.sqrt(np.trace(rec.covariance, axis1=1, axis2=2)))


def test_per_point_posterior_files_still_load(tmp_path):
    """A per-point Posterior saves without walls or plan and loads with None for both."""
    from bayescal.posterior import Posterior

    rng = np.random.default_rng(0)
    post = Posterior(param_samples=rng.normal(size=(5, 8)), point_samples=np.zeros((5, 2, 3)),
                     noise_samples=np.zeros((5, 0)), noise_names=(), pixels=np.zeros((2, 2)),
                     approx_points=np.zeros((2, 3)), sigma_px=0.5, sigma_scene=np.ones((2, 3)),
                     prior=None, tau=np.ones(7), ess=np.ones(7), n_steps=10, burn=2,
                     n_walkers=16, converged=False, acceptance=0.5, imh_acceptance=0.5,
                     laplace_cov8=np.eye(8), laplace_cov7=np.eye(7), map_params=np.zeros(8),
                     map_points=np.zeros((2, 3)), map_point_covariance=np.zeros((2, 3, 3)))
    back = bc.load_posterior(post.save(tmp_path / "p.npz"))
    assert back.wall_samples is None and back.plan is None


def test_plan_posterior_argument_errors():
    ds = bc.simulate_room(range_mm=1000.0, n_points=30, sigma_px=0.5, approx_error=0.05,
                          approx_model="wall", rng=1)
    with pytest.raises(TypeError, match="sigma_scene does not apply"):
        bc.sample_posterior(ds.pixels, ds.floor_plan, sigma_px=0.5, sigma_scene=1.0)
    with pytest.raises(TypeError, match="sigma_scene"):
        bc.sample_posterior(ds.pixels, ds.approx_points, sigma_px=0.5)
    with pytest.raises(ValueError, match="n_walkers must be at least 2 \\* ndim = 42"):
        bc.sample_posterior(ds.pixels, ds.floor_plan, sigma_px=0.5, n_walkers=20)


def test_floor_plan_arrays_round_trip():
    plan = FloorPlan(bc.room_walls(1000.0), distance_sd=np.arange(1.0, 8.0), angle_sd=0.01)
    back = FloorPlan.from_arrays(plan.to_arrays())
    np.testing.assert_array_equal(back.segments, plan.segments)
    np.testing.assert_array_equal(back.param_sd, plan.param_sd)
    with pytest.raises(ValueError, match="lack the key 'segments'"):
        FloorPlan.from_arrays({})
