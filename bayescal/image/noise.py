"""The image's noise: variance as a linear function of the grey level, from the image itself;
a check of the ring's point variances against the ring's own scatter; and the variance a
point's peak takes from wall texture under the stripe and from scatter about the ring."""

from __future__ import annotations

import numpy as np
from scipy.ndimage import uniform_filter

from .ring import circular_windows, local_quadratic

__all__ = ["noise_model", "ring_scatter_scale", "clutter_variance", "scatter_factor", "CLUTTER_K"]


def noise_model(img, *, levels=None, n_bins=12, rows=None):
    """Fit ``var(I) = a + b * I`` (shot plus read noise) to one image.

    Horizontal second differences ``I[x-1] - 2 I[x] + I[x+1]`` of white noise have
    variance ``6 var``; their robust (MAD) spread in bins of the local mean grey
    level gives the variance per level, and a least-squares line through the
    bins gives ``a`` and ``b``. Smooth texture adds little to a second
    difference, and edges are rare enough for the MAD to ignore them.

    Parameters
    ----------
    img : ndarray, shape (H, W)
        Grey levels (float).
    levels : ndarray, shape (H, W), optional
        Grey levels that set the shot noise, if not ``img`` (for a difference of
        two exposures: the sum of the two, with ``var = a + b * level``).
    n_bins : int, optional
        Number of grey-level bins (quantiles of the local mean).
    rows : array_like of int, optional
        Use these rows only (each with the rows either side for its 3x3 mean level, so
        inside ``1 ... H - 2``), binned by rank; default every row. A sample of rows
        estimates the same line at a fraction of the cost (the ring tracker's,
        ``bayescal.image.track``).

    Returns
    -------
    callable
        ``var(levels)``: ndarray of the noise variance, grey levels^2, floored at
        the smallest binned variance.
    """
    lev = img if levels is None else levels
    if rows is None:
        level = uniform_filter(lev, 3)[:, 1:-1]
    else:                               # the same 3x3 mean, on the rows asked for only
        rows = np.asarray(rows, dtype=int)
        img, lev = img[rows], lev[rows - 1] + lev[rows] + lev[rows + 1]
        level = (lev[:, :-2] + lev[:, 1:-1] + lev[:, 2:]) / 9.0
    d = img[:, :-2] - 2 * img[:, 1:-1] + img[:, 2:]
    level, d = level.ravel(), d.ravel()
    if rows is None:
        edges = np.unique(np.quantile(level, np.linspace(0, 1, n_bins + 1)))
        which = np.clip(np.searchsorted(edges, level, side="right") - 1, 0,
                        max(len(edges) - 2, 0))
        # the samples sorted by bin once (a bin's medians do not depend on the order): 12
        # boolean masks over the image took most of the time
        order = np.argsort(which.astype(np.uint8), kind="stable")    # radix sort: < 256 bins
        counts = np.bincount(which, minlength=len(edges) - 1)[:len(edges) - 1]
        ends = np.cumsum(counts)
    else:
        # by rank: uniform_filter's running sums leave rounding noise of 1e-17 on the levels
        # of the whole image, which splits a mass of one level (a black margin: half of a
        # rendered image) between several quantile bins as ranks do; the exact sums of a
        # sample of rows would put it in one bin (the line's intercept then 4x: measured)
        ends = np.linspace(0, len(level), n_bins + 1).astype(int)[1:]
        order = np.argpartition(level, ends[:-1])           # the bins' members, by rank
        counts = np.diff(np.concatenate([[0], ends]))
    lv, vv = [], []
    for lo, hi in zip(ends - counts, ends, strict=True):
        if hi - lo > 50:
            dk = d[order[lo:hi]]
            lv.append(np.median(level[order[lo:hi]]))
            vv.append((1.4826 * np.median(np.abs(dk - np.median(dk)))) ** 2 / 6.0)
    lv, vv = np.asarray(lv), np.asarray(vv)
    floor = max(float(np.min(vv)) if vv.size else 1.0, 1.0 / 12.0)
    if vv.size >= 2 and np.ptp(lv) > 0:
        b, a = np.polyfit(lv, vv, 1)
        b = max(b, 0.0)
    else:
        a, b = floor, 0.0
    return lambda levels: np.maximum(a + b * np.clip(levels, 0, None), floor)


def ring_scatter_scale(r, var, ok, *, shared_px=3.5):
    """Scale (>= 1) on a ring's point variances when the ring scatters more than they say.

    The ring is a smooth curve over azimuth, so each point's radius is predicted by a
    quadratic through its neighbours on either side, leaving out those within
    ``shared_px`` of it along the ring (at least 2 profiles): texture under the stripe
    moves neighbouring peaks together (lag-1 correlation of the errors 0.45-0.68 at 1.7 px
    spacing, lag 2 0.01-0.34, lag 4 at most 0.15, on our textured rooms with a laser-off
    image), so a smoother through them hides part of the error, as a running median through
    the point does. The quadratic reaches 5x as far. The squared miss over its variance,
    ``var (1 + leverage)`` with the prediction's own, has median 0.455 (a chi-square with
    one degree of freedom) when the variances are right; the median over the ring over
    0.455 is the scale, floored at 1 (a ring that bends within reach, at a room's corner,
    adds a few large misses, which the median ignores). One scale per ring: a running
    median over a hundred profiles, floored at 1, inflated rings whose variances were right
    (its noise, cut at 1, is a bias upwards).

    Parameters
    ----------
    r, var : ndarray, shape (N,)
        Radii (px) and their variances (px^2) around the closed ring, in azimuth order at
        equal steps.
    ok : ndarray of bool, shape (N,)
        Points to use (unflagged, finite).
    shared_px : float, optional
        Distance along the ring within which errors are shared, px.

    Returns
    -------
    float
        1 when fewer than 10 points can be checked.
    """
    n = len(r)
    spacing = max(float(np.median(r[ok])) if ok.any() else 1.0, 1e-3) * 2 * np.pi / n
    gap = max(2, int(np.ceil(shared_px / spacing)))
    offs = np.arange(-5 * gap, 5 * gap + 1)
    X = np.stack([np.ones(len(offs)), offs, offs ** 2], axis=1).astype(float)
    w = (circular_windows(ok, 5 * gap) & (np.abs(offs) > gap)[None]).astype(float)
    coef, A = local_quadratic(w, X, circular_windows(np.where(ok, r, 0.0), 5 * gap))
    miss = r - coef[:, 0]
    good = ok & (np.sum(w, axis=1) >= 6) & (np.abs(miss) < 3.0)
    if good.sum() < 10:
        return 1.0
    q = miss[good] ** 2 / (var[good] * (1.0 + np.linalg.inv(A[good])[:, 0, 0]))
    return max(1.0, float(np.median(q)) / 0.455)


#: the clutter variance's factor (see clutter_variance), measured: z rms 1.1-1.3 without a
#: laser-off image on both renderers' textured rooms (0.8 and 1.0 move it by about +-0.05)
CLUTTER_K = 0.9


def clutter_variance(pol, k, var_img, width, height):
    """Radial variance (px^2) from wall texture under the stripe, per profile.

    Texture at the beam's scale that the running median leaves in the high-passed profile
    moves the peak by about its slope times ``width^2 / height``, an error shared by
    neighbouring profiles that no scatter about the smoothed ring can reveal. Its size comes
    from five high-passed samples either side of the peak, past the stripe's tails: their
    robust mean square beyond the pixel noise's variance (zero where only noise is left, as
    with a laser-off image), times ``(CLUTTER_K width / height)^2``.
    """
    n, K = pol.high.shape
    i = np.arange(n)[:, None]
    # five samples each side, past the stripe's own tails: from 3 of its sds (at least 3
    # px) or 1 px past where the profile first drops below a tenth of the peak (a
    # saturated, flat-topped stripe is wider than its fitted sd says), at most 12 px
    j = np.arange(1, 13)
    below = [pol.high[i, np.clip(k[:, None] + sgn * j[None], 0, K - 1)]
             < 0.1 * np.maximum(height, 0.0)[:, None] for sgn in (-1, 1)]
    tail = np.maximum(*[np.where(b.any(1), np.argmax(b, axis=1) + 2, 13) for b in below])
    start = np.clip(np.maximum(np.ceil(3 * np.nan_to_num(width, nan=1.0)), tail), 3, 12)
    side = np.arange(5)[None, :] + start[:, None]
    cand = np.clip(k[:, None] + np.concatenate([-side, side], axis=1), 0, K - 1).astype(int)
    rr = pol.radii[cand]
    H, W = var_img.shape
    u = np.clip(np.rint(pol.center[0] + np.cos(pol.phi)[:, None] * rr).astype(int), 0, W - 1)
    v = np.clip(np.rint(pol.center[1] + np.sin(pol.phi)[:, None] * rr).astype(int), 0, H - 1)
    # a robust mean square (the median over 0.455, a chi-square's with 1 degree of freedom):
    # a narrow ridge beside the stripe (a ghost, a lamp's edge) does not move its peak
    ms = np.median(pol.high[i, cand] ** 2, axis=1) / 0.455
    excess = np.maximum(ms - var_img[v, u].mean(1), 0.0)
    w = np.nan_to_num(np.maximum(width, 0.5), nan=0.5)
    return np.nan_to_num(excess * (CLUTTER_K * w / np.maximum(height, 1e-3)) ** 2, nan=0.0)


def scatter_factor(d, var, win):
    """Factor (>= 1) on the variances where the points scatter about the smoothed ring more
    than their variances say (texture under the stripe, a misfit the noise model misses):
    the running median of ``d^2 / var`` over ``win`` azimuths over 0.455, the median of a
    chi-square with 1 degree of freedom."""
    with np.errstate(all="ignore"):
        q = np.where(np.abs(d) < 3.0, d ** 2 / var, np.nan)
    n, h = len(q), win // 2
    # each window's median of its finite values (np.nanmedian's, 4x faster): sorted, NaN last
    s = np.sort(circular_windows(q, h), axis=1)
    c = np.sum(np.isfinite(s), axis=1)
    i = np.arange(n)
    med = (s[i, np.maximum((c - 1) // 2, 0)] + s[i, np.maximum(c // 2, 0)]) / 2
    return np.maximum(1.0, np.where(c > 0, med, 1.0) / 0.455)
