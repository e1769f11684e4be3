"""Score a laser extraction against the true ring of a rendered image (``renderer2.Truth2``),
or against another extraction of the same image (:func:`agreement`: the ring tracker's
against the full extractor's).

Each extracted pixel is compared with the true ring at the same image angle about ``center``:
its error is the radial offset from the ring, projected on the ring's normal
(``(r - r_true) cos psi``, ``tan psi = r_true' / r_true``), in px, positive away from the centre.
"""

import numpy as np


def _ring_polar(truth, center):
    """The true ring as radius against image angle about ``center``, sorted, for the visible
    azimuths."""
    pix = truth.pixels[truth.visible]
    phi = np.arctan2(pix[:, 1] - center[1], pix[:, 0] - center[0])
    r = np.hypot(pix[:, 0] - center[0], pix[:, 1] - center[1])
    order = np.argsort(phi)
    return phi[order], r[order]


def _ring_radius(phi_t, r_t, phi):
    """Radius of the ring and its derivative d r / d phi at image angles ``phi``, with NaN in
    gaps of the visible ring wider than 3 azimuth steps."""
    r = np.interp(phi, phi_t, r_t, period=2 * np.pi)
    ext = np.concatenate([phi_t[-1:] - 2 * np.pi, phi_t, phi_t[:1] + 2 * np.pi])
    rext = np.concatenate([r_t[-1:], r_t, r_t[:1]])
    dr = np.gradient(rext, ext)[1:-1]
    drdphi = np.interp(phi, phi_t, dr, period=2 * np.pi)
    step = 2 * np.pi / max(len(phi_t), 1)
    k = np.searchsorted(ext, phi)
    gap = (ext[np.clip(k, 0, len(ext) - 1)] - ext[np.clip(k - 1, 0, len(ext) - 1)]) > 3.5 * step
    return np.where(gap, np.nan, r), drdphi


def score_extraction(pixels, truth, center=None, *, flagged=None, gross_px=1.0, n_bins=None):
    """Errors of extracted laser pixels against the true ring.

    Parameters
    ----------
    pixels : array_like, shape (N, 2)
        Extracted ``(u, v)``, px (same pixel convention as the renderer: integer at centres).
    truth : renderer2.Truth2
    center : array_like, shape (2,), optional
        The point the ring is parametrised about; the principal point by default.
    flagged : array_like of bool, shape (N,), optional
        Points the extractor flagged; they are left out of every number.
    gross_px : float
        A point with ``|error| > gross_px`` (or at an angle where no ring is visible) is gross.
    n_bins : int, optional
        For ``kept``: the number of azimuths the extractor sampled around the whole ring. By
        default the number of pixels given, flagged ones included (right for an extractor that
        returns one point per sampled azimuth and flags rather than drops); at least 36.

    Returns
    -------
    dict
        ``n`` points scored; ``kept``: the points at angles where the ring is visible over
        the azimuths sampled there (``n_bins`` times the visible fraction of the ring's
        azimuths), at most 1; ``bias``: mean error of the non-gross points (px); ``median``;
        ``robust_sd``: 1.4826 MAD of the errors of all points on the ring;
        ``gross``: fraction of gross points; ``rms`` of the non-gross errors;
        ``errors`` (n,) with NaN where no ring is visible.
    """
    pixels = np.asarray(pixels, float).reshape(-1, 2)
    n_bins = max(36, len(pixels)) if n_bins is None else int(n_bins)
    if flagged is not None:
        pixels = pixels[~np.asarray(flagged, bool)]
    center = truth.center if center is None else np.asarray(center, float)
    nan = float("nan")
    if not truth.ring or not np.any(truth.visible):
        return dict(n=len(pixels), kept=nan, bias=nan, median=nan, robust_sd=nan,
                    gross=1.0 if len(pixels) else 0.0, rms=nan, errors=np.full(len(pixels), nan))
    phi_t, r_t = _ring_polar(truth, center)
    phi = np.arctan2(pixels[:, 1] - center[1], pixels[:, 0] - center[0])
    r = np.hypot(pixels[:, 0] - center[0], pixels[:, 1] - center[1])
    rt, drt = _ring_radius(phi_t, r_t, phi)
    err = (r - rt) * np.cos(np.arctan2(drt, rt))
    on = np.isfinite(err)
    good = on & (np.abs(err) <= gross_px)
    ring_frac = float(np.mean(truth.visible))
    med = float(np.median(err[on])) if np.any(on) else nan
    return dict(
        n=len(pixels),
        kept=float(min(1.0, np.count_nonzero(on) / (n_bins * ring_frac))),
        bias=float(np.mean(err[good])) if np.any(good) else nan,
        median=med,
        robust_sd=float(1.4826 * np.median(np.abs(err[on] - med))) if np.any(on) else nan,
        gross=float(np.mean(~good)) if len(pixels) else 0.0,
        rms=float(np.sqrt(np.mean(err[good] ** 2))) if np.any(good) else nan,
        errors=err,
    )


def agreement(a, b, *, along_px=1.5):
    """How far two extractions of one frame agree, point by point (the tracker's against
    the full extractor's, ``docs/images.md``).

    Each point of ``a`` is paired with the point of ``b`` nearest to it if it lies within
    ``along_px`` of it along the ring; a pair's difference is taken along ``b``'s normal
    (the direction of its covariance's smaller eigenvalue: along the ring a point's place
    is the chosen azimuth of its profile, not a measurement).

    Parameters
    ----------
    a, b : LaserPixels
    along_px : float, optional

    Returns
    -------
    dict
        ``pairs`` (points unflagged in both and paired), ``diff_px`` (their differences
        along the normal, px), ``sd_ratio`` (``a``'s sd along the normal over ``b``'s),
        ``only_a`` and ``only_b`` (paired points unflagged in one only), ``unpaired``.
    """
    if len(a) == 0 or len(b) == 0:
        return dict(pairs=0, diff_px=np.zeros(0), sd_ratio=np.zeros(0), only_a=0, only_b=0,
                    unpaired=len(a))
    db = b.pixels - b.center
    ab = np.arctan2(db[:, 1], db[:, 0])
    order = np.argsort(ab)
    da = a.pixels - b.center
    aa = np.arctan2(da[:, 1], da[:, 0])
    pos = np.searchsorted(ab[order], aa)
    cand = order[np.stack([(pos - 1) % len(b), pos % len(b)], -1)]
    dist = np.linalg.norm(a.pixels[:, None] - b.pixels[cand], axis=-1)
    j = cand[np.arange(len(a)), np.argmin(dist, axis=1)]
    w, v = np.linalg.eigh(b.covariance[j])
    normal = v[..., 0]
    delta = a.pixels - b.pixels[j]
    across = np.abs(np.sum(delta * normal, axis=1))
    paired = np.hypot(*delta.T) ** 2 - across ** 2 <= along_px ** 2
    both = paired & ~a.flagged & ~b.flagged[j]
    return dict(pairs=int(both.sum()), diff_px=across[both],
                sd_ratio=a.sd_normal[both] / np.sqrt(np.maximum(w[both, 0], 1e-300)),
                only_a=int(np.sum(paired & ~a.flagged & b.flagged[j])),
                only_b=int(np.sum(paired & a.flagged & ~b.flagged[j])),
                unpaired=int(np.sum(~paired)))
