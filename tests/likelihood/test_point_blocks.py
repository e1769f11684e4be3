"""The likelihood's cache-sized point blocks: the same numbers as one pass over all points."""

import numpy as np
import pytest

import bayescal as bc
from bayescal.likelihood import point_blocks
from bayescal.likelihood.points import LaserLikelihood


@pytest.fixture
def small_blocks(monkeypatch):
    """Blocks of 16 points whatever the walkers (the real ones are ~2000 points)."""
    monkeypatch.setattr(point_blocks, "BLOCK_ELEMENTS", 16)
    monkeypatch.setattr(point_blocks, "MIN_BLOCK", 16)


def _case(sigma_px, sigma_scene, outliers):
    ds = bc.simulate_room(range_mm=1500, n_points=70, sigma_px=0.3, approx_error=0.03,
                          approx_model="gaussian", rng=11)
    lik = LaserLikelihood(ds.pixels, ds.approx_points, outliers=outliers,
                          sigma_px=ds.sigma_px if sigma_px else None,
                          sigma_scene=ds.sigma_scene if sigma_scene else None)
    theta = ds.params.to_identifiable()
    extra = [np.log(0.3)] * (not sigma_px) + [np.log(0.03)] * (not sigma_scene) \
        + [-3.0] * outliers
    rng = np.random.default_rng(0)
    psi = np.concatenate([theta, extra]) * (1 + 1e-4 * rng.standard_normal((5, 7 + len(extra))))
    return lik, psi, lik.initial_q(theta) + 2.0


@pytest.mark.parametrize("sigma_px, sigma_scene, outliers",
                         [(True, True, False), (False, True, True), (True, False, True)])
def test_blocks_give_the_one_pass_numbers(small_blocks, sigma_px, sigma_scene, outliers):
    lik, psi, q0 = _case(sigma_px, sigma_scene, outliers)
    blocks = point_blocks.point_blocks(lik, len(psi))
    assert len(blocks) == 5                                       # 70 points, 16 per block
    assert [b[1].n for b in blocks] == [16, 16, 16, 16, 6]
    ll_b, q_b, C_b = lik.laplace(psi, q0, n_iter=2)
    v_b, g_b = lik.grad_log_marginal(psi, q0, n_iter=2)
    m_b = lik.log_marginal(psi, q0, n_iter=2)
    d_b = lik.point_log_density(psi, q_b)
    point_blocks.clear_blocks(lik)
    with pytest.MonkeyPatch.context() as mp:
        mp.setattr(point_blocks, "MIN_BLOCK", 10**6)
        assert len(point_blocks.point_blocks(lik, len(psi))) == 1
        ll, q, C = lik.laplace(psi, q0, n_iter=2)
        v, g = lik.grad_log_marginal(psi, q0, n_iter=2)
        d = lik.point_log_density(psi, q)
    np.testing.assert_allclose(ll_b, ll, rtol=1e-12)
    np.testing.assert_allclose(m_b, ll, rtol=1e-12)
    np.testing.assert_allclose(v_b, v, rtol=1e-12)
    np.testing.assert_allclose(g_b, g, rtol=1e-9, atol=1e-9)
    np.testing.assert_array_equal(q_b, q)
    np.testing.assert_array_equal(C_b, C)
    np.testing.assert_allclose(d_b, d, rtol=1e-12)


def test_new_reference_noise_reaches_the_blocks(small_blocks):
    """set_reference_noise after the blocks were made: they must not keep the old level."""
    lik, psi, q0 = _case(False, True, False)
    before = lik.log_marginal(psi, q0, n_iter=2)
    lik.set_reference_noise(sigma_px=0.7)
    after = lik.log_marginal(psi, q0, n_iter=2)
    point_blocks.clear_blocks(lik)
    with pytest.MonkeyPatch.context() as mp:
        mp.setattr(point_blocks, "MIN_BLOCK", 10**6)
        one_pass = lik.log_marginal(psi, q0, n_iter=2)
    assert not np.allclose(after, before)
    np.testing.assert_allclose(after, one_pass, rtol=1e-12)


def test_block_size_is_a_power_of_two_at_least_the_minimum():
    assert point_blocks._block_size(24) == 2048
    assert point_blocks._block_size(1) == 32768
    assert point_blocks._block_size(10**6) == point_blocks.MIN_BLOCK
