"""An emcee move for near-Gaussian posteriors: independence Metropolis-Hastings.

Every walker proposes a fresh point from a fixed multivariate Student-t
``t_df(mean, scale^2 * cov)`` and accepts it with the Metropolis-Hastings ratio
``p(x') q(x) / (p(x) q(x'))``. The move is exact for any fixed proposal; when
the proposal resembles the posterior (here: mean and covariance estimated from
a burn-in run with emcee's own moves, then frozen) acceptance is high and the
autocorrelation time is a few steps instead of tens. The heavy Student-t tails
keep the ratio bounded where the posterior has heavier tails than a Gaussian.

The sampler mixes it with :class:`emcee.moves.DEMove` (see
:func:`bayescal.sampling.default_moves`); both are tested on N(0, I).
"""

from __future__ import annotations

import numpy as np
from emcee.moves import MHMove
from scipy.special import gammaln

__all__ = ["IndependenceMove"]


class IndependenceMove(MHMove):
    """Independence Metropolis-Hastings move with a multivariate Student-t proposal.

    Parameters
    ----------
    mean : array_like, shape (ndim,)
    cov : array_like, shape (ndim, ndim)
        Proposal covariance before ``scale``; must be positive definite.
    df : float, optional
        Degrees of freedom of the Student-t (default 5).
    scale : float, optional
        Inflation of the proposal's spread (default 1.2).
    """

    def __init__(self, mean, cov, *, df=5.0, scale=1.2):
        mean = np.asarray(mean, dtype=float)
        cov = np.asarray(cov, dtype=float)
        ndim = len(mean)
        if cov.shape != (ndim, ndim):
            raise ValueError(f"cov must have shape {(ndim, ndim)}, got {cov.shape}")
        if not df > 0:
            raise ValueError(f"df must be positive, got {df!r}")
        try:
            self._L = np.linalg.cholesky(cov) * float(scale)
        except np.linalg.LinAlgError:
            raise ValueError("cov must be symmetric positive definite") from None
        self._Linv = np.linalg.inv(self._L)
        self.mean, self.df, self.ndim_ = mean, float(df), ndim
        super().__init__(self._propose, ndim=ndim)

    def log_q(self, x):
        """Log density of the proposal (up to a constant), x shape (..., ndim)."""
        z = (np.asarray(x) - self.mean) @ self._Linv.T
        m = np.sum(z * z, axis=-1)
        return -0.5 * (self.df + self.ndim_) * np.log1p(m / self.df)

    def sample(self, n, random):
        """Draw ``n`` proposals with a legacy RandomState ``random`` (emcee's)."""
        z = random.randn(n, self.ndim_)
        w = random.chisquare(self.df, size=n) / self.df
        return self.mean + (z / np.sqrt(w)[:, None]) @ self._L.T

    def _propose(self, x0, random):
        x1 = self.sample(len(x0), random)
        return x1, self.log_q(x0) - self.log_q(x1)

    def log_norm(self):
        """Log normalising constant of the proposal (for tests)."""
        d, v = self.ndim_, self.df
        return (gammaln((v + d) / 2) - gammaln(v / 2) - 0.5 * d * np.log(v * np.pi)
                - np.sum(np.log(np.diag(self._L))))
