"""The floor-plan likelihood on a misaligned (tilted and offset) laser cone."""

import numpy as np
import pytest
from helpers import check_plan_residual_jacobians

import bayescal as bc
from bayescal.likelihood.floorplan import PlanLikelihood
from bayescal.likelihood.plan_misaligned import MisalignedPlanLikelihood, plan_likelihood
from bayescal.scene.floorplan import FloorPlan

POSE = np.array([0.02, -0.015, 4.0, -6.0])          # tilt_x, tilt_y (rad), offset (mm)


@pytest.fixture(scope="module")
def room():
    ds = bc.simulate_room(range_mm=1500, n_points=60, n_walls=6, sigma_px=0.3, rng=3,
                          tilt=POSE[:2], offset=POSE[2:])
    return ds, FloorPlan(ds.walls, distance_sd=50.0, angle_sd=0.02)


def test_residual_jacobians_carry_the_pose(room, rng, numdiff):
    ds, plan = room
    lik = MisalignedPlanLikelihood(ds.pixels, plan, sigma_px=0.3)
    g, walls = np.r_[ds.params.to_identifiable(), POSE], plan.param_nominal.reshape(-1, 2)
    t = lik._start(g[None])[0] + rng.normal(0, 0.01, lik.n)
    # the sampler's elementwise hot path (tilted height and its slope) agrees with them
    Jg = check_plan_residual_jacobians(lik, g, walls, t, 0.3, numdiff, rows=(0, 7),
                                       dt_tol=dict(rtol=1e-9, atol=1e-12))
    assert Jg.shape == (lik.n, 2, 11)


@pytest.mark.parametrize("sigma_px", [0.3, None])
def test_zero_pose_is_the_aligned_likelihood(room, sigma_px):
    ds, plan = room
    kw = dict(sigma_px=sigma_px, outliers=True)
    a = PlanLikelihood(ds.pixels, plan, **kw)
    m = MisalignedPlanLikelihood(ds.pixels, plan, **kw)
    extra = [np.log(0.3)] * (sigma_px is None) + [-3.0]
    psi_a = np.r_[ds.params.to_identifiable(), plan.param_nominal, extra]
    psi_m = np.r_[ds.params.to_identifiable(), np.zeros(4), plan.param_nominal, extra]
    la, qa, ca = a.laplace(psi_a)
    lm, qm, cm = m.laplace(psi_m)
    assert np.isfinite(la) and lm == pytest.approx(la, rel=1e-12, abs=1e-8)
    np.testing.assert_allclose(qm, qa, atol=1e-12)
    np.testing.assert_allclose(cm, ca, rtol=1e-9)
    np.testing.assert_allclose(m.points_3d(psi_m, qm), a.points_3d(psi_a, qa), atol=1e-9)
    np.testing.assert_allclose(m.point_log_density(psi_m, qm), a.point_log_density(psi_a, qa),
                               rtol=1e-9, atol=1e-9)
    assert m.extra_names == bc.POSE_NAMES + a.extra_names
    # the pose's prior joins the walls' and the noise's
    prior = bc.Prior()
    assert m.log_prior_extra(psi_m[7:]) == pytest.approx(
        a.log_prior_extra(psi_a[7:]) + prior.logpdf_pose(np.zeros(4)), rel=1e-12)
    g, walls, sig = m.split(psi_m)
    assert g.shape == (11,) and walls.shape == (plan.n_walls, 2)


def test_the_true_pose_explains_the_pixels_better(room):
    ds, plan = room
    m = MisalignedPlanLikelihood(ds.pixels, FloorPlan(ds.walls, distance_sd=50.0,
                                                      angle_sd=0.02), sigma_px=0.3)
    w = FloorPlan(ds.walls, distance_sd=50.0, angle_sd=0.02).param_nominal
    theta = ds.params.to_identifiable()
    l_true = m.laplace(np.r_[theta, POSE, w])[0]
    l_zero = m.laplace(np.r_[theta, np.zeros(4), w])[0]
    assert l_true > l_zero + 100
    # the points at the true pose are the simulated ones (walls exact)
    q = m.laplace(np.r_[theta, POSE, w])[1]
    assert np.median(np.linalg.norm(m.points_3d(np.r_[theta, POSE, w], q) - ds.points,
                                    axis=-1)) < 5.0


def test_plan_likelihood_dispatch(room):
    ds, plan = room
    assert type(plan_likelihood("aligned", ds.pixels, plan, None, sigma_px=1.0)) \
        is PlanLikelihood
    lik = plan_likelihood("misaligned", ds.pixels, plan, {"tilt_x": bc.Prior().pose_dists[
        "tilt_x"]}, sigma_px=1.0)
    assert isinstance(lik, MisalignedPlanLikelihood) and lik.n_geo == 11
    with pytest.raises(ValueError, match="model must be"):
        plan_likelihood("tilted", ds.pixels, plan, None, sigma_px=1.0)
