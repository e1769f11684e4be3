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


def test_log_marginal_is_pose_laplace_with_one_step(rng):
    """The cheap path (local pose coordinates, SVD of the field basis) gives the same number
    as one Gauss-Newton step of :meth:`pose_laplace`, over walkers, padded views and both
    noise models (rounding only: 1e-8 on values ~100)."""
    views, truth = bc.simulate_views(n_views=3, rng=rng)
    views[2] = views[2].subset(np.arange(25))
    lik = BoardLikelihood(views)
    W = 4
    k = truth["intrinsics"] + rng.normal(size=(W, 5)) * [0.002, 1, 1, 1, 1]
    poses = truth["poses"] + rng.normal(size=(W, 3, 6)) * np.r_[[0.01] * 3, [1.0] * 3]
    s2 = rng.uniform(0.02, 0.1, size=(W, 3))
    for t2 in (np.zeros(W), rng.uniform(0.001, 0.01, size=W)):
        ref, _ = lik.pose_laplace(k, poses, s2, t2, n_steps=1)
        np.testing.assert_allclose(lik.log_marginal(k, poses, s2, t2), ref, rtol=0, atol=1e-8)
