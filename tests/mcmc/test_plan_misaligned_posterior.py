"""sample_posterior(plan, model="misaligned"): the pose sampled with the walls."""

import warnings

import numpy as np

import bayescal as bc
from bayescal.sensor.pose import POSE_NAMES

TRUE_POSE = np.r_[np.radians([1.0, 0.5]), 5.0, -5.0]


def test_misaligned_plan_posterior_samples_the_pose(tmp_path):
    ds = bc.simulate_room(range_mm=2500, n_points=80, n_walls=6, sigma_px=0.2,
                          approx_error=0.03, approx_model="wall", rng=0,
                          tilt=TRUE_POSE[:2], offset=TRUE_POSE[2:])
    with warnings.catch_warnings():
        # the pose mixes slowly without a gradient move (docs/floorplan.md): a short run
        warnings.simplefilter("ignore", bc.NotConvergedWarning)
        post = bc.sample_posterior(ds.pixels, ds.floor_plan, sigma_px=0.2, model="misaligned",
                                   rng=4, min_ess=100, n_samples=300, max_steps=2000,
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
