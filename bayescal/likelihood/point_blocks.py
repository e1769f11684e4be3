"""Cache-sized blocks of the points for the likelihood's hot path.

:meth:`bayescal.likelihood.points.LaserLikelihood.laplace` and its gradient work on
``(walkers, N)`` arrays with a few dozen elementwise operations, each writing a
temporary of that size. At ``24 x 20 000`` every temporary is 3.8 MB and the
pass is bound by memory traffic; cut into blocks of about
:data:`BLOCK_ELEMENTS` elements (``24 x 2000``) the temporaries stay in cache and
the same work runs about twice as fast per point (``docs/performance.md``). The
points are independent given the globals, so the blocks' results are exact:
per-point arrays are concatenated, sums over points added.

A block is the likelihood itself with its per-point arrays sliced (views, no
copies), cached per block size on the likelihood.
"""

from __future__ import annotations

import copy

import numpy as np

__all__ = ["BLOCK_ELEMENTS", "point_blocks", "clear_blocks", "concat_blocks", "sum_blocks"]

#: elements (leading draws x points) per block: 24 walkers x 2000 points
BLOCK_ELEMENTS = 48_000
#: smallest block, in points (a handful of walkers must not cut N into slivers)
MIN_BLOCK = 2048

#: the per-point attributes of a LaserLikelihood (first axis N)
_PER_POINT = ("pixels", "approx", "rho", "w_scene", "_scene_mask", "_n_rows", "_log_w_given",
              "px_white", "_px_log_det")
_CACHE = "_point_block_cache"


def _block_size(lead_size):
    """Points per block for ``lead_size`` leading draws: a power of two >= MIN_BLOCK."""
    raw = BLOCK_ELEMENTS // max(int(lead_size), 1)
    return max(MIN_BLOCK, 1 << max(int(raw).bit_length() - 1, 0))


def _sub_likelihood(lik, sl):
    sub = copy.copy(lik)
    sub.__dict__.pop(_CACHE, None)
    sub.__dict__.pop("_marginal_columns", None)     # point_algebra.point_columns: the block's own
    for name in _PER_POINT:
        value = getattr(lik, name, None)
        if isinstance(value, np.ndarray):
            setattr(sub, name, value[sl])
    sub.n = len(sub.pixels)
    return sub


def point_blocks(lik, lead_size):
    """``(slice, block likelihood)`` pairs covering ``lik``'s points in order.

    One pair ``(slice(None), lik)`` when the points fit one block. The blocks
    share ``lik``'s settings at the time they were made: call
    :func:`clear_blocks` after changing any (``set_reference_noise`` does).
    """
    size = _block_size(lead_size)
    if size >= lik.n:
        return ((slice(None), lik),)
    cache = lik.__dict__.setdefault(_CACHE, {})
    if size not in cache:
        cache[size] = tuple((slice(lo, lo + size), _sub_likelihood(lik, slice(lo, lo + size)))
                            for lo in range(0, lik.n, size))
    return cache[size]


def clear_blocks(lik):
    """Forget ``lik``'s cached blocks (after a change of its settings)."""
    lik.__dict__.pop(_CACHE, None)


def _blocks_of(lik, psi, q):
    psi, q = np.asarray(psi, dtype=float), np.asarray(q, dtype=float)
    return psi, q, point_blocks(lik, np.prod(psi.shape[:-1], dtype=int))


def concat_blocks(lik, method, psi, q, *args):
    """``lik.<method>(psi, q, *args)`` by blocks; its tuple of per-point arrays (..., N)
    concatenated (``None`` entries stay ``None``). ``q`` has shape (..., N, k)."""
    psi, q, blocks = _blocks_of(lik, psi, q)
    if len(blocks) == 1:
        return getattr(lik, method)(psi, q, *args)
    parts = [getattr(sub, method)(psi, q[..., sl, :], *args) for sl, sub in blocks]
    return tuple(None if p[0] is None else np.concatenate(p, axis=-1)
                 for p in zip(*parts, strict=True))


def sum_blocks(lik, method, psi, q, *args):
    """``lik.<method>(psi, q, *args)`` by blocks; its tuple of sums over points added."""
    psi, q, blocks = _blocks_of(lik, psi, q)
    parts = [getattr(sub, method)(psi, q[..., sl, :], *args) for sl, sub in blocks]
    return tuple(sum(p[1:], p[0]) for p in zip(*parts, strict=True))
