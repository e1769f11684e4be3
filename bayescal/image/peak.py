"""Sub-pixel peaks of radial profiles, with their variance propagated from the pixels."""

from __future__ import annotations

import numpy as np

__all__ = ["bilinear", "corner_sum", "fit_peaks", "flank_baseline", "path_peaks"]

_OFFS = np.arange(-2, 3)


def bilinear(img, u, v):
    """Samples and their pixel weights: values (...), indices (..., 4, 2), weights (..., 4)."""
    H, W = img.shape
    u0 = np.clip(np.floor(u).astype(int), 0, W - 2)
    v0 = np.clip(np.floor(v).astype(int), 0, H - 2)
    fu, fv = np.clip(u - u0, 0, 1), np.clip(v - v0, 0, 1)
    idx = np.stack([np.stack([v0, u0], -1), np.stack([v0, u0 + 1], -1),
                    np.stack([v0 + 1, u0], -1), np.stack([v0 + 1, u0 + 1], -1)], axis=-2)
    wts = np.stack([(1 - fu) * (1 - fv), fu * (1 - fv), (1 - fu) * fv, fu * fv], axis=-1)
    vals = corner_sum(img[idx[..., 0], idx[..., 1]] * wts)
    return vals, idx, wts


def corner_sum(g):
    """``np.sum(g, axis=-1)`` of the 4 corners of bilinear samples (..., 4), in the order
    the reduction takes them, ``((g0 + g1) + g2) + g3`` (its numbers, checked; 10x faster
    than a reduction over so short an axis)."""
    return ((g[..., 0] + g[..., 1]) + g[..., 2]) + g[..., 3]


def flank_baseline(values, k, level, *, inner=3, outer=9, q=5.0):
    """A straight baseline under the 5 samples around each profile's peak: ``level`` at the
    peak, and the slope of the line through a low percentile of each of its two flanks.

    A running median over the profile (the ridge search's high-pass) is lifted wherever a
    second ridge shares its window, as a ghost of the ring 6-8 px away does: the lift is
    uneven across the peak, a tilt that moves it by up to 0.27 px. Each flank (``inner``
    to ``outer`` px from the peak) gives one level, its ``q`` percentile (near its least
    sample), which a ridge covering part of the flank does not lift; on a straight slope of
    the background both sit at their flank's low end, so their line has its slope. Only the
    slope is taken: their shared low bias would spoil the fit's misfit, which scales the
    variances; the level at the peak (the running median's) moves no peak.

    Parameters
    ----------
    values : ndarray, shape (n, K)
        Profiles on a 1-px radial grid.
    k : ndarray of int, shape (n,)
        Index of each profile's peak sample.
    level : ndarray, shape (n,)
        The baseline at the peak sample.

    Returns
    -------
    ndarray, shape (n, 5)
        The baseline at the peak's samples ``k - 2 ... k + 2``.
    """
    n, K = values.shape
    i = np.arange(n)[:, None]
    side = np.arange(inner, outer + 1)[None]
    lo = np.percentile(values[i, np.clip(k[:, None] - side, 0, K - 1)], q, axis=1)
    hi = np.percentile(values[i, np.clip(k[:, None] + side, 0, K - 1)], q, axis=1)
    return np.asarray(level, float)[:, None] + ((hi - lo) / (inner + outer))[:, None] * _OFFS[None]


def _pixel_variance(dmu_ds, idx, wts, var_px):
    """Variance of a function of bilinear samples, ``sum (d mu / d pixel)^2 var(pixel)``:
    the coefficients of samples that share a pixel are summed first (they are correlated);
    ``var_px``: the variance at the pixels ``idx`` (N, S, 4 m, 2) (the 4 corners of each of
    the m rays' bilinear samples, (v0, u0) first).

    Each pixel's summed coefficient is found in an 8x8 grid about the samples' corner
    (bincount); ``sum_p coef_p^2 var_p`` is then taken as ``sum`` over the (sample, pixel)
    pairs of ``c * coef_p * var_p``, which reads the variance at the pairs' pixels only."""
    n = len(dmu_ds)
    anchor = idx[:, :, 0::4].reshape(n, -1, 2).min(axis=1)      # the samples' (v0, u0)
    loc = np.clip(idx - anchor[:, None, None, :], 0, 7)
    slot = (np.arange(n)[:, None] * 64 + (loc[..., 0] * 8 + loc[..., 1]).reshape(n, -1))
    c = (dmu_ds[..., None] * wts).reshape(n, -1)
    coefs = np.bincount(slot.ravel(), weights=c.ravel(), minlength=n * 64)
    return np.sum(c * coefs[slot] * var_px.reshape(n, -1), axis=1)


def fit_peaks(img, var_img, center, phi, r_pk, base, sub=(0.0,)):
    """A Gaussian through 5 (or 3) radial samples (1 px apart) around ``r_pk`` per azimuth.

    Parameters
    ----------
    img, var_img : ndarray, shape (H, W)
        Grey levels and their noise variance.
    center : ndarray, shape (2,)
    phi, r_pk : ndarray, shape (N,)
        Azimuth (rad) and the integer-grid radius of the highest sample (px).
    base : ndarray, shape (N, 5) or (N, 3)
        Baseline under the 5 (or 3) samples (the profile's running median), subtracted;
        its width sets the number of samples.
    sub : sequence of float, optional
        Azimuth offsets (rad) of the rays averaged into each sample.

    Returns
    -------
    r, var, height, snr, chi2, width : ndarray, shape (N,)
        Peak radius (px), its variance (px^2), height above the baseline (grey levels),
        height over the noise sd, misfit per degree of freedom (2; NaN with 3 samples,
        which a Gaussian fits exactly), Gaussian sd (px); the variance is at most the
        square of the number of samples.
    dmu_ds : ndarray, shape (N, 5) or (N, 3)
        Derivative of the peak radius with respect to each sample, px per grey level.
    """
    offs = np.arange(base.shape[1]) - base.shape[1] // 2
    radii = (r_pk[:, None] + offs[None, :])[..., None]
    ang = phi[:, None, None] + np.asarray(sub, float)[None, None, :]
    vals, idx, wts = bilinear(img, center[0] + np.cos(ang) * radii, center[1] + np.sin(ang) * radii)
    m = len(sub)
    vals = vals.mean(axis=-1)                                  # (N, 5)
    idx = idx.reshape(len(phi), len(offs), 4 * m, 2)
    wts = wts.reshape(len(phi), len(offs), 4 * m) / m
    s = np.maximum(vals - base, 1e-3 * np.maximum(np.abs(vals - base).max(1), 1)[:, None])
    # weighted quadratic fit of log(s) against x, weights s^2 (Caruana)
    X = np.stack([np.ones(len(offs)), offs, offs ** 2], axis=1).astype(float)
    XtW = X.T[None] * (s ** 2)[:, None, :]
    Q = np.linalg.solve(XtW @ X[None], XtW)                    # (N, 3, 5)
    coef = Q @ np.log(s)[..., None]
    b, c = coef[:, 1, 0], np.minimum(coef[:, 2, 0], -1e-3)
    mu = np.clip(-b / (2 * c), offs[0], offs[-1])
    dmu_dy = -Q[:, 1] / (2 * c[:, None]) + b[:, None] * Q[:, 2] / (2 * c[:, None] ** 2)
    dmu_ds = dmu_dy / s
    # a flat or one-sided profile (c near 0) has a peak clipped to the samples' span and a
    # linearised variance without bound: the span's square bounds it
    var_px = var_img[idx[..., 0], idx[..., 1]]
    var = np.minimum(_pixel_variance(dmu_ds, idx, wts, var_px), float(len(offs)) ** 2)
    resid = (np.log(s) - (X[None] @ coef)[..., 0]) * s
    sd_s = np.sqrt(np.sum(wts ** 2 * var_px, axis=-1))
    dof = len(offs) - 3
    chi2 = np.sum((resid / sd_s) ** 2, axis=1) / dof if dof else np.full(len(phi), np.nan)
    j = len(offs) // 2
    height = vals[:, j] - base[:, j]
    snr = height / sd_s[:, j]
    return r_pk + mu, var, height, snr, chi2, np.sqrt(-0.5 / c), dmu_ds


def path_peaks(sig, var_img, pol, k, flank, narrow=None, clip=None, fits=None):
    """The peaks of profiles ``pol`` (a :class:`~bayescal.image.ring.PolarImage`) at samples
    ``k`` (n,), as :func:`fit_peaks` returns them (``r``, ``var``, ``height``, ``snr``,
    ``chi2``, ``width``), of signal ``sig`` and its noise variance ``var_img``, the
    baseline from the flanks (``flank``: a laser-off difference) or the profiles' running
    median: a Gaussian through 5 samples, or through the 3 middle
    ones where ``narrow`` (n,) (a neighbouring ridge 2 px away shares a 5-sample window);
    where the peak is clipped (``clip`` (n, K): the samples at the sensor's saturation), the
    middle of the clipped run (:func:`_plateau`). ``fits`` (a dict) keeps the 5-sample fits
    for the next pass, which refits only the profiles whose peak sample moved (each
    profile's fit is its own: the same numbers)."""
    i = np.arange(len(pol.phi))
    base = flank_baseline(pol.values, k, pol.base[i, k]) if flank else \
        pol.base[i[:, None], k[:, None] + np.arange(-2, 3)[None]]
    redo = np.nonzero(k != fits["k"])[0] if fits else i
    out = [a.copy() for a in fits["out"]] if fits else [None] * 6
    if len(redo):
        new = fit_peaks(sig, var_img, pol.center, pol.phi[redo], pol.radii[k[redo]], base[redo],
                        sub=pol.sub)[:6]
        out = list(new) if not fits else out
        for a, b in zip(out, new, strict=True):
            a[redo] = b
    if fits is not None:
        fits.update(k=k.copy(), out=[a.copy() for a in out])
    if narrow is not None and narrow.any():
        j = np.nonzero(narrow)[0]
        sub = fit_peaks(sig, var_img, pol.center, pol.phi[j], pol.radii[k[j]], base[j, 1:4],
                        sub=pol.sub)[:6]
        for a, b in zip(out, sub, strict=True):
            a[j] = b
    if clip is not None:
        _plateau(pol, k, clip, out)
    return out


def _plateau(pol, k, clipped, out):
    """Peaks clipped at the sensor's saturation (``clipped`` (n, K): the samples there): a
    Gaussian through a flat top is no estimate (1-1.5 px off on a third renderer's clipped
    stripes); the middle of the run of clipped samples is, to the quantisation of its two
    ends (variance 1/24 px^2). Updates ``out`` (r, var, height, snr, chi2, width) in
    place."""
    n, K = clipped.shape
    i = np.arange(n)
    on = clipped[i, k]
    if not on.any():
        return
    j = np.arange(1, 16)
    left = clipped[i[:, None], np.clip(k[:, None] - j[None], 0, K - 1)]
    right = clipped[i[:, None], np.clip(k[:, None] + j[None], 0, K - 1)]
    a = np.argmin(np.column_stack([left, np.zeros(n, bool)]), axis=1)      # run lengths
    b = np.argmin(np.column_stack([right, np.zeros(n, bool)]), axis=1)
    on &= (a + b >= 1) & (a < 15) & (b < 15)
    r, var, _, _, chi2, _ = out
    r[on] = pol.radii[k[on]] + 0.5 * (b[on] - a[on])
    var[on] = 1.0 / 24.0
    chi2[on] = np.nan
