"""The floor-plan likelihood on a misaligned (tilted and offset) laser cone."""

import numpy as np
import pytest

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
    k = lik.hard_wall_index(walls, t)
    R, Jg, Jw, Jt = lik.residuals(g, walls, t, k, 0.3, jacobian=True)
    assert Jg.shape == (lik.n, 2, 11)
    i = np.arange(lik.n)
    num_t = np.stack([numdiff(lambda x, j=j: lik.residuals(g, walls, np.where(i == j, x[0], t),
                                                           k, 0.3)[j], [t[j]], 1e-7)[:, 0]
                      for j in range(lik.n)])
    np.testing.assert_allclose(Jt, num_t, rtol=1e-5, atol=1e-6)
    num_g = numdiff(lambda x: lik.residuals(x, walls, t, k, 0.3), g,
                    1e-6 * np.maximum(1, np.abs(g)))
    np.testing.assert_allclose(Jg, num_g, rtol=1e-5, atol=1e-5)
    for j in (0, 7):
        def f(x, j=j):
            w = walls.copy()
            w[k[j]] = x
            return lik.residuals(g, w, t, k, 0.3)[j]
        np.testing.assert_allclose(Jw[j], numdiff(f, walls[k[j]], [1e-4, 1e-7]),
                                   rtol=1e-5, atol=1e-6)
    # the sampler's elementwise hot path (tilted height and its slope) agrees with them
    d, a = walls[k, 0], walls[k, 1]
    u, v, du, dv = lik._pixel_terms(g[None], t[None], d[None], np.cos(a)[None],
                                    np.sin(a)[None])
    np.testing.assert_allclose(np.stack([u[0], v[0]], -1), R * 0.3 + ds.pixels, rtol=1e-12)
    np.testing.assert_allclose(np.stack([du[0], dv[0]], -1), Jt * 0.3, rtol=1e-9, atol=1e-12)


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
