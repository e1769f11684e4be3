"""sample_posterior(plan, model="misaligned"): the pose sampled with the walls."""

import warnings

import numpy as np
import pytest
from helpers import check_seed_scatter

import bayescal as bc
from bayescal.sensor.pose import POSE_NAMES

TRUE_POSE = np.r_[np.radians([1.0, 0.5]), 5.0, -5.0]


def test_misaligned_plan_posterior_samples_the_pose(tmp_path):
    ds = bc.simulate_room(range_mm=2500, n_points=80, n_walls=6, sigma_px=0.2,
                          approx_error=0.03, approx_model="wall", rng=0,
                          tilt=TRUE_POSE[:2], offset=TRUE_POSE[2:])
    with warnings.catch_warnings():
        # a short run: shapes and the pose's place (convergence: the slow test below)
        warnings.simplefilter("ignore", bc.NotConvergedWarning)
        post = bc.sample_posterior(ds.pixels, ds.floor_plan, sigma_px=0.2, model="misaligned",
                                   rng=4, min_ess=100, n_samples=300, max_steps=150, n_tune=30,
                                   progress=False)
    assert post.model == "misaligned"
    assert post.noise_names[:4] == POSE_NAMES and post.noise_names[-1] == "outlier_frac"
    assert post.laser_samples.shape == (300, 4)
    assert post.wall_samples.shape == (300, 6, 2) and post.point_samples.shape == (300, 80, 3)
    assert post.map_result.model == "misaligned"
    ls = post.laser_samples
    z = (ls.mean(axis=0) - TRUE_POSE) / ls.std(axis=0)
    assert np.all(np.abs(z) < 4), z
    theta = post.param_samples
    assert np.all(np.isfinite(theta)) and post.covariance(identifiable=True).shape == (11, 11)
    # the points lie on the sampled tilted cones
    k = 7
    lit = bc.cone_point(bc.SensorParams.from_array(theta[k]), post.point_samples[k, :, :2],
                        laser=bc.LaserPose.from_array(ls[k]))
    np.testing.assert_allclose(post.point_samples[k], lit, atol=1e-6)
    back = bc.load_posterior(post.save(tmp_path / "p.npz"))
    np.testing.assert_array_equal(back.laser_samples, post.laser_samples)
    assert back.model == "misaligned" and back.wall_samples.shape == (300, 6, 2)
    rec = post.reconstruct(ds.pixels[:20])
    assert np.all(np.isfinite(rec.mean))


@pytest.mark.slow
def test_misaligned_plan_posterior_converges_with_an_honest_ess():
    """The misaligned plan posterior (HMC on the plan gradient; the apparent principal point,
    fitted radially, as a coordinate) converges, and its ESS is
    honest: one room (2500 mm, 6 walls, 150 points, 3 % plan, tilt (1, 0.5) deg, offset (5,
    -5) mm), 8 sampler seeds; the sd of the 8 posterior means over the rms claimed
    Monte-Carlo error follows sqrt(chi2_7 / 7) per coordinate if the ESS is right. Asserted
    for the 7 identifiable parameters, the 4 of the pose and the 12 of the walls: each
    inside the family-wise band (1 - 1e-3 over 23), and their mean square inside the 99 %
    band of chi2_7 / 7 (the fully correlated, widest null). Measured: ratios 0.72-1.71, mean
    square 1.56 (with the earlier half-size apparent principal point: 2.86 failing, 1.41 with
    the walls' distances net of the pose: docs/floorplan.md section 13)."""
    ds = bc.simulate_room(range_mm=2500, n_points=150, n_walls=6, sigma_px=0.2,
                          approx_error=0.03, approx_model="wall", rng=5,
                          tilt=TRUE_POSE[:2], offset=TRUE_POSE[2:])
    means, errs = [], []
    for seed in range(8):
        post = bc.sample_posterior(ds.pixels, ds.floor_plan, sigma_px=0.2, model="misaligned",
                                   rng=200 + seed, progress=False, n_samples=20000,
                                   n_point_mh=0, on_unconverged="raise")
        walls = post.wall_samples.reshape(len(post.wall_samples), -1)
        x = np.concatenate([post.theta_samples, post.laser_samples, walls], axis=1)
        ess = post.ess[:x.shape[1]]
        means.append(x.mean(axis=0))
        errs.append(x.std(axis=0) / np.sqrt(ess))
    check_seed_scatter(means, errs)
