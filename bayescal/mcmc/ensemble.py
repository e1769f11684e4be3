"""Keeping an ensemble and its proposal usable: a degenerate covariance regularized, a
collapsed ensemble spread again, or a :class:`~bayescal.NotConvergedError` that says why.

A fit that ended on a bound gives a Laplace covariance without a Cholesky factor, and
walkers can collapse onto one point in a tuning round; emcee's moves and emcee itself
then stop with a numpy error. Healthy input passes through untouched (nothing drawn),
so a healthy run's chain is the same with or without these guards.

:func:`prime_allocator` keeps the first run of a process from paying the kernel for its
temporaries (``docs/performance.md``).
"""

from __future__ import annotations

import numpy as np

from ..errors import NotConvergedError

__all__ = ["spd_covariance", "spread_walkers", "prime_allocator", "COV_FLOOR", "PRIME_BYTES"]

#: bytes of the block :func:`prime_allocator` allocates and frees: glibc's malloc then
#: returns up to twice this much freed memory at the top of its heap to the kernel only
#: when more is free. 8 MiB: the first aligned posterior of a process made 9 000 minor page
#: faults (0.0-0.1 s of system time) against 335 000 (0.8 s) unprimed, 283 000 with 1 MiB,
#: 43 000 with 2 MiB (1000 mm z-known room, N = 600); the dynamic threshold's ceiling is
#: 32 MiB (docs/performance.md)
PRIME_BYTES = 8 << 20
_PRIMED = []


#: smallest eigenvalue a proposal covariance keeps, relative to its reference scale
COV_FLOOR = 1e-8


def spd_covariance(cov, fallback=None, *, floor=COV_FLOOR, what="proposal covariance"):
    """A symmetric positive-definite covariance from an estimate that may be degenerate.

    A collapsed ensemble (walkers on one point or one line), a Laplace matrix
    from a fit that ended on a bound, or rounding give a covariance that is
    singular, indefinite or not finite, and a proposal built on it cannot draw.
    A covariance with a Cholesky factor is returned as it is; otherwise the
    ``fallback`` (the previous proposal's) is used when given, else the
    estimate's eigenvalues are clipped from below at ``floor`` times the
    largest.

    Parameters
    ----------
    cov : array_like, shape (d, d)
        The estimate.
    fallback : array_like, shape (d, d), optional
        The covariance to keep when the estimate is unusable.
    floor : float, optional
        Relative eigenvalue floor.
    what : str, optional
        Named in the error message.

    Returns
    -------
    ndarray, shape (d, d)

    Raises
    ------
    NotConvergedError
        Neither the estimate nor the fallback is usable (not finite, or no
        positive direction at all).
    """
    cov = np.asarray(cov, dtype=float)
    if np.all(np.isfinite(cov)):
        try:
            np.linalg.cholesky(cov)
            return cov
        except np.linalg.LinAlgError:
            pass
    if fallback is not None:
        return spd_covariance(fallback, floor=floor, what=what)
    if not np.all(np.isfinite(cov)):
        raise NotConvergedError(f"the {what} is not finite: the start (the least-squares fit "
                                "or the walkers) is degenerate; check the fit for parameters "
                                "on a bound and for flagged rows")
    e, V = np.linalg.eigh(0.5 * (cov + cov.T))
    if not e[-1] > 0:
        raise NotConvergedError(f"the {what} has no positive direction (the walkers "
                                "collapsed onto one point): the sampler cannot propose")
    out = (V * np.maximum(e, floor * e[-1])) @ V.T
    return 0.5 * (out + out.T)


def spread_walkers(state, target, cov, rng, *, max_tries=20):
    """Walkers an ensemble can move: a collapsed ensemble is re-drawn around its mean.

    Walkers that collapsed onto one point (or onto fewer dimensions than the
    target has) cannot propose along the lost directions, and emcee refuses to
    start from them. Such an ensemble is replaced by draws around its mean with
    ``cov`` (shrunk tenfold at each try until every draw has a finite target
    density); a healthy ensemble is returned as it is, drawing nothing.

    Parameters
    ----------
    state : emcee.State or array_like, shape (W, d)
    target : callable
        Vectorized log density, (W, d) -> (W,).
    cov : array_like, shape (d, d)
        Spread of the new walkers (the current proposal's covariance).
    rng : numpy.random.Generator
    max_tries : int, optional

    Returns
    -------
    emcee.State or ndarray, shape (W, d)

    Raises
    ------
    NotConvergedError
        No spread around the collapsed walkers has a finite density.
    """
    from emcee.ensemble import walkers_independent

    x = np.asarray(getattr(state, "coords", state), dtype=float)
    if walkers_independent(x):
        return state
    center = np.mean(x, axis=0)
    L = np.linalg.cholesky(spd_covariance(cov))
    for k in range(int(max_tries)):
        new = center + (0.1 ** k) * rng.standard_normal(x.shape) @ L.T
        if np.all(np.isfinite(target(new))) and walkers_independent(new):
            return new
    raise NotConvergedError("the walkers collapsed onto one point and no spread around it "
                            "has a finite posterior density: the start is degenerate (check "
                            "the least-squares fit for parameters on a bound)")


def prime_allocator(nbytes=PRIME_BYTES):
    """Raise glibc malloc's trim threshold once per process, as its first large free would.

    The sampler's density evaluations allocate and free numpy temporaries of 10-100 kB
    (walkers x points) thousands of times. glibc's malloc gives the kernel back any free
    space above 128 kB at the top of its heap (its initial trim threshold), so each
    evaluation grew the heap again page by page, each page zero-filled by the kernel: the
    first posterior of a process made ~8000 ``brk`` calls and 335 000 minor page faults,
    0.8-1.0 s of system time in a call of 2.1 s of CPU (1000 mm z-known room, N = 600).
    Freeing a block that malloc had mapped by itself raises the trim threshold to twice the
    block's size (glibc's dynamic mmap threshold, up to 32 MiB): later calls of a process
    did not pay this, because the point draws at the end of the first call free blocks of
    1-19 MB. This allocates and frees ``nbytes`` at once, untouched (no page is ever
    written), so the first call runs as the later ones. Elsewhere (another allocator) it is
    a harmless allocation. The process may then keep up to ``2 nbytes`` of freed memory.
    """
    if not _PRIMED:
        np.empty(int(nbytes) // 8)
        _PRIMED.append(True)
