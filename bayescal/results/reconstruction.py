"""Reconstructed 3D points with uncertainty: the objects ``result.reconstruct`` returns.

Both unpack as ``mean, covariance``: :class:`Reconstruction` (Monte-Carlo draws
under the posterior) and :class:`LinearReconstruction` (first-order propagation
at the least-squares solution).
"""

from __future__ import annotations

import numpy as np

__all__ = ["Reconstruction", "LinearReconstruction"]


class Reconstruction:
    """Reconstructed 3D points with uncertainty; unpacks as ``mean, covariance``.

    Attributes
    ----------
    mean : ndarray, shape (M, 3)
        Posterior mean of each point, mm.
    covariance : ndarray, shape (M, 3, 3)
        Posterior covariance (parameter uncertainty plus pixel noise), mm^2.
    samples : ndarray, shape (S, M, 3)
        The Monte-Carlo draws behind them.
    level : float
        Credible level of :attr:`intervals`.
    intervals : ndarray, shape (M, 3, 2)
        Equal-tailed per-axis credible intervals, mm.
    valid : ndarray of bool, shape (M,)
        False where (almost) every draw missed the cone.
    """

    def __init__(self, samples, level):
        self.samples = samples
        self.level = level
        self.valid = np.mean(np.isfinite(samples[..., 0]), axis=0) > 0.99
        s = np.where(np.isfinite(samples), samples, np.nan)
        self.mean = np.nanmean(s, axis=0)
        d = s - self.mean
        self.covariance = np.nanmean(d[..., :, None] * d[..., None, :], axis=0)
        lo, hi = (1 - level) / 2, (1 + level) / 2
        self.intervals = np.moveaxis(np.nanquantile(s, [lo, hi], axis=0), 0, -1)

    def __iter__(self):
        return iter((self.mean, self.covariance))


class LinearReconstruction:
    """Points triangulated with first-order uncertainty; unpacks as ``mean, covariance``.

    Attributes
    ----------
    mean : ndarray, shape (M, 3)
        mm (NaN where the ray misses the cone).
    covariance : ndarray, shape (M, 3, 3)
        mm^2.
    """

    def __init__(self, mean, covariance):
        self.mean, self.covariance = mean, covariance

    def __iter__(self):
        return iter((self.mean, self.covariance))
