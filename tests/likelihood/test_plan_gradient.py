"""The floor-plan log marginal's gradient (the misaligned plan sampler's HMC move)."""

import numpy as np
import pytest

import bayescal as bc
from bayescal.likelihood.floorplan import PlanLikelihood
from bayescal.likelihood.plan_gradient import PlanGradient
from bayescal.likelihood.plan_misaligned import MisalignedPlanLikelihood
from bayescal.mcmc.steps import CollapsedTarget
from bayescal.scene.floorplan import FloorPlan

POSE = np.array([0.02, -0.015, 4.0, -6.0])          # tilt_x, tilt_y (rad), offset (mm)


class _AlignedWithGradient(PlanGradient, PlanLikelihood):
    """The aligned plan likelihood with the gradient (the code is the same for both)."""


@pytest.fixture(scope="module")
def room():
    ds = bc.simulate_room(range_mm=1500, n_points=80, n_walls=6, sigma_px=0.3, rng=3,
                          tilt=POSE[:2], offset=POSE[2:])
    return ds, FloorPlan(ds.walls, distance_sd=50.0, angle_sd=0.02)


def _psi(ds, plan, lik, *, pose):
    extra = [np.log(0.3)] * lik.infer_px + [-3.0] * lik.outliers
    return np.r_[ds.params.to_identifiable(), POSE if pose else [], plan.param_nominal, extra]


@pytest.mark.parametrize("cls", [MisalignedPlanLikelihood, _AlignedWithGradient])
def test_piece_jacobian_is_the_residuals_jacobian(room, rng, cls):
    # the hand-written derivatives at a fixed azimuth against the least squares' Jacobians
    ds, plan = room
    cov = np.array([[0.09, 0.03], [0.03, 0.25]]) * rng.uniform(0.5, 2.0, (len(ds.pixels), 1, 1))
    lik = cls(ds.pixels, plan, sigma_px=0.3, pixel_cov=cov)
    g = _psi(ds, plan, lik, pose=cls is MisalignedPlanLikelihood)[:lik.n_geo]
    walls = plan.param_nominal.reshape(-1, 2) + rng.normal(0, [5.0, 0.005], (plan.n_walls, 2))
    t = lik._start(g[None])[0] + rng.normal(0, 0.01, lik.n)
    for p in (0, 1):
        k = lik.wall_pair[:, p]
        R, Jg, Jw, _ = lik.residuals(g, walls, t, k, 1.0, jacobian=True)
        sel = np.arange(lik.n)
        rr, rj_geo, rj_wall = lik._piece_jacobian(g[None], walls[None], t[None], p, sel)
        np.testing.assert_allclose(rr[0], np.sum(R * R, axis=1), rtol=1e-10)
        np.testing.assert_allclose(rj_geo[0], np.einsum("nc,nck->nk", R, Jg), rtol=1e-6,
                                   atol=1e-9 * np.abs(rj_geo).max())
        np.testing.assert_allclose(rj_wall[0], np.einsum("nc,nck->nk", R, Jw), rtol=1e-6,
                                   atol=1e-9 * np.abs(rj_wall).max())


@pytest.mark.parametrize("sigma_px, outliers, restrict", [(0.3, True, True), (None, True, False),
                                                          (0.3, False, False)])
def test_gradient_matches_finite_differences(room, rng, sigma_px, outliers, restrict):
    ds, plan = room
    lik = MisalignedPlanLikelihood(ds.pixels, plan, sigma_px=sigma_px, outliers=outliers)
    psi0 = _psi(ds, plan, lik, pose=True)
    sd = np.r_[[0.01, 2.0, 2.0, 0.5, 0.5, 2.0, 0.005], [0.005, 0.005, 2.0, 2.0],
               plan.param_sd, [0.02] * lik.infer_px, [0.3] * outliers]
    psi = psi0 + sd * rng.standard_normal((3, len(psi0)))
    if restrict:
        lik.restrict_pieces(psi0 + 3 * sd * rng.standard_normal((50, len(psi0))))
        assert 0 < len(lik.near) < lik.n
    value, grad = lik.grad_log_marginal(psi, n_iter=3)
    assert np.array_equal(value, lik.laplace(psi, n_iter=3)[0])
    num = np.zeros_like(grad)
    for j in range(len(psi0)):
        e = np.zeros(len(psi0))
        e[j] = 1e-4 * sd[j]
        num[:, j] = (lik.laplace(psi + e, n_iter=3)[0]
                     - lik.laplace(psi - e, n_iter=3)[0]) / (2 * e[j])
    # in nats per step of the spread above: the log(H/C) and corner-truncation terms left
    # out of the gradient move it by < 1 nat (measured 0.2-0.8 on xi, gamma, beta with the
    # noise inferred); a wrong derivative would be off by its own size (tens to hundreds)
    g, n = grad * sd, num * sd
    assert np.all(np.linalg.norm(g - n, axis=1) < 0.05 * np.linalg.norm(n, axis=1) + 1.5)
    np.testing.assert_allclose(g, n, rtol=0.05, atol=1.0)


def test_the_misaligned_plan_sampler_has_the_gradient_move(room):
    ds, plan = room
    target = CollapsedTarget(MisalignedPlanLikelihood(ds.pixels, plan, sigma_px=0.3),
                             bc.Prior(), None, 2)
    assert target.has_gradient
    assert not CollapsedTarget(PlanLikelihood(ds.pixels, plan, sigma_px=0.3), bc.Prior(),
                               None, 2).has_gradient
