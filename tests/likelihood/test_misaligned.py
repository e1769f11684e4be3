"""The misaligned likelihood: the aligned one at zero pose, analytic Jacobians, pose prior."""

import numpy as np
import pytest
from scipy import stats

import bayescal as bc
from bayescal.likelihood.misaligned import MisalignedLikelihood
from bayescal.likelihood.points import LaserLikelihood
from bayescal.likelihood.priors import Prior

POSE = np.array([np.radians(1.0), np.radians(-0.5), 4.0, -3.0])


@pytest.fixture(scope="module")
def data():
    truth = bc.SensorParams.paper()
    ds = bc.simulate_room(truth, range_mm=1500, n_points=40, sigma_px=0.3, approx_error=0.02,
                          approx_model="gaussian", rng=3, tilt=tuple(POSE[:2]),
                          offset=tuple(POSE[2:]))
    return ds


def _pair(ds, **kw):
    args = dict(sigma_px=0.3, sigma_scene=ds.sigma_scene, **kw)
    return (LaserLikelihood(ds.pixels, ds.approx_points, **args),
            MisalignedLikelihood(ds.pixels, ds.approx_points, **args))


def test_zero_pose_is_the_aligned_likelihood(data):
    al, mis = _pair(data, outliers=True)
    theta = data.params.to_identifiable()
    q = data.approx_points[:, :2]
    lw = np.log(0.05 / 0.95)
    psi_a, psi_m = np.r_[theta, lw], np.r_[theta, np.zeros(4), lw]
    for a, b in zip(al.residuals(theta, q, np.float64(0.3), al.w_scene, jacobian=True),
                    mis.residuals(np.r_[theta, np.zeros(4)], q, np.float64(0.3), mis.w_scene,
                                  jacobian=True), strict=True):
        np.testing.assert_allclose(b[..., :a.shape[-1]], a, rtol=1e-10, atol=1e-10)
    np.testing.assert_allclose(mis.laplace(psi_m, q)[0], al.laplace(psi_a, q)[0], rtol=1e-12)
    assert mis.extra_names == bc.sensor.pose.POSE_NAMES + al.extra_names


def test_residual_jacobians_match_finite_differences(data):
    _, mis = _pair(data)
    g = np.r_[data.params.to_identifiable(), POSE]
    q = data.points[:, :2] + 3.0
    sig = np.float64(0.3)
    R, Jg, Jq = mis.residuals(g, q, sig, mis.w_scene, jacobian=True)
    for k in range(len(g)):
        e = np.zeros_like(g)
        e[k] = 1e-6 * max(1.0, abs(g[k]))
        num = (mis.residuals(g + e, q, sig, mis.w_scene)
               - mis.residuals(g - e, q, sig, mis.w_scene)) / (2 * e[k])
        np.testing.assert_allclose(Jg[..., k], num, rtol=1e-5, atol=1e-6 * np.abs(num).max())
    for k in range(2):
        e = np.zeros_like(q)
        e[:, k] = 1e-4
        num = (mis.residuals(g, q + e, sig, mis.w_scene)
               - mis.residuals(g, q - e, sig, mis.w_scene)) / 2e-4
        np.testing.assert_allclose(Jq[..., k], num, rtol=1e-5, atol=1e-8)


def test_point_terms_are_the_residuals_normal_equations(data):
    _, mis = _pair(data)
    g = np.r_[data.params.to_identifiable(), POSE]
    q = data.points[:, :2] + 2.0
    sig = np.float64(0.3)
    R, _, Jq = mis.residuals(g, q, sig, mis.w_scene, jacobian=True)
    rr, Cp, Cs, g0, g1 = mis._point_terms(g, q[:, 0], q[:, 1], sig, mis.w_scene)
    np.testing.assert_allclose(rr, np.sum(R * R, axis=1), rtol=1e-10)
    C = np.einsum("nki,nkj->nij", Jq, Jq)
    np.testing.assert_allclose(Cp[0] + Cs[0], C[:, 0, 0], rtol=1e-10)
    np.testing.assert_allclose(Cp[1] + Cs[1], C[:, 0, 1], rtol=1e-10, atol=1e-12)
    np.testing.assert_allclose(Cp[2] + Cs[2], C[:, 1, 1], rtol=1e-10)
    grad = np.einsum("nki,nk->ni", Jq, R)
    np.testing.assert_allclose(np.c_[g0, g1], grad, rtol=1e-9, atol=1e-12)


def test_pose_prior_by_name():
    prior = Prior({"tilt_x": stats.norm(0.0, 0.01), "h": stats.norm(210.0, 5.0)})
    assert prior.pose_dists["tilt_x"].std() == pytest.approx(0.01)
    assert prior.pose_dists["offset_y"].std() == pytest.approx(5.0)       # the default
    assert prior.dists["h"].mean() == pytest.approx(210.0)
    r, J = prior.pose_residuals(np.array([0.02, 0.0, 5.0, 0.0]), jacobian=True)
    np.testing.assert_allclose(r, [2.0, 0.0, 1.0, 0.0])
    np.testing.assert_allclose(np.diag(J), [100.0, 1 / np.radians(2.0), 0.2, 0.2])
    expected = (stats.norm(0, 0.01).logpdf(0.02) + stats.norm(0, np.radians(2)).logpdf(0.0)
                + stats.norm(0, 5).logpdf(5.0) + stats.norm(0, 5).logpdf(0.0))
    assert prior.logpdf_pose(np.array([0.02, 0.0, 5.0, 0.0])) == pytest.approx(expected)
    with pytest.raises(ValueError, match="unknown parameter name.*tilt_z"):
        Prior({"tilt_z": stats.norm(0, 1)})


@pytest.mark.parametrize("outliers", [False, True])
def test_collapsed_gradient_matches_finite_differences(data, outliers):
    # given noise, Jeffreys point prior: the log marginal is the profile likelihood and the
    # envelope-theorem gradient is exact up to the Gauss-Newton modes' convergence
    _, mis = _pair(data, outliers=outliers)
    psi = np.r_[data.params.to_identifiable(), POSE, [np.log(0.05 / 0.95)] if outliers else []]
    q0 = data.points[:, :2]
    value, grad = mis.grad_log_marginal(psi, q0, n_iter=8)
    assert value == pytest.approx(mis.laplace(psi, q0, n_iter=8)[0], rel=1e-12)
    for k in range(len(psi)):
        e = np.zeros_like(psi)
        e[k] = 1e-5 * max(1.0, abs(psi[k]))
        num = (mis.laplace(psi + e, q0, n_iter=8)[0]
               - mis.laplace(psi - e, q0, n_iter=8)[0]) / (2 * e[k])
        assert grad[k] == pytest.approx(num, rel=2e-3, abs=1e-3 * max(1.0, abs(num))), k
