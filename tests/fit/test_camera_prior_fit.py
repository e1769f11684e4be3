"""The laser stage on a camera calibrated beforehand (``camera=``): a tight camera holds its
intrinsics, a loose one lets the laser data move them; approximate points and floor plans,
aligned and misaligned cones; the sequential method's stage 2 on the camera."""

import numpy as np
import pytest

import bayescal as bc

TRUTH = bc.SensorParams.paper()
THETA = TRUTH.to_identifiable()
SD = np.array([0.01, 1.0, 1.0, 0.5, 0.5])
CORR = np.eye(5)
CORR[0, 1:3] = CORR[1:3, 0] = 0.9
CORR[1, 2] = CORR[2, 1] = 0.85
COV = CORR * np.outer(SD, SD)
#: the camera's intrinsics off the truth: xi by 0.02, gammas by 1 px, the centre by 2 px
OFF = np.array([0.02, 1.0, -1.0, 2.0, -2.0])


@pytest.fixture(scope="module")
def room():
    return bc.simulate_room(range_mm=2500, n_points=100, sigma_px=0.3, approx_error=0.03,
                            rng=7)


def _fit(room, camera, scene, model):
    if scene == "plan":
        return bc.calibrate_simultaneous(room.pixels, room.floor_plan, sigma_px=0.3,
                                         camera=camera, model=model)
    return bc.calibrate_simultaneous(room.pixels, room.approx_points, sigma_px=0.3,
                                     sigma_scene=room.sigma_scene, camera=camera, model=model)


@pytest.mark.parametrize("scene, model", [("points", "aligned"), ("plan", "aligned"),
                                          ("points", "misaligned"), ("plan", "misaligned")])
def test_a_tight_camera_holds_its_intrinsics(room, scene, model):
    m, cov = THETA[:5] + 0.05 * OFF, COV * 1e-8     # off by about 1 sd of the data
    res = _fit(room, (m, cov), scene, model)
    assert res.converged, res.message
    th, sd = res.extras["theta"][:5], np.sqrt(np.diag(res.covariance(identifiable=True))[:5])
    # the laser data pull against 1e-4-sd priors: the intrinsics move by < 0.1 of their sd
    np.testing.assert_array_less(np.abs(th - m), 0.1 * np.sqrt(np.diag(cov)))
    np.testing.assert_allclose(sd, np.sqrt(np.diag(cov)), rtol=0.01)


@pytest.mark.parametrize("scene, model", [("points", "aligned"), ("plan", "aligned"),
                                          ("points", "misaligned")])
def test_a_loose_camera_lets_the_laser_data_move_it(room, scene, model):
    m, cov = THETA[:5] + OFF, COV * 100.0            # sds 10x the offsets' size or more
    res = _fit(room, (m, cov), scene, model)
    assert res.converged, res.message
    th, c = res.extras["theta"][:5], res.covariance(identifiable=True)[:5, :5]
    z = (th - THETA[:5]) / np.sqrt(np.diag(c))
    print(scene, model, np.round(z, 2), np.round(np.abs(th - THETA[:5]) / np.abs(OFF), 3))
    # the centre comes back to the truth (within 4 sd, and 5x closer than the camera put
    # it); xi and the gammas move too, wherever the data see them
    assert np.all(np.abs(z) < 4.0)
    np.testing.assert_array_less(np.abs(th - THETA[:5])[3:], 0.2 * np.abs(OFF[3:]))


def test_the_camera_prior_replaces_the_default_priors_and_is_refused_beside_them(room):
    from scipy import stats

    cam = (THETA[:5], COV)
    res = bc.calibrate_simultaneous(room.pixels, room.approx_points, sigma_px=0.3,
                                    sigma_scene=room.sigma_scene, camera=cam,
                                    prior={"h": stats.norm(200.0, 5.0)})
    assert res.converged
    with pytest.raises(ValueError, match="camera's prior replaces"):
        bc.calibrate_simultaneous(room.pixels, room.approx_points, sigma_px=0.3,
                                  sigma_scene=room.sigma_scene, camera=cam,
                                  prior={"u0": stats.norm(400.0, 5.0)})
    with pytest.raises(TypeError, match="camera must be a camera calibration"):
        bc.calibrate_simultaneous(room.pixels, room.approx_points, sigma_px=0.3,
                                  sigma_scene=room.sigma_scene, camera="camera.json")


def test_sequential_on_a_camera_fits_the_pose_alone_and_carries_the_camera(room):
    plain = bc.calibrate_sequential(room.calibration)
    m = THETA[:5] + 0.1 * OFF
    tight = bc.calibrate_sequential(room.calibration, camera=(m, COV * 1e-8))
    loose = bc.calibrate_sequential(room.calibration, camera=(m, COV))
    for res in (tight, loose):
        assert res.converged and res.extras["camera_given"]
        assert res.extras["stage1"]["n_unknowns"] == 6 and res.n_unknowns == 8
        np.testing.assert_allclose(res.params.to_identifiable()[:5], m, rtol=1e-12)
        np.testing.assert_allclose(res.extras["stage1_covariance"][:5, :5],
                                   res.covariance(identifiable=True)[:5, :5], rtol=1e-12)
    # the pattern noise is not inflated by the camera's error (0.1 of OFF: 1-2 camera sds)
    np.testing.assert_allclose(loose.extras["sigma_px_used"], plain.extras["sigma_px_used"],
                               rtol=0.05)
    # the camera's covariance widens h and beta (measured 1.07x and 1.6x)
    assert loose.std[6] > tight.std[6] and loose.std[7] > 1.3 * tight.std[7]


@pytest.mark.slow
def test_posterior_on_a_tight_camera_keeps_its_intrinsics():
    # ~12 s: the sampler keeps gamma and h as coordinates (tau 2.5-3; 9-34 with the ring's)
    ds = bc.simulate_room(range_mm=1000, n_points=40, sigma_px=0.5, approx_error=0.02,
                          approx_model="gaussian", rng=0)
    m, cov = THETA[:5] + 0.05 * OFF, COV * 1e-6
    post = bc.sample_posterior(ds.pixels, ds.approx_points, sigma_px=0.5,
                               sigma_scene=ds.sigma_scene, camera=(m, cov), rng=1,
                               progress=False, min_ess=200, n_samples=400, outliers=False)
    th = bc.sensor.parameters.to_identifiable(post.param_samples)
    sd = np.sqrt(np.diag(cov))
    # posterior means within 0.2 prior sd of the camera's (400 draws: Monte-Carlo error
    # ~0.07 sd), sds within 20 % of the camera's
    np.testing.assert_array_less(np.abs(th[:, :5].mean(0) - m), 0.2 * sd)
    np.testing.assert_allclose(th[:, :5].std(0), sd, rtol=0.2)
    assert np.all(post.param_samples[:, 0] + post.param_samples[:, 1] > 0)
    assert post.prior.camera is not None
    assert post.converged and np.max(post.tau) < 6


def test_the_sampler_keeps_gamma_when_the_camera_holds_it():
    from bayescal.mcmc.collapsed import _camera_holds_gamma
    from bayescal.mcmc.coordinates import Coordinates
    from bayescal.mcmc.steps import CollapsedTarget

    tight, loose = bc.Prior(camera=(THETA[:5], COV * 1e-6)), bc.Prior(camera=(THETA[:5], COV))
    cov = np.diag([1e-5, 0.04, 0.04, 0.01, 0.01, 25.0, 1e-5])      # data: gamma sd 0.2 px
    assert _camera_holds_gamma(tight, cov) and not _camera_holds_gamma(loose, cov)
    assert not _camera_holds_gamma(bc.Prior(), cov)
    c = Coordinates(1500.0, ring=False)
    psi = np.r_[THETA, -3.0]
    np.testing.assert_array_equal(c.to_sampling(psi), psi)
    np.testing.assert_array_equal(c.from_sampling(psi), psi)
    assert c.log_jacobian(psi) == 0.0
    # the sampler's log prior is the camera prior's (a likelihood without extra globals)
    class NoExtras:
        @staticmethod
        def log_prior_extra(extra):
            return 0.0

    target = CollapsedTarget(NoExtras(), tight, None, 1, c)
    np.testing.assert_allclose(target.log_prior(THETA[None]), tight.logpdf_theta(THETA[None]))


@pytest.mark.slow
def test_floor_plan_posterior_on_a_camera():
    # the plan sampler with the camera's prior (aligned cone, 60 points, 3 % plan)
    ds = bc.simulate_room(range_mm=1000, n_points=60, sigma_px=0.3, approx_error=0.03, rng=3)
    cam = (THETA[:5], COV * 0.01)
    post = bc.sample_posterior(ds.pixels, ds.floor_plan, sigma_px=0.3, camera=cam, rng=2,
                               progress=False, min_ess=200, n_samples=400)
    th = bc.sensor.parameters.to_identifiable(post.param_samples)
    z = (th.mean(0) - THETA) / th.std(0)
    print("plan posterior z:", np.round(z, 2), "tau", np.round(post.tau, 1))
    assert post.converged and np.all(np.abs(z) < 4)
    assert np.all(th[:, :5].std(0) <= 1.05 * np.sqrt(np.diag(cam[1])))
