"""Draws of every laser point's latent coordinates given samples of the globals.

The collapsed sampler integrates the points out; after it, each point is drawn
from its conditional given each sample of ``psi``: the Laplace Gaussian of
:meth:`~bayescal.likelihood.points.LaserLikelihood.laplace` as an independence proposal,
corrected by Metropolis-Hastings against the likelihood's exact conditional
density. Shared by the sampler and :meth:`bayescal.Posterior.reconstruct`.
"""

from __future__ import annotations

import numpy as np
from scipy.special import log_expit

from .point_algebra import _fused_applies, _fused_newton, _fused_terms, _mix_sum, _noise_setup

__all__ = ["draw_points", "chol_of_inverse", "draw_proposal", "draw_log_density",
           "DRAW_ELEMENTS"]

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
            L = np.zeros(C.shape)
            L[..., 0, 0], L[..., 1, 0], L[..., 1, 1] = _chol_of_inverse2(
                C[..., 0, 0], C[..., 0, 1], C[..., 1, 1])
            return L
    return np.linalg.cholesky(np.linalg.inv(C))


def draw_points(lik, psi, q_start, rng, *, n_mh, n_iter, batch=None, stepped=False):
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
    stepped : bool, optional
        Where the fused passes apply: the proposal's precision one Gauss-Newton step
        before its mode (``n_iter`` passes in place of ``n_iter + 1``;
        :func:`draw_proposal`).

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
        qm, draw, density, first = _proposal(lik, p, q_start, n_iter, stepped)
        q, lg = draw(rng)
        lp = density(q)
        for _ in range(n_mh):
            q2, lg2 = draw(rng)
            lp2 = density(q2)
            log_r = (lp2 - lg2) - (lp - lg)
            accept = np.log(rng.random(log_r.shape)) < log_r
            q = np.where(_along(accept, first), q2, q)
            lp = np.where(accept, lp2, lp)
            lg = np.where(accept, lg2, lg)
            acc.append(accept.mean())
        # no draw inside the model's domain (e.g. an outlier's wide azimuth off its wall):
        # the Laplace mode, so that every point sample stays finite
        finite = np.isfinite(lp)
        if not finite.all():
            q = np.where(_along(finite, first), q, qm())
        out[lo:lo + batch] = np.moveaxis(q, 0, -1) if first else q
    return out, float(np.mean(acc)) if acc else float("nan")


def _along(mask, first):
    """``mask`` (b, N) broadcast against points (k, b, N) (``first``) or (b, N, k)."""
    return mask[None] if first else mask[..., None]


def _proposal(lik, psi, q_start, n_iter, stepped=False):
    """The Laplace proposal of one batch: a function giving its mean (rarely needed), a draw
    function (``rng`` -> draws and their log density up to a constant), the target's log
    density up to a constant per (sample, point), and whether the points' coordinates come
    first (k, b, N) in place of last (b, N, k). The aligned cone's in fused passes on
    contiguous coordinates (:func:`draw_proposal`: 2x faster at N = 600, the same draws to
    rounding), any other likelihood's from ``laplace`` and ``point_log_density``."""
    # the fused passes are the per-point likelihood's (points.LaserLikelihood), which sums
    # its marginal by them too
    fused = draw_proposal(lik, psi, q_start, n_iter, stepped=stepped) \
        if callable(getattr(lik, "_marginal_block", None)) else None
    if fused is None:
        _, qm, C = lik.laplace(psi, q_start, n_iter=n_iter)
        L = chol_of_inverse(C)                                           # (b, N, k, k)
        return (lambda: qm), (lambda rng: _gauss_draw(qm, L, rng)), \
            (lambda q: lik.point_log_density(psi, q)), False
    x, y, C = fused
    L = _chol_of_inverse2(*C)
    return (lambda: np.stack([x, y])), (lambda rng: _gauss_draw2(x, y, L, rng)), \
        (lambda q: draw_log_density(lik, psi, q[0], q[1])), True


def _chol_of_inverse2(a, b, c):
    """:func:`chol_of_inverse` of 2x2 matrices ``[[a, b], [b, c]]`` given as their entries:
    ``(l00, l10, l11)``."""
    with np.errstate(invalid="ignore", divide="ignore"):
        det = a * c - b * b
        l00 = np.sqrt(c / det)                      # inv(C) = [[c, -b], [-b, a]] / det
        l10 = -b / det / l00
        return l00, l10, np.sqrt(a / det - l10 * l10)


def _gauss_draw2(x, y, L, rng):
    """:func:`_gauss_draw` with the mean as ``(x, y)`` and ``L`` as ``(l00, l10, l11)``; the
    draw as (2, b, N) (the same random numbers as :func:`_gauss_draw`'s)."""
    z = rng.standard_normal(x.shape + (2,))
    z0, z1 = z[..., 0], z[..., 1]
    q = np.empty((2,) + x.shape)
    np.multiply(L[0], z0, out=q[0])
    q[0] += x
    np.multiply(L[1], z0, out=q[1])
    q[1] += L[2] * z1
    q[1] += y
    return q, -0.5 * (z0 * z0 + z1 * z1)


def _gauss_draw(mean, L, rng):
    """Draw from N(mean, L L^T) per point; returns the draw and its log density + const."""
    z = rng.standard_normal(mean.shape)
    return mean + np.einsum("...ij,...j->...i", L, z), -0.5 * np.sum(z * z, axis=-1)


def _draw_setup(lik, psi):
    """:func:`_noise_setup` of ``psi`` (W, d) and its ``extra``, for the point draws."""
    psi = np.asarray(psi, dtype=float)
    extra = psi[:, 7:]
    sig = np.exp(extra[:, 0]) if lik.infer_px else np.full(len(psi), lik.sigma_px)
    return _noise_setup(lik, psi[:, :7], extra, sig), extra


def draw_proposal(lik, psi, q0, n_iter, *, stepped=False):
    """The point draws' Laplace proposal of the aligned cone in fused passes: the modes
    ``(x, y)`` (W, N) and precisions ``(C00, C01, C11)`` (W, N) of
    :meth:`~bayescal.likelihood.points.LaserLikelihood.laplace` (``q`` and ``C``, the
    outlier mixture's moment-matched scaling included); ``None`` where the fused passes do
    not apply (:func:`_fused_applies`). ``psi`` (W, d), ``q0`` (N, 2) or (W, N, 2).

    ``stepped``: the mode of ``laplace(n_iter=n_iter)`` with the precision of
    ``laplace(n_iter=n_iter - 1)``, in ``n_iter`` passes in place of ``n_iter + 1``: the
    precision one Gauss-Newton step before the mode (``n_iter`` >= 1). With ``n_iter`` 1 the
    pass is on the shared start's (N,) arrays, a third of the draws' work saved; the
    draws' Metropolis-Hastings corrections accepted as many (0.9988 and 0.979 either way on
    the 1000 mm z-known and 5000 mm rooms, docs/performance.md)."""
    if not _fused_applies(lik, psi, q0):
        return None
    q0 = np.asarray(q0, dtype=float)
    with np.errstate(invalid="ignore", divide="ignore", over="ignore"):
        s, extra = _draw_setup(lik, psi)
        g = _fused_newton(s["p"], s["c"], q0[..., 0], q0[..., 1], s["w"],
                          n_iter - bool(stepped), False)
        if stepped:                             # the mode one step on from the last pass
            g["x"], g["y"] = g["x"] - g["d"][0], g["y"] - g["d"][1]
        C = g["C"]
        if lik.outliers:
            r = _mix_sum(extra[:, -1], g["m"], lik._n_rows, lik.outlier_scale, True)[1]
            f = 1.0 / ((1.0 - r) + r * lik.outlier_scale**2)
            C = tuple(ci * f for ci in C)
    shape = (len(extra), lik.n)
    return np.broadcast_to(g["x"], shape), np.broadcast_to(g["y"], shape), C


def draw_log_density(lik, psi, x, y):
    """Each point's exact log density of ``(x, y)`` (W, N) given ``psi`` (W, d) for the
    aligned cone (where :func:`draw_proposal` applies), up to a constant per (walker,
    point): :meth:`~bayescal.likelihood.points.LaserLikelihood.point_log_density` without
    its normalisers, which cancel in the draws' Metropolis-Hastings ratios; ``-inf``
    outside the model's domain."""
    with np.errstate(invalid="ignore", divide="ignore", over="ignore"):
        s, extra = _draw_setup(lik, psi)
        flat = lik.point_prior == "flat"
        rr, _, _, _, parts = _fused_terms(s["p"], s["c"], x, y, s["w"], True, not flat,
                                          grad=False)
        out = -0.5 * rr
        if not flat:                                # the Jeffreys prior at the reference noise
            sp, ss = s["sp"][:, None], s["ss"][:, None]
            c00, c01, c11 = (a * sp + b * ss for a, b in zip(*parts, strict=True))
            out += 0.5 * np.log(c00 * c11 - c01 * c01)
        if lik.outliers:                            # outliers.mix(laplace=False), per point
            scale, lw = lik.outlier_scale, extra[:, -1:]
            delta = rr * (0.5 * (1.0 - 1.0 / scale**2)) - lik._n_rows * np.log(scale)
            out += np.logaddexp(log_expit(-lw), log_expit(lw) + delta)
    return np.where(np.isfinite(out), out, -np.inf)
