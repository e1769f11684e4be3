"""Corruptions of a room's rows, written apart from the package's own harness.

Written from a list of blunders (swapped rows, a mis-paired block, units typed in cm or m,
a z sign flip, digit typos, spurious pixels, a ghost arc, and mixes of them) without reading
``bayescal/validation/corruption.py``. It acts on a :class:`rooms2.Room` (any object with
its fields: ``pixels``, ``pixels_true``, ``approx_points``, ``sigma_scene``, ``sigma_px``,
``params``, ``image_size``) and returns a corrupted copy (``dataclasses.replace``) and the
sorted indices of the rows it corrupted; nothing else changes.

**A corruption must corrupt.** A changed row counts only if the change is far outside the
noise, so that a detector is never scored on a "blunder" the data cannot see:

- an approximate point's change ``delta`` (mm, over the axes with a finite sd; an axis with
  sd ``inf`` carries no information, so a change there is no corruption) must have
  ``|delta / sd| > K_SD = 5`` (the chance that Gaussian noise alone moves a point that far
  is 1.5e-5 per row, chi-square with 3 dof) **and** ``|delta| > MIN_MM = 20`` mm (a smaller
  slip is within what a tape measure gives);
- a pixel's change must exceed ``K_PX = 6`` pixel-noise sds and ``MIN_PX = 1`` px.

Candidate rows that fail the rule, or whose changed approximate point would leave the
projection domain (``xi |P| - z > 0``, true and nominal sensor), are passed over; when too
few rows qualify the function raises :class:`NoEligibleRows` (e.g. a z sign flip when z has
sd ``inf``, a mis-paired block in a room whose rows are sorted by azimuth, so neighbours are
close, or a swap in a room whose approximate points are all within 20 mm of each other).
Rows in ``exclude`` are never touched, which is how :func:`mix` keeps its kinds on distinct rows.

What is its own (the package's harness was not read, so this is no comparison): the rule
above; every kind keeps pixels inside the image; the ghost arc is
a run of rows *consecutive in azimuth* displaced radially about the principal point by one
shared 2-5 px (a reflected copy of the ring), not by per-row noise; digit typos change one
decimal digit of a coordinate (place 1 to the leading digit) or multiply it by 10.

Use (from ``tests/scene``: ``import corrupt2``; elsewhere ``from scene import corrupt2``)::

    bad, rows = corrupt2.CORRUPTIONS["mispaired_block"](room, rng)
    bad, rows = corrupt2.mix(room, rng, frac=0.05)
"""

from __future__ import annotations

import dataclasses

import numpy as np

from bayescal.errors import InvalidValueError

__all__ = ["CORRUPTIONS", "K_PX", "K_SD", "MIN_MM", "MIN_PX", "NoEligibleRows",
           "changed_enough", "digit_typo", "ghost_arc", "mispaired_block", "mix",
           "pixel_changed_enough", "spurious_pixels", "swap_pair", "swap_pairs", "typed_cm",
           "typed_m", "z_sign_flip"]

K_SD, MIN_MM = 5.0, 20.0
K_PX, MIN_PX = 6.0, 1.0


class NoEligibleRows(InvalidValueError):
    """Too few rows of the room can take this corruption under the module's rule."""


def changed_enough(delta, sd):
    """Whether changes ``delta`` (n, 3) mm of points with sds ``sd`` (n, 3) are corruptions."""
    fin = np.isfinite(sd)
    z = np.where(fin, delta / np.where(fin, sd, 1.0), 0.0)
    mm = np.where(fin, delta, 0.0)
    return (np.linalg.norm(z, axis=-1) > K_SD) & (np.linalg.norm(mm, axis=-1) > MIN_MM)


def pixel_changed_enough(delta, sigma_px):
    """Whether pixel changes ``delta`` (n, 2) px are corruptions."""
    d = np.linalg.norm(delta, axis=-1)
    return (d > K_PX * sigma_px) & (d > MIN_PX)


def _free(room, exclude):
    free = np.ones(len(room.pixels), bool)
    free[np.asarray(list(exclude), int)] = False
    return free


def _done(room, rows, *, pixels=None, approx=None):
    new = dataclasses.replace(
        room, pixels=room.pixels if pixels is None else pixels,
        approx_points=room.approx_points if approx is None else approx)
    return new, np.sort(np.asarray(rows, int))


def _need(got, want, what, unit="row(s) or run(s) qualify"):
    if got < want:
        raise NoEligibleRows(f"{what}: {got} {unit}; expected {want} (a change of > {K_SD:g} sd "
                             f"and > {MIN_MM:g} mm, or > {K_PX:g} sd_px and > {MIN_PX:g} px)")


def swap_pairs(room, rng, *, n_pairs=3, exclude=()):
    """Swap the approximate points of ``n_pairs`` disjoint pairs of rows (2 n_pairs rows)."""
    rng = np.random.default_rng(rng)
    a, sd = room.approx_points.copy(), room.sigma_scene
    pool = list(rng.permutation(np.flatnonzero(_free(room, exclude))))
    pairs = []
    while len(pairs) < n_pairs and len(pool) >= 2:
        i = pool.pop()
        d = a[pool] - a[i]
        ok = changed_enough(d, sd[[i] * len(pool)]) & changed_enough(-d, sd[pool])
        if ok.any():
            pairs.append((i, pool.pop(int(np.flatnonzero(ok)[0]))))
    _need(len(pairs), n_pairs, "swap_pairs")
    rows = np.array(pairs, int).reshape(-1, 2)
    a[rows[:, 0]], a[rows[:, 1]] = room.approx_points[rows[:, 1]], room.approx_points[rows[:, 0]]
    return _done(room, rows.ravel(), approx=a)


def swap_pair(room, rng, *, exclude=()):
    """Swap the approximate points of two rows."""
    return swap_pairs(room, rng, n_pairs=1, exclude=exclude)


def mispaired_block(room, rng, *, k=5, exclude=()):
    """Rows ``s .. s+k-1`` take the approximate points of rows ``s+1 .. s+k`` (a block
    mis-paired by one row; row ``s+k`` is read, not changed). ``k >= 1``."""
    rng = np.random.default_rng(rng)
    a, n = room.approx_points, len(room.pixels)
    ok = _free(room, exclude)[:-1] & changed_enough(a[1:] - a[:-1], room.sigma_scene[:-1])
    runs = np.convolve(ok.astype(int), np.ones(k, int), mode="valid") == k
    starts = np.flatnonzero(runs) if n > k else np.array([], int)
    _need(int(len(starts) > 0), 1, f"mispaired_block (k = {k})")
    s = int(rng.choice(starts))
    new = a.copy()
    new[s:s + k] = a[s + 1:s + k + 1]
    return _done(room, np.arange(s, s + k), approx=new)


def _in_domain(room, point):
    """``xi |P| - z > 0`` for the true and the nominal sensor (the CLI refuses the rest)."""
    xis = [room.params[0], getattr(room, "nominal", room.params)[0]]
    return all(xi * np.linalg.norm(point) - point[2] > 0 for xi in xis)


def _rowwise(room, rng, change, n_rows, exclude, what):
    """Apply ``change(a_row, sd_row, rng) -> new row`` to ``n_rows`` random rows where the
    change qualifies and leaves the point in the projection domain."""
    rng = np.random.default_rng(rng)
    a, sd = room.approx_points.copy(), room.sigma_scene
    rows = []
    for i in rng.permutation(np.flatnonzero(_free(room, exclude))):
        if len(rows) == n_rows:
            break
        new = change(a[i], sd[i], rng)
        if changed_enough((new - a[i])[None], sd[i][None])[0] and _in_domain(room, new):
            a[i] = new
            rows.append(i)
    _need(len(rows), n_rows, what)
    return _done(room, rows, approx=a)


def typed_cm(room, rng, *, n_rows=3, exclude=()):
    """Approximate points typed in cm: divided by 10 (all three coordinates)."""
    return _rowwise(room, rng, lambda p, sd, g: p / 10.0, n_rows, exclude, "typed_cm")


def typed_m(room, rng, *, n_rows=3, exclude=()):
    """Approximate points typed in m: divided by 1000."""
    return _rowwise(room, rng, lambda p, sd, g: p / 1000.0, n_rows, exclude, "typed_m")


def z_sign_flip(room, rng, *, n_rows=3, exclude=()):
    """The sign of z flipped (no corruption where z has sd ``inf`` or is near 0)."""
    return _rowwise(room, rng, lambda p, sd, g: p * np.array([1.0, 1.0, -1.0]), n_rows,
                    exclude, "z_sign_flip")


def _typo(p, sd, rng):
    """One coordinate (an axis with finite sd) times 10, or one decimal digit changed."""
    axes = np.flatnonzero(np.isfinite(sd))
    ax = int(rng.choice(axes))
    new = p.copy()
    v = float(p[ax])
    if rng.random() < 0.5:
        new[ax] = 10.0 * v
        return new
    top = int(np.floor(np.log10(abs(v)))) if abs(v) >= 1 else 0
    place = 10.0 ** int(rng.integers(0, top + 1))
    digit = int(abs(v) // place % 10)
    other = int(rng.choice([d for d in range(10) if d != digit]))
    new[ax] = np.copysign(abs(v) + (other - digit) * place, v if v != 0 else 1.0)
    return new


def digit_typo(room, rng, *, n_rows=3, exclude=()):
    """Digit typos: in each row one coordinate times 10 or one of its digits changed."""
    return _rowwise(room, rng, _typo, n_rows, exclude, "digit_typo")


def _in_image(pixels, image_size):
    w, h = image_size
    return np.all((pixels >= 0) & (pixels <= np.array([w - 1, h - 1])), axis=-1)


def spurious_pixels(room, rng, *, n_rows=3, shift_px=(10.0, 40.0), exclude=()):
    """Pixels moved by ``U(shift_px)`` px in a random direction (kept inside the image)."""
    rng = np.random.default_rng(rng)
    px, rows = room.pixels.copy(), []
    for i in rng.permutation(np.flatnonzero(_free(room, exclude))):
        if len(rows) == n_rows:
            break
        ang, mag = rng.uniform(-np.pi, np.pi), rng.uniform(*shift_px)
        new = px[i] + mag * np.array([np.cos(ang), np.sin(ang)])
        if _in_image(new, room.image_size) and \
                pixel_changed_enough((new - px[i])[None], room.sigma_px)[0]:
            px[i] = new
            rows.append(i)
    _need(len(rows), n_rows, "spurious_pixels")
    return _done(room, rows, pixels=px)


def ghost_arc(room, rng, *, k=8, shift_px=(2.0, 5.0), exclude=()):
    """A run of ``k`` rows consecutive in azimuth (about the true principal point), all
    displaced radially by one shared ``U(shift_px)`` px, outwards or inwards at random."""
    rng = np.random.default_rng(rng)
    centre = np.asarray(room.params, float)[4:6]
    rel = room.pixels_true - centre
    order = np.argsort(np.arctan2(rel[:, 1], rel[:, 0]))
    free = _free(room, exclude)[order]
    wrapped = np.concatenate([free, free[:k - 1]]).astype(int)
    starts = np.flatnonzero(np.convolve(wrapped, np.ones(k, int), mode="valid") == k)
    _need(int(len(starts) > 0 and k <= len(order)), 1, f"ghost_arc (k = {k})")
    rows = order[(int(rng.choice(starts)) + np.arange(k)) % len(order)]
    shift = rng.uniform(*shift_px) * rng.choice([-1.0, 1.0])
    unit = rel[rows] / np.linalg.norm(rel[rows], axis=1, keepdims=True)
    px = room.pixels.copy()
    px[rows] += shift * unit
    ok = pixel_changed_enough(px[rows] - room.pixels[rows], room.sigma_px)
    _need(int(np.sum(ok & _in_image(px[rows], room.image_size))), k, "ghost_arc")
    return _done(room, rows, pixels=px)


#: name -> function(room, rng, *, exclude=()) with its default size.
CORRUPTIONS = {
    "swap_pair": swap_pair, "swap_pairs": swap_pairs, "mispaired_block": mispaired_block,
    "typed_cm": typed_cm, "typed_m": typed_m, "z_sign_flip": z_sign_flip,
    "digit_typo": digit_typo, "spurious_pixels": spurious_pixels, "ghost_arc": ghost_arc,
}

#: For mix: name -> (keyword for the size, smallest and largest size, rows per unit of size).
_SIZES = {
    "swap_pair": (None, 1, 1, 2), "swap_pairs": ("n_pairs", 2, 3, 2),
    "mispaired_block": ("k", 2, 5, 1), "typed_cm": ("n_rows", 1, 3, 1),
    "typed_m": ("n_rows", 1, 3, 1), "z_sign_flip": ("n_rows", 1, 3, 1),
    "digit_typo": ("n_rows", 1, 3, 1), "spurious_pixels": ("n_rows", 1, 3, 1),
    "ghost_arc": ("k", 3, 6, 1),
}


def mix(room, rng, *, kinds=None, frac=0.05, exclude=(), return_parts=False):
    """Several kinds on distinct rows, at most ``floor(frac * N)`` rows in all.

    Kinds (default: all of :data:`CORRUPTIONS`) are tried in random order, each with a
    random size that fits the rows left (the first leaves one row for a second kind); a
    kind no row qualifies for is skipped. At least two kinds must apply, else
    :class:`NoEligibleRows` (always for N < 40 at the default ``frac``).

    Returns
    -------
    room, rows
        As the single kinds; with ``return_parts=True`` also ``{kind: rows}``.
    """
    rng = np.random.default_rng(rng)
    budget = int(np.floor(frac * len(room.pixels)))
    used, parts = set(int(i) for i in exclude), {}
    for name in rng.permutation(sorted(kinds or CORRUPTIONS)):
        key, lo, hi, per = _SIZES[name]
        left = budget - (len(used) - len(exclude)) - (0 if parts else 1)  # room for a 2nd
        if lo * per > left:
            continue
        size = int(rng.integers(lo, min(hi, left // per) + 1))
        try:
            room, rows = CORRUPTIONS[name](room, rng, exclude=sorted(used),
                                          **({key: size} if key else {}))
        except NoEligibleRows:
            continue
        parts[str(name)] = rows
        used.update(int(i) for i in rows)
    _need(len(parts), 2, f"mix ({budget} rows allowed)", "kind(s) applied")
    rows = np.sort(np.concatenate(list(parts.values())))
    return (room, rows, parts) if return_parts else (room, rows)
