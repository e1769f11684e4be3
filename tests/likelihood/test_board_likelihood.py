"""The board likelihood: Woodbury products and log-determinants against dense algebra,
and the pose-integrated likelihood against a dense Laplace computation."""

import numpy as np

import bayescal as bc
from bayescal.likelihood.boards import BoardLikelihood


def _dense_cov(lik, k, s2, t2):
    n = lik.n_obs[k]
    B = lik.B[k, :n]
    return s2 * np.eye(n) + t2 * B @ B.T


def test_woodbury_products_match_dense(rng):
    views, truth = bc.simulate_views(n_views=3, rng=rng)
    views[1] = views[1].subset(np.arange(30))            # a shorter, padded view
    lik = BoardLikelihood(views, degree=2)
    s2, t2 = np.array([0.04, 0.09, 0.02]), 0.03
    Ninv, logdet = lik.noise_factors(s2, t2)
    G = rng.normal(size=(3, 2 * lik.M, 4)) * np.repeat(lik.mask, 2, axis=1)[..., None]
    P = lik.products(G, s2, t2, Ninv)
    for k in range(3):
        n = lik.n_obs[k]
        S = _dense_cov(lik, k, s2[k], t2)
        np.testing.assert_allclose(P[k], G[k, :n].T @ np.linalg.solve(S, G[k, :n]), rtol=1e-10)
        np.testing.assert_allclose(logdet[k], np.linalg.slogdet(S)[1], rtol=1e-12)


def test_pose_laplace_matches_dense_gaussian_integral(rng):
    """At the pose's mode the Laplace value is the Gaussian integral of the linearised model."""
    views, truth = bc.simulate_views(n_views=2, rng=rng)
    lik = BoardLikelihood(views)
    k = truth["intrinsics"]
    s2, t2 = np.array([0.05, 0.08]), 0.02
    lm, poses = lik.pose_laplace(k, truth["poses"], s2, t2, n_steps=6)
    r, _, Jp = lik.residuals(k, poses, jacobian=True)
    for j in range(2):
        S = _dense_cov(lik, j, s2[j], t2)
        W = np.linalg.inv(S)
        H = Jp[j].T @ W @ Jp[j]
        n = lik.n_obs[j]
        ref = -0.5 * (r[j] @ W @ r[j] + np.linalg.slogdet(S)[1] + np.linalg.slogdet(H)[1]
                      + (n - 6) * np.log(2 * np.pi))
        assert abs(lm[j] - ref) < 1e-6
        assert np.max(np.abs(Jp[j].T @ W @ r[j])) < 1e-6          # a mode: zero gradient
