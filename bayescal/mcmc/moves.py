"""An emcee move for near-Gaussian posteriors: independence Metropolis-Hastings.

Every walker proposes a fresh point from a fixed multivariate Student-t
``t_df(mean, scale^2 * cov)`` and accepts it with the Metropolis-Hastings ratio
``p(x') q(x) / (p(x) q(x'))``. The move is exact for any fixed proposal; when
the proposal resembles the posterior (here: mean and covariance estimated from
a burn-in run with emcee's own moves, then frozen) acceptance is high and the
autocorrelation time is a few steps instead of tens. The heavy Student-t tails
keep the ratio bounded where the posterior has heavier tails than a Gaussian.

The sampler mixes it with :class:`emcee.moves.DEMove` (see
:func:`bayescal.mcmc.sampling.default_moves`); both are tested on N(0, I).

:class:`HMCMove` is Hamiltonian Monte Carlo per walker, vectorized over the
walkers (one gradient call per leapfrog step for the whole ensemble), with the
tuned covariance as inverse mass matrix. It follows curved ridges where no fixed
proposal fits (``docs/bayes.md`` section 3). Leapfrog with any position-only
force is reversible and volume-preserving, so the move is exact even where the
gradient is approximate; only its acceptance suffers.
"""

from __future__ import annotations

import numpy as np
from emcee.moves import MHMove, Move
from emcee.state import State
from scipy.special import gammaln

from ..errors import InvalidValueError

__all__ = ["IndependenceMove", "HMCMove"]


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
            raise InvalidValueError(f"cov must have shape {(ndim, ndim)}, got {cov.shape}")
        if not df > 0:
            raise InvalidValueError(f"df must be positive, got {df!r}")
        try:
            self._L = np.linalg.cholesky(cov) * float(scale)
        except np.linalg.LinAlgError:
            raise InvalidValueError("cov must be symmetric positive definite") from None
        self._Linv = np.linalg.inv(self._L)
        self.mean, self.df, self.ndim_ = mean, float(df), ndim
        self.n_proposed, self.n_accepted = 0, 0
        super().__init__(self._propose, ndim=ndim)

    @property
    def acceptance(self):
        """Fraction of this move's proposals accepted so far (NaN before any)."""
        return self.n_accepted / self.n_proposed if self.n_proposed else float("nan")

    def propose(self, model, state):
        """emcee's Metropolis-Hastings step, counting this move's acceptance."""
        state, accepted = super().propose(model, state)
        self.n_proposed += len(accepted)
        self.n_accepted += int(np.sum(accepted))
        return state, accepted

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


class HMCMove(Move):
    """Hamiltonian Monte Carlo for every walker, vectorized over the ensemble.

    Each call draws a momentum per walker, runs ``n_steps`` leapfrog steps of
    size ``step_size`` (times a uniform jitter ``1 +- jitter`` per walker, which
    avoids periodic trajectories) and accepts each walker's end point with
    probability ``min(1, exp(-dH))``. The kinetic energy is ``p^T cov p / 2``:
    in coordinates whitened by ``cov`` the walkers move with unit mass.

    Parameters
    ----------
    value_and_grad : callable
        ``value_and_grad(x)`` with ``x`` (W, ndim) returns the log density (W,)
        (the same function the sampler targets) and its gradient (W, ndim).
    cov : array_like, shape (ndim, ndim)
        Inverse mass matrix (the posterior covariance estimate).
    step_size : float, optional
        Leapfrog step in whitened units.
    n_steps : int, optional
        Leapfrog steps per move.
    jitter : float, optional
        Relative jitter of the step size, in [0, 1).
    adapt : bool, optional
        Adapt ``step_size`` towards ``target_accept`` after every call
        (Robbins-Monro on its log). Breaks detailed balance: only for tuning
        runs whose chain is discarded; freeze with ``adapt=False`` afterwards.
    target_accept : float, optional
        Acceptance the adaptation aims at.
    """

    def __init__(self, value_and_grad, cov, *, step_size=0.3, n_steps=8, jitter=0.2,
                 adapt=False, target_accept=0.75):
        cov = np.asarray(cov, dtype=float)
        if cov.ndim != 2 or cov.shape[0] != cov.shape[1]:
            raise InvalidValueError(f"cov must be a square matrix, got shape {cov.shape}")
        try:
            self._L = np.linalg.cholesky(cov)
        except np.linalg.LinAlgError:
            raise InvalidValueError("cov must be symmetric positive definite") from None
        if not step_size > 0:
            raise InvalidValueError(f"step_size must be positive, got {step_size!r}")
        if int(n_steps) < 1:
            raise InvalidValueError(f"n_steps must be a positive integer, got {n_steps!r}")
        if not 0 <= jitter < 1:
            raise InvalidValueError(f"jitter must be in [0, 1), got {jitter!r}")
        self.value_and_grad = value_and_grad
        self.step_size, self.n_steps, self.jitter = float(step_size), int(n_steps), float(jitter)
        self.adapt, self.target_accept = bool(adapt), float(target_accept)
        self.n_calls, self.accept_sum = 0, 0.0
        self._cache = None

    @property
    def acceptance(self):
        """Mean acceptance probability over the calls so far."""
        return self.accept_sum / max(self.n_calls, 1)

    def _start(self, x):
        """Log density and gradient at x, reusing the last call's end where x matches."""
        if self._cache is not None and self._cache[0].shape == x.shape:
            cx, clp, cg = self._cache
            same = np.all(cx == x, axis=1)
            if np.all(same):
                return clp, cg
            lp, g = clp.copy(), cg.copy()
            lp[~same], g[~same] = self.value_and_grad(x[~same])
            return lp, g
        return self.value_and_grad(x)

    def propose(self, model, state):
        """One HMC transition of every walker; returns ``(state, accepted)``."""
        x0 = np.array(state.coords, dtype=float)
        W, d = x0.shape
        rnd = model.random
        lp0, g0 = self._start(x0)
        g = g0
        eps = self.step_size * (1.0 + self.jitter * (2.0 * rnd.rand(W, 1) - 1.0))
        r = rnd.randn(W, d)
        h0 = -state.log_prob + 0.5 * np.sum(r * r, axis=1)
        alive = np.isfinite(state.log_prob) & np.all(np.isfinite(g), axis=1)
        g = np.where(alive[:, None], g, 0.0)
        x = x0.copy()
        r = r + 0.5 * eps * (g @ self._L)
        for i in range(self.n_steps):
            x = x + eps * (r @ self._L.T)
            lp, g = self.value_and_grad(x)
            alive &= np.isfinite(lp) & np.all(np.isfinite(g), axis=1)
            g = np.where(alive[:, None], g, 0.0)
            r = r + (eps if i < self.n_steps - 1 else 0.5 * eps) * (g @ self._L)
        with np.errstate(invalid="ignore", over="ignore"):
            log_a = np.where(alive, h0 - (-lp + 0.5 * np.sum(r * r, axis=1)), -np.inf)
            log_a = np.where(np.isnan(log_a), -np.inf, log_a)
        accepted = np.log(rnd.rand(W)) < log_a
        a_mean = float(np.mean(np.exp(np.minimum(log_a, 0.0))))
        self.n_calls += 1
        self.accept_sum += a_mean
        if self.adapt:
            self.step_size *= np.exp(2.0 * (a_mean - self.target_accept) / np.sqrt(self.n_calls))
        new_state = State(x, log_prob=lp)
        state = self.update(state, new_state, accepted)
        self._cache = (np.array(state.coords), np.where(accepted, lp, lp0),
                       np.where(accepted[:, None], g, g0))
        return state, accepted
