"""An independent extractor of a ring laser in a dark frame, to check bayescal's on real
frames where no truth exists.

Written from a plain recipe (radial profiles of the red channel from a centre inside the ring,
white and border pixels left out, a sub-pixel centroid within 1.5 px of each profile's peak, a
robust Fourier curve r(theta) of order 12; a second pass within 6 px of the first's curve),
not from bayescal's extractor: it shares no code with ``bayescal.image``. It needs only a
centre inside the ring (any point near the ring's middle; the tests pass bayescal's profile
centre, which moves no peak).
"""

import numpy as np
from scipy.ndimage import map_coordinates

#: profiles per turn and the Fourier order of the ring's curve
N_AZIMUTH, ORDER = 720, 12


def _design(theta):
    return np.column_stack([np.ones(len(theta))] + [f(j * theta) for j in range(1, ORDER + 1)
                                                    for f in (np.cos, np.sin)])


def _profiles(rgb, center, theta, radii):
    a = np.asarray(rgb, float)[..., :3]
    red = np.where(a.min(axis=2) > 0.6 * a.max(), 0.0, a[..., 0])    # white light left out
    red -= np.median(red)
    u = center[0] + np.cos(theta)[:, None] * radii
    v = center[1] + np.sin(theta)[:, None] * radii
    prof = map_coordinates(red, [v.ravel(), u.ravel()], order=1, cval=0.0).reshape(u.shape)
    H, W = red.shape                   # a bright column or row at the image's border
    return np.where((u > 8) & (u < W - 9) & (v > 8) & (v < H - 9), prof, 0.0)


def _peaks(prof, radii, band):
    """Per profile, the centroid of the samples within 1.5 px of its highest (NaN if faint)."""
    sel = prof if band is None else np.where(np.abs(radii[None] - band[:, None]) < 6.0, prof,
                                             -np.inf)
    k = np.argmax(sel, axis=1)
    r = np.full(len(prof), np.nan)
    for i, ki in enumerate(k):
        m = np.abs(radii - radii[ki]) <= 1.5
        w = prof[i, m] - np.min(prof[i, m])
        if prof[i, ki] > 10 and w.sum() > 0:
            r[i] = np.sum(w * radii[m]) / w.sum()
    return r


def _robust_curve(theta, r):
    """Tukey-biweight Fourier fit: coefficients and the robust sd of the residuals."""
    ok = np.isfinite(r)
    X, w = _design(theta), ok.astype(float)
    for _ in range(20):
        coef = np.linalg.lstsq(X[ok] * w[ok, None], r[ok] * w[ok], rcond=None)[0]
        res = r - X @ coef
        s = 1.4826 * np.median(np.abs(res[ok]))
        u = np.nan_to_num(res / (4.685 * s), nan=9.0)
        w = np.where(np.abs(u) < 1, (1 - u ** 2) ** 2, 0.0) * ok
    return coef, s


def reference_ring(rgb, center):
    """The ring of a dark colour frame about ``center`` (u, v) px.

    Returns
    -------
    dict
        ``theta`` (n,), ``r`` (n,) the points' radii (NaN where none), ``coef`` the curve's
        Fourier coefficients, ``sd`` the points' robust sd about it (px), ``center``.
    """
    c = np.asarray(center, float)
    theta = np.linspace(-np.pi, np.pi, N_AZIMUTH, endpoint=False)
    radii = np.arange(5.0, 0.5 * np.hypot(*np.shape(rgb)[:2]), 0.25)
    prof = _profiles(rgb, c, theta, radii)
    band = None
    for _ in range(2):
        r = _peaks(prof, radii, band)
        coef, sd = _robust_curve(theta, r)
        band = _design(theta) @ coef
    return {"theta": theta, "r": r, "coef": coef, "sd": sd, "center": c}


def offsets(ref, pixels):
    """Radial offsets (px) of ``pixels`` (N, 2) from the reference curve."""
    d = np.asarray(pixels, float) - ref["center"]
    return np.hypot(d[:, 0], d[:, 1]) - _design(np.arctan2(d[:, 1], d[:, 0])) @ ref["coef"]
