"""The laser ring in polar coordinates: radial high-pass, a local noise scale, and the
ring chosen by dynamic programming over azimuth.

A radial profile from a centre inside the ring crosses the stripe once. Wall texture
varies slowly along the profile (or in steps, at a poster's edge); a running median
along the radius follows both, so the profile minus its median keeps thin ridges
only. Per azimuth the texture can still out-shine the laser, but the laser is the one
ridge that continues around the whole image: the ring is the closed path through the
(azimuth, radius) grid that maximises the summed, capped ridge score with a penalty on
every radial step (:func:`ring_path`).
"""

from __future__ import annotations

import warnings

import numpy as np
from numpy.lib.stride_tricks import sliding_window_view
from scipy.ndimage import gaussian_filter1d, map_coordinates

__all__ = ["PolarImage", "polar_image", "running_median", "circular_windows", "ridge_near",
           "ridge_crest", "ring_path", "circle_fit", "ring_model", "ring_priors", "ring_curve",
           "PATH_CAP", "TIE", "QUANTUM_SD", "ring_rays", "ring_circle", "RAY_GRID", "RAY_STEP"]

#: the largest score an azimuth of a path can gain, noise sds (:func:`ring_path`)
PATH_CAP = 8.0

#: a path's gain per azimuth for running on a capped sample of higher score than another:
#: a tie-break, far below any step's cost (without it the path kept to a bright stripe's
#: inner flank, 3-4 px off its crest on real frames)
TIE = 1e-6

#: the least scale of the ridge score in an integer image, grey levels: its quantisation
#: alone (sd 1/sqrt(12)) through the score's high-pass and 1-px smoothing (0.25-0.37 of a
#: pixel's white noise, measured; the least taken). A frame that is black but for the ring
#: has no spread at all: every sample the ring's light reaches scored 1e6-1e10 sds
QUANTUM_SD = 0.25 / np.sqrt(12.0)

#: first radius of the profiles, px (the centre's few pixels carry no ring)
R_MIN = 3.0


class PolarImage:
    """Profiles of an image along rays from ``center``: ``values[i, k]`` at azimuth
    ``phi[i]`` and radius ``radii[k]`` (bilinear; NaN outside the image).

    Attributes
    ----------
    phi : ndarray, shape (n,)
    radii : ndarray, shape (K,)
    values, base, high, score : ndarray, shape (n, K)
        Samples; their running radial median; ``values - base``; the ridge score (the
        high-pass smoothed over 1 px and divided by its local robust sd, at least
        ``floor``).
    valid : ndarray of bool, shape (n, K)
    """

    def __init__(self, img, center, phi, radii, highpass_px, sub=2, floor=0.0):
        self.center, self.phi, self.radii = np.asarray(center, float), phi, radii
        #: azimuth offsets of the rays averaged into one profile (they share its pixels)
        self.sub = (np.arange(sub) - (sub - 1) / 2.0) * (2 * np.pi / len(phi)) / sub
        H, W = img.shape
        self.values = self.sample(img)
        u, v = self._rays[-1]
        self.valid = (u >= 0) & (u <= W - 1) & (v >= 0) & (v <= H - 1)
        self.base = running_median(self.values, max(5, int(highpass_px) | 1))
        self.high = np.where(self.valid, self.values - self.base, 0.0)
        self._floor, self._score, self._scale = floor, None, None

    @property
    def score(self):
        """The ridge score (n, K), computed when first read (measuring a ring whose path
        is known needs none)."""
        if self._score is None:
            smooth = gaussian_filter1d(self.high, 1.0, axis=1)
            self._scale = np.maximum(_local_sd(smooth, self.valid), self._floor)
            # near the centre neighbouring profiles sample the same pixels: one azimuth step
            # there is less than a pixel of new evidence, and a blob would pass for a ring
            arc = np.minimum(1.0, self.radii * (2 * np.pi / len(self.phi)))
            self._score = np.where(self.valid, smooth / self._scale, 0.0) * arc[None, :]
        return self._score

    @score.setter
    def score(self, value):
        self._score = value

    @property
    def scale(self):
        """The ridge score's local noise sd (n, K)."""
        if self._scale is None:
            _ = self.score
        return self._scale

    def sample(self, image):
        """``image`` (H, W) along the profiles (n, K): bilinear, each sample the mean of the
        profile's rays."""
        out = 0.0
        for u, v in self._rays:
            vals = map_coordinates(image, [v.ravel(), u.ravel()], order=1, mode="nearest",
                                   output=float)
            out = out + vals.reshape(u.shape) / len(self.sub)
        return out

    @property
    def _rays(self):
        """The samples' coordinates ``(u, v)`` (n, K) px of each ray of the profiles."""
        if getattr(self, "_uv", None) is None:
            self._uv = [(self.center[0] + np.cos(self.phi + d)[:, None] * self.radii[None],
                         self.center[1] + np.sin(self.phi + d)[:, None] * self.radii[None])
                        for d in self.sub]
        return self._uv

    def sample_mask(self, mask):
        """A boolean image ``mask`` (H, W) at the profiles' samples (n, K), nearest pixel."""
        u = self.center[0] + np.cos(self.phi)[:, None] * self.radii[None]
        v = self.center[1] + np.sin(self.phi)[:, None] * self.radii[None]
        H, W = mask.shape
        return mask[np.clip(np.rint(v).astype(int), 0, H - 1),
                    np.clip(np.rint(u).astype(int), 0, W - 1)]


def running_median(values, width):
    """The running median of ``width`` (odd) samples along each row of ``values`` (n, K),
    the rows' end samples repeated beyond them: ``median_filter(values, size=(1, width),
    mode="nearest")``'s numbers, by a partial sort of each window (2x faster)."""
    h = width // 2
    padded = np.pad(values, ((0, 0), (h, h)), mode="edge")
    out = np.empty(values.shape)
    step = max(1, 2 ** 20 // max(values.size // max(len(values), 1) * width, 1))
    for i in range(0, len(values), step):        # in blocks: each window is copied once
        win = sliding_window_view(padded[i:i + step], width, axis=1)
        out[i:i + step] = np.partition(win, h, axis=-1)[..., h]
    return out


def circular_windows(a, half):
    """The windows ``a[(i - half ... i + half) % n]`` of a closed sequence ``a`` (n,), one
    per row (n, 2 half + 1): ``a[(arange(n)[:, None] + arange(-half, half + 1)) % n]``'s
    values, as a view of ``a`` wrapped once."""
    a = np.asarray(a)
    n = len(a)
    if half >= n:
        return a[(np.arange(n)[:, None] + np.arange(-half, half + 1)[None]) % n]
    return sliding_window_view(np.concatenate([a[n - half:], a, a[:half]]), 2 * half + 1)


def _local_sd(x, valid, *, block=(8, 32)):
    """Robust local sd of ``x``: the median absolute value in blocks of ``block`` samples
    (azimuth x radius), so that the ridge, a few samples of each block, does not count as
    noise; blocks are blended bilinearly and invalid samples ignored."""
    n, K = x.shape
    bn, bk = -(-n // block[0]), -(-K // block[1])
    a = np.full((bn * block[0], bk * block[1]), np.nan)
    a[:n, :K] = np.where(valid, np.abs(x), np.nan)
    blocks = a.reshape(bn, block[0], bk, block[1]).transpose(0, 2, 1, 3).reshape(bn, bk, -1)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)       # all-NaN blocks (off the image)
        med = np.nanmedian(blocks, axis=2)
    fill = np.nanmedian(med) if np.isfinite(med).any() else 1.0
    med = np.where(np.isfinite(med), med, fill) * 1.4826
    # bilinear blend of the block values, periodic in azimuth
    ti = (np.arange(n) + 0.5) / block[0] - 0.5
    tk = np.clip((np.arange(K) + 0.5) / block[1] - 0.5, 0, bk - 1)
    i0 = np.floor(ti).astype(int)
    fi = (ti - i0)[:, None]
    k0 = np.minimum(np.floor(tk).astype(int), max(bk - 2, 0))
    fk = (tk - k0)[None, :]
    k1 = np.minimum(k0 + 1, bk - 1)
    rows = (1 - fi) * med[i0 % bn] + fi * med[(i0 + 1) % bn]
    s = (1 - fk) * rows[:, k0] + fk * rows[:, k1]
    return np.maximum(s, 1e-9 + 1e-6 * fill)


def ridge_near(pol, k, half):
    """Per profile, the index of the highest high-passed sample within ``half`` samples of
    index ``k`` (n,), kept 2 samples inside the radial grid (the peak fit needs 5)."""
    K = len(pol.radii)
    cand = np.clip(np.asarray(k)[:, None] + np.arange(-half, half + 1)[None], 2, K - 3)
    return cand[np.arange(len(cand)), np.argmax(np.take_along_axis(pol.high, cand, 1), axis=1)]


def ridge_crest(pol, k, *, reach=8):
    """Per profile, the sample reached from index ``k`` (n,) by climbing the high-passed
    profile uphill (at most ``reach`` samples): the crest of the ridge the path runs on.
    A bright stripe scores past the path's cap over several px, where the path is free to
    run on its flank."""
    K = len(pol.radii)
    k = np.clip(np.asarray(k).copy(), 1, K - 2)
    rows = np.arange(len(k))
    for _ in range(int(reach)):
        h = pol.high[rows[:, None], k[:, None] + np.arange(-1, 2)[None]]
        step = np.argmax(h, axis=1) - 1
        if not step.any():
            break
        k = np.clip(k + step, 1, K - 2)
    return k


def polar_image(img, center, *, n_azimuth, r_max, highpass_px=15, r_min=R_MIN, floor=0.0):
    """The :class:`PolarImage` of ``img`` around ``center`` from ``r_min`` (an integer
    offset from :data:`R_MIN`) out to ``r_max`` px; ``floor``: the least scale of its
    score (:data:`QUANTUM_SD` for an integer image)."""
    # mid-step azimuths: one profile in the middle of each of n equal sectors (of each
    # degree for n = 360)
    phi = np.linspace(-np.pi, np.pi, int(n_azimuth), endpoint=False) + np.pi / int(n_azimuth)
    r0 = R_MIN + max(0.0, np.floor(r_min - R_MIN))
    radii = np.arange(r0, max(float(r_max), r0 + 8.0))
    return PolarImage(img, center, phi, radii, highpass_px, floor=floor)


def ring_path(score, *, cap=None, jump=2, penalty=0.5, tie=None):
    """The closed ridge through ``score`` (n azimuths x K radii) by dynamic programming.

    The path takes one radius index per azimuth, moves at most ``jump`` indices between
    neighbouring azimuths at a cost of ``penalty`` per index, and maximises the sum of
    ``min(score, cap)`` (a lamp cannot buy a detour; ``cap`` defaults to :data:`PATH_CAP`);
    ties between capped samples go to the higher ``tie`` (default ``score``), by at most
    :data:`TIE` per azimuth (a log of the excess, so that it tells scores of 1e3 from 1e9).
    Closure: the recursion runs over two
    laps and the path is read off the middle lap, far from both ends.

    Returns
    -------
    path : ndarray of int, shape (n,)
        Radius index per azimuth.
    closure : int
        Radial index difference between the path's two ends one lap apart (0 for a ring
        that closes).
    gain : float
        Mean capped score per azimuth along the path, net of its step penalties.
    """
    n, K = score.shape
    c = PATH_CAP if cap is None else cap
    # ties (a stripe past the cap over several px) broken toward the higher score, not the
    # first index: a path on such a run keeps to its crest, not its inner flank
    S = np.minimum(score, c) + TIE * np.log1p(np.maximum((score if tie is None else tie) - c,
                                                          0.0)) / 64.0
    offs = np.arange(-jump, jump + 1)
    pen = penalty * np.abs(offs)
    back = np.empty((2 * n, K), dtype=np.int8)
    D = S[0].copy()
    cols = np.arange(K)
    # the running score padded with -inf: window row k holds D[k + d] for every step d
    Dp = np.full(K + 2 * jump, -np.inf)
    win = np.lib.stride_tricks.sliding_window_view(Dp, len(offs))
    for t in range(1, 2 * n):
        Dp[jump:jump + K] = D
        cand = win - pen
        arg = np.argmax(cand, axis=1)
        back[t] = arg
        D = cand[cols, arg] + S[t % n]
    path = np.empty(2 * n, dtype=int)
    path[-1] = int(np.argmax(D))
    for t in range(2 * n - 1, 0, -1):
        path[t - 1] = path[t] + offs[back[t, path[t]]]
    lo = n // 2
    out = np.empty(n, dtype=int)
    idx = np.arange(lo, lo + n)
    out[idx % n] = path[idx]
    steps = np.abs(np.diff(np.append(out, out[0])))
    gain = float(np.mean(S[np.arange(n), out]) - penalty * np.mean(steps))
    return out, int(path[lo + n] - path[lo]), gain


def circle_fit(points, weights=None, *, iters=8):
    """Robust algebraic circle fit: centre (2,) px, radius px and the residuals (N,) px."""
    p = np.asarray(points, float)
    w0 = np.ones(len(p)) if weights is None else np.asarray(weights, float)
    w = w0.copy()
    A = np.column_stack([p, np.ones(len(p))])
    b = np.sum(p ** 2, axis=1)
    c, R, res = np.full(2, np.nan), np.nan, np.full(len(p), np.nan)
    for _ in range(iters):
        if np.count_nonzero(w > 0) < 3:
            break
        sol = np.linalg.lstsq(A * w[:, None], b * w, rcond=None)[0]
        c = sol[:2] / 2
        R = float(np.sqrt(max(sol[2] + c @ c, 0.0)))
        res = np.hypot(p[:, 0] - c[0], p[:, 1] - c[1]) - R
        s = 1.4826 * np.median(np.abs(res[w > 0])) + 0.3
        w = w0 / np.maximum(1.0, np.abs(res) / (2.5 * s))
        w[np.abs(res) > 6 * s] = 0.0
    return c, R, res


#: the profiles that measure a ring (:func:`ring_rays`): their centre on a grid of RAY_GRID
#: px, their number a multiple of RAY_STEP (one per 2 px of the circumference, 360-3600), so
#: that two measurements of one ring (the full extractor's, the ring tracker's) whose circles
#: (:func:`ring_circle`) differ by their noise, 0.01 px, read the same profiles. Measured
#: about a centre 2.8 px off the ring's, a ring of radius 60 px or more is crossed within 3
#: degrees of its normal
RAY_GRID = 4.0
RAY_STEP = 8


def ring_rays(ring_center, ring_radius, *, center=None, n_azimuth=None):
    """The centre (2,) px and number of the profiles that measure a ring whose circle is
    ``ring_center`` (2,) px, ``ring_radius`` px: the user's ``center`` and ``n_azimuth``
    where given, else the circle's centre on a grid of :data:`RAY_GRID` px and one profile
    per 2 px of its circumference, a multiple of :data:`RAY_STEP` (360-3600)."""
    rc = np.asarray(ring_center, dtype=float)
    if center is not None:
        c = np.asarray(center, dtype=float)
        R = float(np.hypot(*(rc - c)) + ring_radius)
    else:
        c = np.round(rc / RAY_GRID) * RAY_GRID if RAY_GRID else rc
        R = float(ring_radius)
    if n_azimuth:
        return c, int(n_azimuth)
    return c, int(np.clip(RAY_STEP * np.floor(np.pi * R / RAY_STEP), 360, 3600))


def ring_circle(pixels, flagged):
    """The circle (centre (2,) px, radius px) of a ring's unflagged points ``pixels`` (N, 2)
    (in azimuth order, N >= 3), each weighted by the ring's length it stands for: the same
    circle whatever profiles sampled the ring (an ellipse sampled about centres 10 px apart:
    0.001 px; unweighted 0.2 px)."""
    p = np.asarray(pixels, float)
    arc = np.hypot(*(np.roll(p, -1, axis=0) - np.roll(p, 1, axis=0)).T) / 2
    ok = ~np.asarray(flagged, bool) & np.isfinite(arc)
    c, R, _ = circle_fit(p[ok], np.sqrt(arc[ok]))      # lstsq squares the weights
    return c, R


def _fourier(phi, order):
    cols = [np.ones_like(phi)]
    for m in range(1, order + 1):
        cols += [np.cos(m * phi), np.sin(m * phi)]
    return np.stack(cols, axis=1)


def ring_model(phi, r, weights, *, order=6, keep=0.8, iters=8):
    """A robust Fourier series ``r(phi)`` through a ring's radii (px), so that a sector where
    the path followed something else (a rail or a poster's edge crossing the ring) does
    not bend it: a least-absolute-deviations fit of order 2 (an ellipse, stiff) starts
    trimmed least squares of order ``order`` on the ``keep`` fraction of the points nearest
    the curve.

    Returns the model's radius at ``phi`` (n,) and the robust sd of the residuals (px).
    """
    w0 = np.asarray(weights, float)
    if np.count_nonzero(w0 > 0) <= 2 * order + 1:
        return np.full(len(phi), np.median(r)), np.inf
    A2, A = _fourier(phi, 2), _fourier(phi, order)
    w = w0.copy()
    for _ in range(iters):                          # IRLS for the L1 fit (weights are sqrt)
        coef = np.linalg.lstsq(A2 * w[:, None], r * w, rcond=None)[0]
        res = r - A2 @ coef
        w = w0 / np.sqrt(np.maximum(np.abs(res), 0.05))
    for _ in range(iters):                          # C-steps of trimmed least squares
        use = w0 > 0
        cut = np.quantile(np.abs(res[use]), keep)
        w = w0 * (np.abs(res) <= cut)
        coef = np.linalg.lstsq(A * w[:, None], r * w, rcond=None)[0]
        res = r - A @ coef
    sd = 1.4826 * float(np.median(np.abs(res[w0 > 0])))
    return A @ coef, sd


def ring_priors(pol, *, z_min=4.0, cap=8.0, n_max=3):
    """Where the ring may be, before any path: circles through the strong ridge samples near
    the radii that most azimuths share (the histogram's highest peaks, 8 px or more apart),
    best first: each its centre (2,), radius px and the robust sd of those samples about it
    (px, how far the ring strays from a circle). Empty when no ridge stands out.

    A laser ring is nearly a circle (its elevation changes little with the wall's distance,
    as the laser sits close to the mirror), while texture edges on the walls undulate
    more; a circle found this way keeps the path from following one of those for a sector
    where it outshines the laser. A rail around the room is a circle too, and may share
    more azimuths than a faint ring: the extractor weighs each circle's ring by its points.
    """
    sc = pol.score
    peak = (sc > z_min) & (sc >= np.roll(sc, 1, axis=1)) & (sc >= np.roll(sc, -1, axis=1))
    ii, kk = np.nonzero(peak)
    if len(ii) < 12:
        return []
    w = np.minimum(sc[ii, kk], cap)
    hist = np.convolve(np.bincount(kk, weights=w, minlength=len(pol.radii)), np.ones(7), "same")
    r = pol.radii[kk]
    pts = pol.center + r[:, None] * np.stack([np.cos(pol.phi[ii]), np.sin(pol.phi[ii])], -1)
    out, top = [], hist.max()
    for _ in range(n_max):
        j = int(np.argmax(hist))
        if not hist[j] > 0.25 * top:
            break
        hist[max(0, j - 5):j + 6] = 0.0
        # the first circle may stray from the profiles' centre (a window of 8 px or 10 %);
        # each is also looked for closer to its radius (4 px or 5 %), so that a ridge
        # beside it (a rail 6-30 px away) does not take its fit
        for wide in ((True, False) if not out else (False,)):
            circle = _circle_near(pts, w, pol.radii[j], r, wide=wide)
            if circle is not None and all(abs(circle[1] - o[1]) > 3.0 for o in out):
                out.append(circle)
    return out


def _circle_near(pts, w, R0, r, *, wide=True):
    """A robust circle through the ridge samples ``pts`` (weights ``w``, radii ``r`` about
    the profiles' centre) near radius ``R0``: the samples within 8 px or 10 % of it, then
    within 5 px or 6 % of the fitted circle; unless ``wide``, 4 px or 5 %, then 4 px or 3 %
    (a ring of 345 px with a rail 20-30 px outside it: the wide window fitted both).
    Returns (centre, radius, robust sd) or None."""
    near = np.abs(r - R0) <= (max(8.0, 0.1 * R0) if wide else max(4.0, 0.05 * R0))
    for _ in range(2):
        if np.count_nonzero(near) < 12:
            return None
        c, R, _ = circle_fit(pts[near], w[near])
        if not np.isfinite(R):
            return None
        res = np.hypot(*(pts - c).T) - R
        near = np.abs(res) <= (max(5.0, 0.06 * R) if wide else max(4.0, 0.03 * R))
    if np.count_nonzero(near) < 12:
        return None
    return c, R, 1.4826 * float(np.median(np.abs(res[near] - np.median(res[near]))))


def local_quadratic(w, X, y):
    """Weighted least-squares quadratics, one per window of a closed sequence.

    ``w``, ``y``: shape (n, m), the weights and values at the m offsets of each of the n
    windows; ``X``: shape (m, 3), the design ``[1, x, x^2]`` at those offsets. Returns the
    coefficients, shape (n, 3), and the normal matrices ``X^T W X``, shape (n, 3, 3)
    (shared by :func:`ring_curve` and :func:`~bayescal.image.noise.ring_scatter_scale`)."""
    m = X.shape[0]
    # as matrix products (BLAS): the einsum over (n, m, 3, 3) took most of a tracked frame
    A = (w @ (X[:, :, None] * X[:, None, :]).reshape(m, 9)).reshape(-1, 3, 3) + 1e-9 * np.eye(3)
    return np.linalg.solve(A, ((w * y) @ X)[..., None])[..., 0], A


def ring_curve(phi, r, valid, *, half_deg=30.0, iters=5):
    """A robust local quadratic of the ring's radius over azimuth: at each profile, a
    tricube-weighted quadratic in the azimuth over ``half_deg`` degrees either side,
    through the ``valid`` radii, refitted with Tukey's biweight on its residuals (so that a
    run of points on another ridge, a rail or a text bar for a few degrees, does not bend
    it). Wider than the running median's window, it sees such a run as off the ring;
    quadratic, it follows the ring's slope and bend between a room's corners.

    Parameters
    ----------
    phi, r : ndarray, shape (n,)
        Azimuths (rad, evenly spaced) and radii (px) of the profiles' points.
    valid : ndarray of bool, shape (n,)
        Points that may carry the curve.

    Returns
    -------
    ndarray, shape (n,)
        The curve's radius at each profile, px (NaN where no valid point is near).
    """
    n = len(phi)
    half = max(3, int(round(half_deg / 360.0 * n)))
    off = np.arange(-half, half + 1)
    x = off / half
    X = np.stack([np.ones_like(x), x, x ** 2], -1)               # (m, 3)
    ok = valid & np.isfinite(r)
    y = circular_windows(np.where(ok, r, 0.0), half)
    tri = (1 - np.abs(x) ** 3)[None] ** 3 * circular_windows(ok, half)
    w = tri
    coef = np.full((n, 3), np.nan)
    for t in range(iters):
        coef, _ = local_quadratic(w, X, y)
        res = y - coef @ X.T
        s = 1.4826 * float(np.median(np.abs(r[ok] - coef[ok, 0]))) if ok.any() else 1.0
        # the scale shrinks from 1 px over the refits: a fit first pulled by a run off the
        # ring is not locked there by a scale already small
        u = res / (4.685 * max(s, 0.1, 2.0 ** -t))
        w = tri * np.maximum(1 - u ** 2, 0.0) ** 2              # Tukey's biweight
    return np.where(tri.sum(1) > 3, coef[:, 0], np.nan)
