"""The point draws' closed-form Cholesky factor of the inverse precision."""

import numpy as np
import pytest

from bayescal.likelihood.point_draws import chol_of_inverse


@pytest.mark.parametrize("k", [1, 2, 3])
def test_chol_of_inverse_matches_numpy(k):
    rng = np.random.default_rng(0)
    A = rng.normal(size=(5, 7, k, k))
    C = A @ np.swapaxes(A, -1, -2) + 0.1 * np.eye(k)
    ref = np.linalg.cholesky(np.linalg.inv(C))
    # rounding only: the closed form and LAPACK agree to ~1e-12 relative
    np.testing.assert_allclose(chol_of_inverse(C), ref, rtol=1e-9, atol=1e-12)


def test_chol_of_inverse_is_nan_where_not_positive_definite():
    C = np.array([[[1.0, 2.0], [2.0, 1.0]]])             # indefinite
    assert np.all(np.isnan(chol_of_inverse(C)[0, 1, 1]))


def _laser_case(sigma_px, sigma_scene, outliers, point_prior):
    """A 70-point room's likelihood with the Jeffreys prior off its reference noise, five
    globals near the truth and a start 2 mm off the approximate points."""
    import bayescal as bc
    from bayescal.likelihood.points import LaserLikelihood

    ds = bc.simulate_room(range_mm=1500, n_points=70, sigma_px=0.3, approx_error=0.03,
                          approx_model="fig9", rng=11)
    lik = LaserLikelihood(ds.pixels, ds.approx_points, outliers=outliers,
                          point_prior=point_prior, sigma_px=ds.sigma_px if sigma_px else None,
                          sigma_scene=np.maximum(ds.sigma_scene, 1.0) if sigma_scene else None)
    lik.set_reference_noise(sigma_px=0.25, kappa=0.04)
    theta = ds.params.to_identifiable()
    extra = [np.log(0.3)] * (not sigma_px) + [np.log(0.03)] * (not sigma_scene) \
        + [-3.0] * outliers
    rng = np.random.default_rng(0)
    psi = np.concatenate([theta, extra]) * (1 + 1e-3 * rng.standard_normal((5, 7 + len(extra))))
    return lik, psi, lik.initial_q(theta) + 2.0


_CASES = [(True, True, False, "jeffreys"), (True, True, True, "jeffreys"),
          (False, True, True, "jeffreys"), (True, False, True, "jeffreys"),
          (False, False, False, "flat")]


@pytest.mark.parametrize("sigma_px, sigma_scene, outliers, point_prior", _CASES)
def test_fused_draw_terms_are_laplaces_and_the_exact_densitys(sigma_px, sigma_scene, outliers,
                                                               point_prior):
    from bayescal.likelihood.point_draws import draw_log_density, draw_proposal

    lik, psi, q0 = _laser_case(sigma_px, sigma_scene, outliers, point_prior)
    _, qm, C = lik.laplace(psi, q0, n_iter=1)
    x, y, (c00, c01, c11) = draw_proposal(lik, psi, q0, 1)
    # the same Gauss-Newton step in another order of operations: rounding only
    np.testing.assert_allclose(np.stack([x, y], -1), qm, rtol=1e-12, atol=1e-9)
    np.testing.assert_allclose(np.stack([c00, c01, c11], -1),
                               C[..., [0, 0, 1], [0, 1, 1]], rtol=1e-10, atol=1e-12)
    # the density up to a constant per (sample, point): differences between two q agree
    rng = np.random.default_rng(1)
    q1, q2 = (qm + rng.normal(0.0, 2.0, qm.shape) for _ in range(2))
    want = lik.point_log_density(psi, q1) - lik.point_log_density(psi, q2)
    got = draw_log_density(lik, psi, q1[..., 0], q1[..., 1]) \
        - draw_log_density(lik, psi, q2[..., 0], q2[..., 1])
    assert np.all(np.isfinite(want))
    np.testing.assert_allclose(got, want, rtol=1e-9, atol=1e-9)


@pytest.mark.parametrize("sigma_px, sigma_scene, outliers, point_prior", _CASES)
def test_stepped_proposal_has_the_next_mode_and_the_last_precision(sigma_px, sigma_scene,
                                                                   outliers, point_prior):
    """The sampler's one-pass proposal: laplace(n_iter=1)'s mode, laplace(n_iter=0)'s
    precision (the outlier mixture's scaling included), and exact draws all the same."""
    from bayescal.likelihood import point_draws
    from bayescal.likelihood.point_draws import draw_proposal

    lik, psi, q0 = _laser_case(sigma_px, sigma_scene, outliers, point_prior)
    _, q1, _ = lik.laplace(psi, q0, n_iter=1)
    _, _, C0 = lik.laplace(psi, q0, n_iter=0)
    x, y, (c00, c01, c11) = draw_proposal(lik, psi, q0, 1, stepped=True)
    np.testing.assert_allclose(np.stack([x, y], -1), q1, rtol=1e-12, atol=1e-9)
    np.testing.assert_allclose(np.stack([c00, c01, c11], -1),
                               C0[..., [0, 0, 1], [0, 1, 1]], rtol=1e-10, atol=1e-12)
    q, acc = point_draws.draw_points(lik, psi, q0, np.random.default_rng(3), n_mh=1,
                                     n_iter=1, stepped=True)
    assert q.shape == psi.shape[:1] + q0.shape and np.all(np.isfinite(q)) and acc > 0.5


@pytest.mark.parametrize("sigma_px, sigma_scene, outliers, point_prior", _CASES[1:3])
def test_fused_draws_are_the_generic_ones(monkeypatch, sigma_px, sigma_scene, outliers,
                                          point_prior):
    from bayescal.likelihood import point_draws

    lik, psi, q0 = _laser_case(sigma_px, sigma_scene, outliers, point_prior)
    fused = point_draws.draw_points(lik, psi, q0, np.random.default_rng(3), n_mh=2, n_iter=1,
                                    batch=2)
    monkeypatch.setattr(point_draws, "draw_proposal", lambda *args, **kw: None)   # laplace's way
    generic = point_draws.draw_points(lik, psi, q0, np.random.default_rng(3), n_mh=2,
                                      n_iter=1, batch=2)
    # the same random numbers, the same acceptances: the same draws to rounding
    assert fused[1] == generic[1]
    np.testing.assert_allclose(fused[0], generic[0], rtol=0, atol=1e-9)


@pytest.mark.parametrize("sigma_px, sigma_scene, outliers, point_prior", _CASES[1:4])
def test_fused_outlier_probs_are_the_likelihoods(sigma_px, sigma_scene, outliers, point_prior):
    from bayescal.likelihood.point_algebra import outlier_probs

    lik, psi, q0 = _laser_case(sigma_px, sigma_scene, outliers, point_prior)
    lik.pixels[3] += 15.0                                # an outlier: r near 1 there
    q = np.broadcast_to(q0, (len(psi),) + q0.shape) + np.random.default_rng(2).normal(
        0.0, 1.0, (len(psi),) + q0.shape)
    want = lik.outlier_prob(psi, q)
    got = outlier_probs(lik, psi, q, 4)
    assert np.all(want[:, 3] > 0.5)
    # the same Gauss-Newton steps and mixture: rounding only
    np.testing.assert_allclose(got, want, rtol=1e-9, atol=1e-12)
