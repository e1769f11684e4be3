"""Draws of every laser point's latent coordinates given samples of the globals.

The collapsed sampler integrates the points out; after it, each point is drawn
from its conditional given each sample of ``psi``: the Laplace Gaussian of
:meth:`~bayescal.likelihood.points.LaserLikelihood.laplace` as an independence proposal,
corrected by Metropolis-Hastings against the likelihood's exact conditional
density. Shared by the sampler and :meth:`bayescal.Posterior.reconstruct`.
"""

from __future__ import annotations

import numpy as np

__all__ = ["draw_points", "chol_of_inverse", "DRAW_ELEMENTS"]

#: (sample, point) pairs per vectorized call of the point draws: small enough that the
#: temporaries of the likelihood's pass stay in cache (at N = 580, 2000 samples: 2.2 s in
#: batches of 83 samples against 3.0 s in batches of 862, docs/performance.md)
DRAW_ELEMENTS = 48_000


def chol_of_inverse(C):
    """Lower Cholesky factor of ``inv(C)`` for stacked SPD matrices ``C`` (..., k, k).

    Closed form for k = 1 and k = 2 (the points' latent dimensions: an azimuth, or
    (x, y)): ~15x faster than ``np.linalg.cholesky(np.linalg.inv(C))``, which loops
    over the stack in C; the general case otherwise. NaN where ``C`` is not SPD.
    """
    C = np.asarray(C, dtype=float)
    k = C.shape[-1]
    with np.errstate(invalid="ignore", divide="ignore"):
        if k == 1:
            return 1.0 / np.sqrt(C)
        if k == 2:
            a, b, c = C[..., 0, 0], C[..., 0, 1], C[..., 1, 1]
            det = a * c - b * b
            l00 = np.sqrt(c / det)                      # inv(C) = [[c, -b], [-b, a]] / det
            l10 = -b / det / l00
            L = np.zeros(C.shape)
            L[..., 0, 0] = l00
            L[..., 1, 0] = l10
            L[..., 1, 1] = np.sqrt(a / det - l10 * l10)
            return L
    return np.linalg.cholesky(np.linalg.inv(C))


def draw_points(lik, psi, q_start, rng, *, n_mh, n_iter, batch=None):
    """Draw every point's latent coordinates given each sample of the globals.

    Each point is drawn from its Laplace Gaussian ``N(q*, C^-1)`` (from
    ``lik.laplace``), then corrected by ``n_mh`` independence Metropolis-Hastings
    steps against the exact conditional ``lik.point_log_density`` (the Gaussian
    as proposal), so a non-Gaussian conditional is still sampled correctly.
    Works for any likelihood of the collapsed-sampler protocol and any per-point
    latent dimension k.

    Parameters
    ----------
    lik : likelihood
        Provides ``n``, ``laplace`` and ``point_log_density``.
    psi : ndarray, shape (S, d)
        Samples of the globals (theta then extras).
    q_start : ndarray, shape (N, k)
        Start of the Gauss-Newton steps.
    rng : numpy.random.Generator
    n_mh : int
        Independence Metropolis-Hastings corrections per draw.
    n_iter : int
        Gauss-Newton iterations.
    batch : int, optional
        Samples per vectorized call (memory: batch x N x k x k floats; default
        ``DRAW_ELEMENTS / N``, at least 1: cache-sized).

    Returns
    -------
    q : ndarray, shape (S, N, k)
    acceptance : float
        Mean acceptance of the corrections (NaN when ``n_mh = 0``).
    """
    S = len(psi)
    k = np.shape(q_start)[-1]
    batch = max(1, DRAW_ELEMENTS // max(lik.n, 1)) if batch is None else int(batch)
    out = np.empty((S, lik.n, k))
    acc = []
    for lo in range(0, S, batch):
        p = psi[lo:lo + batch]
        _, qm, C = lik.laplace(p, q_start, n_iter=n_iter)
        L = chol_of_inverse(C)                                           # (b, N, k, k)
        q, lg = _gauss_draw(qm, L, rng)
        lp = lik.point_log_density(p, q)
        for _ in range(n_mh):
            q2, lg2 = _gauss_draw(qm, L, rng)
            lp2 = lik.point_log_density(p, q2)
            log_r = (lp2 - lg2) - (lp - lg)
            accept = np.log(rng.random(log_r.shape)) < log_r
            q = np.where(accept[..., None], q2, q)
            lp = np.where(accept, lp2, lp)
            lg = np.where(accept, lg2, lg)
            acc.append(accept.mean())
        # no draw inside the model's domain (e.g. an outlier's wide azimuth off its wall):
        # the Laplace mode, so that every point sample stays finite
        out[lo:lo + batch] = np.where(np.isfinite(lp)[..., None], q, qm)
    return out, float(np.mean(acc)) if acc else float("nan")


def _gauss_draw(mean, L, rng):
    """Draw from N(mean, L L^T) per point; returns the draw and its log density + const."""
    z = rng.standard_normal(mean.shape)
    return mean + np.einsum("...ij,...j->...i", L, z), -0.5 * np.sum(z * z, axis=-1)
