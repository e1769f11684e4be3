"""The sampler's fused hot path (point_algebra.marginal_sum): laplace's numbers, summed."""

import numpy as np
import pytest

import bayescal as bc
from bayescal.likelihood.points import LaserLikelihood


def _case(sigma_px, sigma_scene, outliers, point_prior):
    ds = bc.simulate_room(range_mm=1500, n_points=70, sigma_px=0.3, approx_error=0.03,
                          approx_model="fig9", rng=11)
    sig_scene = np.maximum(ds.sigma_scene, 1.0)
    lik = LaserLikelihood(ds.pixels, ds.approx_points, outliers=outliers,
                          point_prior=point_prior,
                          sigma_px=ds.sigma_px if sigma_px else None,
                          sigma_scene=sig_scene if sigma_scene else None)
    lik.set_reference_noise(sigma_px=0.25, kappa=0.04)     # the Jeffreys prior off its levels
    theta = ds.params.to_identifiable()
    extra = [np.log(0.3)] * (not sigma_px) + [np.log(0.03)] * (not sigma_scene) \
        + [-3.0] * outliers
    rng = np.random.default_rng(0)
    psi = np.concatenate([theta, extra]) * (1 + 1e-3 * rng.standard_normal((5, 7 + len(extra))))
    return lik, psi, lik.initial_q(theta) + 2.0


@pytest.mark.parametrize("sigma_px, sigma_scene, outliers, point_prior", [
    (True, True, False, "jeffreys"), (True, True, True, "jeffreys"),
    (False, True, True, "jeffreys"), (True, False, False, "jeffreys"),
    (False, False, True, "jeffreys"), (True, True, True, "flat"), (False, False, False, "flat")])
@pytest.mark.parametrize("n_iter", [1, 3])
def test_fused_sum_is_laplaces(sigma_px, sigma_scene, outliers, point_prior, n_iter):
    lik, psi, q0 = _case(sigma_px, sigma_scene, outliers, point_prior)
    want = lik.laplace(psi, q0, n_iter=n_iter)[0]
    # a shared start (N, 2) and one per walker (W, N, 2): the two first passes of the kernel
    for q in (q0, np.broadcast_to(q0, (len(psi),) + q0.shape).copy()):
        got = lik.log_marginal(psi, q, n_iter=n_iter)
        # the same terms summed in another order: rounding of sums of ~70 terms of ~1e3
        np.testing.assert_allclose(got, want, rtol=1e-12, atol=1e-8)


def test_fused_sum_is_minus_inf_outside_the_domain():
    lik, psi, q0 = _case(True, True, True, "jeffreys")
    psi[1, 0] = 1e-3                       # xi ~ 0: the projection's denominator D <= 0
    want = lik.laplace(psi, q0, n_iter=1)[0]
    got = lik.log_marginal(psi, q0, n_iter=1)
    assert np.isneginf(got[1]) and np.array_equal(np.isinf(got), np.isinf(want))
    np.testing.assert_allclose(got[[0, 2, 3, 4]], want[[0, 2, 3, 4]], rtol=1e-12)


@pytest.mark.parametrize("sigma_px, sigma_scene, outliers", [
    (True, True, True), (False, False, True), (True, True, False)])
def test_fused_gradient_is_the_general_paths(sigma_px, sigma_scene, outliers, monkeypatch):
    """The gradient from the fused modes and outlier probabilities against the general
    path's (laplace's modes, one more step); its value exactly log_marginal's."""
    from bayescal.likelihood import point_algebra

    lik, psi, q0 = _case(sigma_px, sigma_scene, outliers, "jeffreys")
    value, grad = lik.grad_log_marginal(psi, q0, n_iter=2)
    np.testing.assert_array_equal(value, lik.log_marginal(psi, q0, n_iter=2))
    monkeypatch.setattr(point_algebra, "_fused_applies", lambda *a: False)
    v_gen, g_gen = lik.grad_log_marginal(psi, q0, n_iter=2)
    np.testing.assert_allclose(value, v_gen, rtol=1e-12)
    # the same modes to rounding: the gradient's terms agree to ~1e-9 of the largest
    scale = np.max(np.abs(g_gen), axis=1, keepdims=True)
    assert np.all(np.abs(grad - g_gen) < 1e-7 * scale), (grad - g_gen) / scale
