"""The image's noise: variance as a linear function of the grey level, from the image itself."""

from __future__ import annotations

import numpy as np
from scipy.ndimage import uniform_filter

__all__ = ["noise_model"]


def noise_model(img, *, levels=None, n_bins=12):
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

    Returns
    -------
    callable
        ``var(levels)``: ndarray of the noise variance, grey levels^2, floored at
        the smallest binned variance.
    """
    d = img[:, :-2] - 2 * img[:, 1:-1] + img[:, 2:]
    level = uniform_filter(img if levels is None else levels, 3)[:, 1:-1]
    edges = np.unique(np.quantile(level, np.linspace(0, 1, n_bins + 1)))
    which = np.clip(np.searchsorted(edges, level, side="right") - 1, 0, len(edges) - 2)
    lv, vv = [], []
    for k in range(len(edges) - 1):
        dk = d[which == k]
        if dk.size > 50:
            lv.append(np.median(level[which == k]))
            vv.append((1.4826 * np.median(np.abs(dk - np.median(dk)))) ** 2 / 6.0)
    lv, vv = np.asarray(lv), np.asarray(vv)
    floor = max(float(np.min(vv)) if vv.size else 1.0, 1.0 / 12.0)
    if vv.size >= 2 and np.ptp(lv) > 0:
        b, a = np.polyfit(lv, vv, 1)
        b = max(b, 0.0)
    else:
        a, b = floor, 0.0
    return lambda levels: np.maximum(a + b * np.clip(levels, 0, None), floor)
