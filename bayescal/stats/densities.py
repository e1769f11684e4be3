"""Log densities of frozen :mod:`scipy.stats` distributions, without scipy's per-call cost.

A frozen distribution's ``logpdf`` spends tens of microseconds per call on argument
parsing and masking whatever the size of its argument; a sampler's prior, evaluated at
every density evaluation, paid that several times per call. :func:`log_density` returns a
plain numpy function with the same values (to rounding) for the common priors (normal,
truncated normal, uniform, lognormal), their constants computed once, and the
distribution's own ``logpdf`` for any other. :func:`log_survival` does the same for the
normal's ``logsf``.
"""

from __future__ import annotations

import numpy as np
from scipy import special, stats

__all__ = ["log_density", "log_survival", "independent_log_density", "logsumexp_last"]

_LOG_SQRT_2PI = 0.5 * np.log(2 * np.pi)


def _family(dist):
    """``(generator, shape args, loc, scale)`` of a frozen distribution, or None."""
    gen = getattr(dist, "dist", None)
    if not isinstance(gen, stats.rv_continuous):
        return None
    try:     # scipy's own parsing of the frozen arguments (positional or keyword)
        shapes, loc, scale = gen._parse_args(*dist.args, **dist.kwds)
    except (AttributeError, TypeError, ValueError):
        return None
    if not (np.ndim(loc) == 0 and np.ndim(scale) == 0 and float(scale) > 0
            and all(np.ndim(s) == 0 for s in shapes)):
        return None
    return gen, tuple(float(s) for s in shapes), float(loc), float(scale)


def _in_support(lo, hi, val):
    """``val`` where ``lo <= x <= hi`` (scipy's closed support), -inf outside, nan for nan x."""
    def f(x):
        x = np.asarray(x, dtype=float)
        return np.where((x < lo) | (x > hi), -np.inf, val(x))
    return f


def log_density(dist):
    """The log density of a frozen distribution as a plain numpy function.

    Parameters
    ----------
    dist : scipy.stats frozen distribution

    Returns
    -------
    callable
        ``f(x) -> ndarray`` of ``x``'s shape, equal to ``dist.logpdf(x)`` to rounding
        (-inf outside the support, nan at nan). Closed forms for ``norm``, ``truncnorm``,
        ``uniform``, ``lognorm`` with scalar parameters; ``dist.logpdf`` otherwise.

    Examples
    --------
    >>> from scipy import stats
    >>> f = log_density(stats.norm(2.0, 0.5))
    >>> bool(abs(f(2.3) - stats.norm(2.0, 0.5).logpdf(2.3)) < 1e-14)
    True
    """
    fam = _family(dist)
    if fam is None:
        return dist.logpdf
    gen, shapes, loc, scale = fam
    inv = 1.0 / scale
    if gen.name == "norm" and type(gen) is type(stats.norm):
        const = -_LOG_SQRT_2PI - np.log(scale)

        def normal(x):
            z = (x - loc) * inv
            return const - 0.5 * z * z
        return normal
    if gen.name == "truncnorm" and type(gen) is type(stats.truncnorm):
        a, b = shapes
        mid = float(dist.median())           # a point of the support fixes the constant
        zm = (mid - loc) * inv
        const = float(dist.logpdf(mid)) + 0.5 * zm * zm
        return _in_support(loc + a * scale, loc + b * scale,
                           lambda x: const - 0.5 * ((x - loc) * inv) ** 2)
    if gen.name == "uniform" and type(gen) is type(stats.uniform):
        const = -np.log(scale)
        return _in_support(loc, loc + scale, lambda x: np.where(x == x, const, np.nan))
    if gen.name == "lognorm" and type(gen) is type(stats.lognorm):
        (s,) = shapes
        log_scale = np.log(scale)

        def lognormal(x):
            y = (np.asarray(x, dtype=float) - loc) * inv
            with np.errstate(divide="ignore", invalid="ignore"):
                val = (-np.log(y) ** 2 / (2 * s**2) - np.log(s * y * np.sqrt(2 * np.pi))
                       - log_scale)
            return np.where(y > 0, val, np.where(np.isnan(y), np.nan, -np.inf))
        return lognormal
    return dist.logpdf


def log_survival(dist):
    """``dist.logsf`` as a plain numpy function (closed form for a normal).

    Parameters
    ----------
    dist : scipy.stats frozen distribution

    Returns
    -------
    callable
        ``f(x) -> ndarray``, ``log P(X > x)``.
    """
    fam = _family(dist)
    if fam is not None and fam[0].name == "norm" and type(fam[0]) is type(stats.norm):
        _, _, loc, scale = fam
        inv = 1.0 / scale
        return lambda x: special.log_ndtr((loc - np.asarray(x, dtype=float)) * inv)
    return dist.logsf


def independent_log_density(dists, cols):
    """The log density of independent priors on some columns, as one numpy function.

    Parameters
    ----------
    dists : sequence of scipy.stats frozen distributions
    cols : sequence of int
        The column each distribution is the prior of.

    Returns
    -------
    callable
        ``f(x) -> ndarray``, ``x`` of shape (..., D) -> ``sum_j dists[j].logpdf(x[..., cols[j]])``
        of shape (...), to rounding; the normal ones in one vectorised pass.
    """
    normal = [_family(d) is not None and type(d.dist) is type(stats.norm) for d in dists]
    ncols = [c for c, n in zip(cols, normal, strict=True) if n]
    mu = np.array([float(d.mean()) for d, n in zip(dists, normal, strict=True) if n])
    sd = np.array([float(d.std()) for d, n in zip(dists, normal, strict=True) if n])
    inv, const = 1.0 / sd, -np.sum(np.log(sd)) - len(ncols) * _LOG_SQRT_2PI
    others = [(c, log_density(d)) for c, d, n in zip(cols, dists, normal, strict=True) if not n]

    def f(x):
        z = (x[..., ncols] - mu) * inv
        out = const - 0.5 * np.einsum("...k,...k->...", z, z)
        for c, lp in others:
            out = out + lp(x[..., c])
        return out
    return f


def logsumexp_last(a):
    """``log(sum(exp(a), axis=-1))``, shifted by the maximum (-inf when all are -inf).

    Parameters
    ----------
    a : ndarray, shape (..., K)

    Returns
    -------
    ndarray, shape (...)
    """
    m = a.max(axis=-1)
    shift = np.where(np.isfinite(m), m, 0.0)
    with np.errstate(divide="ignore"):
        return np.log(np.exp(a - shift[..., None]).sum(axis=-1)) + shift
