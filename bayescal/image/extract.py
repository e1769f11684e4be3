"""Laser pixels from an image, with a covariance per point.

:func:`extract_laser` reads radial profiles from a centre inside the ring, finds
one sub-pixel peak per azimuth (a weighted Gaussian fit to five samples), rejects
distractors by ring consistency, and propagates the image noise through the fit
to each point's variance along the ring's normal. The method and its measured
accuracy are in ``docs/images.md``.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.ndimage import grey_opening, median_filter

from .noise import noise_model
from .read import as_gray, read_image

__all__ = ["LaserPixels", "extract_laser", "laser_frame", "IMAGE_SUFFIXES"]

_OFFS = np.arange(-2, 3)


@dataclass(frozen=True)
class LaserPixels:
    """Laser centre-line pixels with their uncertainty.

    Attributes
    ----------
    pixels : ndarray, shape (N, 2)
        ``(u, v)`` in px.
    covariance : ndarray, shape (N, 2, 2)
        Covariance of each pixel, px^2: the fit's variance along the ring's
        normal, ``along_sd**2`` along the ring.
    snr : ndarray, shape (N,)
        Peak height over the noise sd at the peak.
    flagged : ndarray of bool, shape (N,)
        Points that fail the ring-consistency or SNR gates (likely distractors).
    center : ndarray, shape (2,)
        Centre of the radial profiles, px.
    """

    pixels: np.ndarray
    covariance: np.ndarray
    snr: np.ndarray
    flagged: np.ndarray
    center: np.ndarray

    def __len__(self):
        return len(self.pixels)

    @property
    def sd_normal(self):
        """ndarray, shape (N,): sd along the ring's normal, px (smallest eigenvalue)."""
        return np.sqrt(np.linalg.eigvalsh(self.covariance)[:, 0])


def _estimate_center(img):
    """Centre of the ring: a robust circle fit to the brightest pixels of the ring."""
    line = img - grey_opening(img, size=(7, 7))        # thin bright structures only
    thr = np.quantile(line, 0.998)
    vv, uu = np.nonzero(line >= thr)
    w = np.ones(len(uu))
    for _ in range(8):
        A = np.stack([uu, vv, np.ones_like(uu)], axis=1).astype(float)
        b = uu.astype(float) ** 2 + vv.astype(float) ** 2
        sol = np.linalg.lstsq(A * w[:, None], b * w, rcond=None)[0]
        c = sol[:2] / 2
        R = np.sqrt(sol[2] + c @ c)
        res = np.hypot(uu - c[0], vv - c[1]) - R
        s = 1.4826 * np.median(np.abs(res)) + 0.5
        w = 1.0 / np.maximum(1.0, np.abs(res) / (2 * s))
    return c, R


def _bilinear(img, u, v):
    """Samples and their pixel weights: values (...), indices (..., 4, 2), weights (..., 4)."""
    H, W = img.shape
    u0 = np.clip(np.floor(u).astype(int), 0, W - 2)
    v0 = np.clip(np.floor(v).astype(int), 0, H - 2)
    fu, fv = u - u0, v - v0
    idx = np.stack([np.stack([v0, u0], -1), np.stack([v0, u0 + 1], -1),
                    np.stack([v0 + 1, u0], -1), np.stack([v0 + 1, u0 + 1], -1)], axis=-2)
    wts = np.stack([(1 - fu) * (1 - fv), fu * (1 - fv), (1 - fu) * fv, fu * fv], axis=-1)
    vals = np.sum(img[idx[..., 0], idx[..., 1]] * wts, axis=-1)
    return vals, idx, wts


def _profiles(img, center, phi, radii):
    radii = np.atleast_2d(radii)
    u = center[0] + np.cos(phi)[:, None] * radii
    v = center[1] + np.sin(phi)[:, None] * radii
    return _bilinear(img, u, v)[0]


def _pick(prof, radii, r_ref, gate):
    """Index of the highest local maximum per profile (within ``gate`` px of r_ref)."""
    p = prof.copy()
    if r_ref is not None:
        p[np.abs(radii[None, :] - r_ref[:, None]) > gate] = -np.inf
    p[:, :2] = p[:, -2:] = -np.inf
    return np.argmax(p, axis=1)


def _fit_peak(img, var_img, center, phi, r_pk):
    """Gaussian fit to 5 radial samples (1 px apart) around r_pk; variance by propagation.

    Returns the peak radius (px), its variance (px^2), the height and the SNR.
    """
    radii = r_pk[:, None] + _OFFS[None, :]
    u = center[0] + np.cos(phi)[:, None] * radii
    v = center[1] + np.sin(phi)[:, None] * radii
    vals, idx, wts = _bilinear(img, u, v)
    ends = np.concatenate([_profiles(img, center, phi, r_pk[:, None] + o) for o in
                           (np.array([-5.0, -4.0]), np.array([4.0, 5.0]))], axis=1)
    base = np.median(ends, axis=1)
    s = np.maximum(vals - base[:, None], 1e-3 * np.maximum(vals.max(1), 1)[:, None])
    # weighted quadratic fit of log(s) against x, weights s^2 (Caruana)
    X = np.stack([np.ones(5), _OFFS, _OFFS ** 2], axis=1).astype(float)
    Wt = s ** 2
    XtW = X.T[None] * Wt[:, None, :]
    Q = np.linalg.solve(XtW @ X[None], XtW)                    # (N, 3, 5)
    coef = Q @ np.log(s)[..., None]
    b, c = coef[:, 1, 0], np.minimum(coef[:, 2, 0], -1e-3)
    mu = np.clip(-b / (2 * c), -2.0, 2.0)
    dmu_dy = -Q[:, 1] / (2 * c[:, None]) + b[:, None] * Q[:, 2] / (2 * c[:, None] ** 2)
    dmu_ds = dmu_dy / s                                         # (N, 5)
    # to pixels: sum the coefficients of each pixel (samples share pixels)
    anchor = idx.reshape(len(phi), -1, 2).min(axis=1)
    loc = idx - anchor[:, None, None, :]
    flat = (loc[..., 0] * 8 + loc[..., 1]).reshape(len(phi), -1)
    coefs = np.zeros((len(phi), 64))
    np.add.at(coefs, (np.arange(len(phi))[:, None], flat),
              (dmu_ds[..., None] * wts).reshape(len(phi), -1))
    gi = anchor[:, None, :] + np.stack(np.unravel_index(np.arange(64), (8, 8)), -1)[None]
    gi[..., 0] = np.clip(gi[..., 0], 0, img.shape[0] - 1)
    gi[..., 1] = np.clip(gi[..., 1], 0, img.shape[1] - 1)
    var = np.sum(coefs ** 2 * var_img[gi[..., 0], gi[..., 1]], axis=1)
    # goodness of fit (residuals in grey levels over their sd, 2 degrees of freedom)
    resid = (np.log(s) - (X[None] @ coef)[..., 0]) * s
    sd_s = np.sqrt(np.sum(wts ** 2 * var_img[idx[..., 0], idx[..., 1]], axis=-1))
    chi2 = np.sum((resid / sd_s) ** 2, axis=1) / 2.0
    height = s[:, 2]
    snr = height / np.sqrt(var_img[idx[:, 2, 0, 0], idx[:, 2, 0, 1]])
    return r_pk + mu, var, height, snr, chi2


def _smooth_radius(phi_r, n_win):
    """Circular running median of the ring radius over ``n_win`` azimuths."""
    return median_filter(phi_r, size=n_win, mode="wrap")


def _covariances(phi, r, r_smooth, var_r, along_sd):
    """Covariances (N, 2, 2): radial variance projected on the ring's normal."""
    n = len(phi)
    dphi = 2 * np.pi / n
    dr = (np.roll(r_smooth, -1) - np.roll(r_smooth, 1)) / (2 * dphi)
    e_r = np.stack([np.cos(phi), np.sin(phi)], -1)
    e_p = np.stack([-np.sin(phi), np.cos(phi)], -1)
    tang = dr[:, None] * e_r + r[:, None] * e_p
    tang /= np.linalg.norm(tang, axis=1, keepdims=True)
    normal = np.stack([tang[:, 1], -tang[:, 0]], -1)
    cos_a = np.abs(np.sum(normal * e_r, axis=1))
    var_n = var_r * cos_a ** 2
    return (var_n[:, None, None] * normal[:, :, None] * normal[:, None, :]
            + along_sd ** 2 * tang[:, :, None] * tang[:, None, :])


def extract_laser(image, *, background=None, center=None, channel=0, n_azimuth=None,
                  min_snr=5.0, gate_px=3.0, along_sd=5.0, var_floor=2.5e-3):
    """Extract the laser centre line, one sub-pixel point per image azimuth.

    Parameters
    ----------
    image : ndarray, shape (H, W) or (H, W, C)
        The image with the laser on (8 or 16 bit, or float).
    background : ndarray, shape (H, W) or (H, W, C), optional
        The same view with the laser off, subtracted before the search.
    center : array_like, shape (2,), optional
        Centre of the radial profiles ``(u, v)`` px (e.g. ``(u0, v0)``); by default
        the centre of a robust circle fit to the brightest pixels.
    channel : int, optional
        Colour channel of the laser in a colour image (0: red).
    n_azimuth : int, optional
        Number of profiles; default one per 2 px of the ring's circumference.
    min_snr : float, optional
        Points whose peak is below ``min_snr`` noise sds are flagged.
    gate_px : float, optional
        Points farther than ``gate_px`` (or 5 of their sds) from the smoothed
        ring are flagged.
    along_sd : float, optional
        Standard deviation given along the ring, px (a point may slide along it).
    var_floor : float, optional
        Variance added along the normal, px^2 (interpolation and model error).

    Returns
    -------
    LaserPixels

    Examples
    --------
    >>> import numpy as np
    >>> import bayescal as bc
    >>> img, truth = bc.render_image(bc.SensorParams.paper(), bc.room_walls(2500), rng=0)
    >>> lp = bc.extract_laser(img)
    >>> lp.pixels.shape[1], lp.covariance.shape[1:]
    (2, (2, 2))
    """
    img = as_gray(image, channel=channel, name="image")
    if background is not None:
        bg = as_gray(background, channel=channel, name="background")
        if bg.shape != img.shape:
            raise ValueError(f"background must have the image's shape {img.shape}, got {bg.shape}")
        # the texture cancels in the difference: its second differences are noise only
        var_img = noise_model(img - bg, levels=0.5 * (img + bg))(img + bg)
        img = img - bg
    else:
        var_img = noise_model(img)(img)
    if center is None:
        c, R = _estimate_center(img)
    else:
        c = np.asarray(center, dtype=float)
        if c.shape != (2,) or not np.all(np.isfinite(c)):
            raise ValueError(f"center must be (u, v) px, finite, got {center!r}")
        R = None
    return _extract(img, var_img, c, R, n_azimuth=n_azimuth, min_snr=min_snr,
                    gate_px=gate_px, along_sd=along_sd, var_floor=var_floor)


def _extract(img, var_img, c, R, *, n_azimuth, min_snr, gate_px, along_sd, var_floor):
    H, W = img.shape
    r_max = max(min(c[0], c[1], W - 1 - c[0], H - 1 - c[1]) - 6, 10)
    radii = np.arange(3.0, r_max)
    n = int(n_azimuth) if n_azimuth else int(np.clip(np.pi * (R or 100.0), 90, 3600))
    phi = np.linspace(-np.pi, np.pi, n, endpoint=False)
    prof = _profiles(img, c, phi, radii)
    r0 = radii[_pick(prof, radii, None, 0)]
    r_s = _smooth_radius(r0, max(5, n // 24) | 1)
    r1 = radii[_pick(prof, radii, r_s, 2 * gate_px + 2)]
    r, var_r, height, snr, chi2 = _fit_peak(img, var_img, c, phi, r1)
    # misfit beyond noise (saturation, texture under the stripe) inflates every variance:
    # the median of chi2/2 with 2 degrees of freedom is ln 2 for a fit that matches
    scale = max(1.0, float(np.median(chi2[np.isfinite(chi2)])) / np.log(2.0))
    var_r = np.maximum(scale, np.nan_to_num(chi2, nan=scale)) * var_r + var_floor
    r_s = _smooth_radius(r, max(5, n // 36) | 1)
    # a lamp or a ghost: off the smoothed ring, a profile unlike the beam (chi2/2 > 6.9 has
    # probability 0.001 for a good fit), or far brighter or dimmer than its neighbours
    h_s = median_filter(height, size=max(5, n // 36) | 1, mode="wrap")
    flagged = ((np.abs(r - r_s) > np.maximum(gate_px, 5 * np.sqrt(var_r)))
               | (snr < min_snr) | ~np.isfinite(r) | (chi2 > 6.9 * scale)
               | (height > 3 * h_s) | (height < h_s / 3))
    keep = height > 0
    pix = c + r[:, None] * np.stack([np.cos(phi), np.sin(phi)], -1)
    cov = _covariances(phi, r, r_s, var_r, along_sd)
    return LaserPixels(pixels=pix[keep], covariance=cov[keep], snr=snr[keep],
                       flagged=flagged[keep], center=np.asarray(c, dtype=float))


#: file suffixes read as images (a reconstruction frame given as an image is extracted)
IMAGE_SUFFIXES = (".png", ".tif", ".tiff", ".jpg", ".jpeg")


def laser_frame(path, *, center=None):
    """A frame of laser pixels from an image file: the extractor's unflagged pixels and
    their covariances.

    Parameters
    ----------
    path : pathlib.Path
    center : array_like, shape (2,), optional
        Centre of the radial profiles, px (a calibration's principal point).

    Returns
    -------
    tuple
        ``(path, pixels (N, 2) px, covariance (N, 2, 2) px^2)``.

    Raises
    ------
    UsageError
        Unreadable image, or no laser pixel the extractor trusts.
    """
    from ..errors import UsageError

    try:
        lp = extract_laser(read_image(path), center=center)
    except (OSError, ValueError) as exc:
        raise UsageError(f"{path}: cannot extract laser pixels ({exc})") from None
    keep = ~np.asarray(lp.flagged, bool)
    if not keep.any():
        raise UsageError(f"{path}: the extractor found no laser pixels it trusts")
    return path, lp.pixels[keep], lp.covariance[keep]
