"""Realistic ring-laser frames with a known truth: a thin red elliptical ring composited onto
a real frame (``../shared/data/pipe``), with the colour leakage, width and brightness
measured on the real dark frames (docs/images.md, "Real ring-laser frames").

Measured on the eight real dark frames (profiles across the ring at the extracted points,
normalised by the red peak, median over the points with a peak over 20 grey levels): the red
stripe is a Gaussian of sd 1.47-1.56 px (with wider wings); green and blue are narrower (sd
0.92-1.01 px) and peak at 0.44-0.56 of the red (colour interpolation of a thin stripe); the
red peak runs from 13-43 grey levels on the faint side to 71-156 on the bright one; the points
scatter 0.13-0.17 px about a smooth curve (a laser's speckle: :data:`SPECKLE`).

:func:`composite_ring` draws that stripe along an ellipse (off the image's centre, a
brightness varying around it, a gap where a mount blocks it), optionally through a Bayer
mosaic and its bilinear demosaic and a JPEG round trip (``renderer3``'s), and returns the
frame as a camera writes it (uint8 RGB) with the ring's true centre line.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

#: the stripe as measured on the real dark frames (see the module's docstring)
RED_SD = 1.5
LEAK = 0.5
LEAK_SD = 0.95
#: speckle contrast: the real dark frames' points scatter 0.13-0.17 px about a smooth curve,
#: a dark composite's without speckle 0.05 px, with 0.15 0.145-0.164 px (measured, 2 seeds)
SPECKLE = 0.15
#: the measured mean profiles across the ring (ring_002.png: offsets -6..6 px by 0.5 px,
#: per red peak): red with its wings, green and blue narrower
PROFILE_OFFSETS = np.arange(-6.0, 6.01, 0.5)
PROFILE_RED = np.array([0.01, 0.01, 0.03, 0.05, 0.07, 0.11, 0.16, 0.26, 0.40, 0.58, 0.78,
                        0.93, 1.00, 0.95, 0.79, 0.58, 0.39, 0.25, 0.17, 0.12, 0.09, 0.06,
                        0.03, 0.00, 0.00])
PROFILE_OTHER = np.array([0.00, 0.00, 0.00, 0.00, 0.00, 0.00, 0.00, 0.02, 0.08, 0.18, 0.29,
                          0.41, 0.46, 0.41, 0.29, 0.14, 0.03, 0.00, 0.00, 0.00, 0.00, 0.00,
                          0.00, 0.00, 0.00])


@dataclass
class CompositeTruth:
    """The composited ring: ``pixels`` (M, 2) px on its centre line, ``visible`` (M,) where
    it is drawn (the mount's gap aside), its ``center`` (2,) and the ellipse's ``axes``
    (a, b) px and ``angle`` (rad)."""

    pixels: np.ndarray
    visible: np.ndarray
    center: np.ndarray
    axes: tuple
    angle: float


def _ellipse_frame(shape, center, axes, angle):
    """Per pixel: an approximate signed distance to the ellipse (px, + outside) and the
    pixel's angle about the centre (rad)."""
    H, W = shape
    v, u = np.mgrid[0:H, 0:W].astype(float)
    du, dv = u - center[0], v - center[1]
    c, s = np.cos(angle), np.sin(angle)
    x, y = c * du + s * dv, -s * du + c * dv
    a, b = axes
    F = (x / a) ** 2 + (y / b) ** 2 - 1.0
    gx, gy = 2 * x / a ** 2, 2 * y / b ** 2
    # first-order distance (to 0.005 px at the stripe's centre for rings of 200 px and more)
    d = F / np.maximum(np.hypot(gx, gy), 1e-9)
    return d, np.arctan2(dv, du)


def composite_ring(base, *, center, axes=(250.0, 230.0), angle=0.3, peak=(40.0, 150.0),
                   bright_deg=60.0, gap_deg=(86.0, 94.0), red_sd=RED_SD, leak=LEAK,
                   leak_sd=LEAK_SD, measured=True, albedo=True, bayer=False, jpeg=None,
                   gain=1.0, noise=0.5, speckle=SPECKLE, rng=None, n_truth=3600):
    """A thin red elliptical ring drawn onto ``base`` with a known centre line.

    Parameters
    ----------
    base : ndarray, shape (H, W, 3) or (H, W, 4), uint8
        The frame to draw on (a real frame; an alpha channel is dropped).
    center : tuple of float
        The ellipse's centre (u, v), px.
    axes : tuple of float
        Its semi-axes, px.
    angle : float
        Its rotation, rad.
    peak : tuple of float
        The red peak (grey levels) on the ring's faint and bright sides.
    bright_deg : float
        Image angle of the bright side about the centre, deg.
    gap_deg : tuple of float
        Image angles (deg) between which the ring is hidden (a mount).
    red_sd, leak, leak_sd : float
        The red stripe's Gaussian sd (px); green and blue peak at ``leak`` of it with sd
        ``leak_sd`` (the real frames'). With ``bayer`` the stripe is drawn in red only and
        the mosaic and its demosaic make the leakage.
    measured : bool
        Draw the real frames' measured mean profiles (:data:`PROFILE_RED`,
        :data:`PROFILE_OTHER`, wings included) instead of the Gaussians.
    albedo : bool
        Scale the laser by the wall's brightness in ``base`` (a lit wall reflects the laser
        as it does the light), between 0.4 and 1.6 of its median.
    bayer : bool
        Pass the frame through an RGGB mosaic and a bilinear demosaic (renderer3's).
    jpeg : int or None
        JPEG quality of a round trip (renderer3's; 4:2:0 chroma).
    gain : float
        Factor on ``base`` (e.g. 0.05 makes a lit frame a dark one).
    noise : float
        Shot noise on the added light: sd ``sqrt(noise * light)`` grey levels.
    speckle : float
        Contrast (sd) of a multiplicative speckle on the laser, correlated over ~1 px.
    rng : numpy.random.Generator or int or None
    n_truth : int
        Points of the true centre line.

    Returns
    -------
    image : ndarray, shape (H, W, 3), uint8
    truth : CompositeTruth
    """
    rng = np.random.default_rng(rng)
    img = np.asarray(base, float)[..., :3] * gain
    H, W = img.shape[:2]
    d, phi = _ellipse_frame((H, W), center, axes, angle)
    lo, hi = peak
    amp = lo + (hi - lo) * 0.5 * (1 + np.cos(phi - np.radians(bright_deg)))
    deg = np.degrees(phi) % 360
    hidden = (deg >= gap_deg[0] % 360) & (deg <= gap_deg[1] % 360)
    amp = np.where(hidden, 0.0, amp)
    if albedo:
        from scipy.ndimage import gaussian_filter

        # the wall's reflectance as the optics see it (not the base frame's pixel noise)
        grey = gaussian_filter(img.mean(axis=2), 1.0)
        med = np.median(grey[grey > np.percentile(grey, 50)]) if grey.max() > 0 else 1.0
        amp = amp * np.clip(grey / max(med, 1e-6), 0.4, 1.6) if med > 20 else amp
    if bayer:
        red = amp * np.exp(-0.5 * (d / red_sd) ** 2)
        light = np.stack([red, 0.1 * red, 0.05 * red], axis=-1)
    elif measured:
        red = amp * np.interp(d, PROFILE_OFFSETS, PROFILE_RED, left=0.0, right=0.0)
        other = amp * np.interp(d, PROFILE_OFFSETS, PROFILE_OTHER, left=0.0, right=0.0)
        light = np.stack([red, other, other], axis=-1)
    else:
        red = amp * np.exp(-0.5 * (d / red_sd) ** 2)
        other = amp * leak * np.exp(-0.5 * (d / leak_sd) ** 2)
        light = np.stack([red, other, other], axis=-1)
    if speckle:         # a laser's speckle: multiplicative, correlated over about a pixel
        from scipy.ndimage import gaussian_filter

        sp = gaussian_filter(rng.standard_normal((H, W)), 0.8)
        light = light * np.clip(1 + speckle * sp / sp.std(), 0.0, None)[..., None]
    light = light + rng.standard_normal(light.shape) * np.sqrt(noise * light)
    out = img + light
    if bayer:
        from renderer3 import demosaic

        yy, xx = np.mgrid[0:H, 0:W]
        cfa = np.where((yy % 2 == 0) & (xx % 2 == 0), 0,
                       np.where((yy % 2 == 1) & (xx % 2 == 1), 2, 1))
        out = demosaic(np.take_along_axis(out, cfa[..., None], axis=2)[..., 0])
    out = np.clip(np.rint(out), 0, 255).astype(np.uint8)
    if jpeg is not None:
        from renderer3 import jpeg_roundtrip

        out = jpeg_roundtrip(out, quality=int(jpeg))[1]
    t = np.linspace(-np.pi, np.pi, int(n_truth), endpoint=False)
    a, b = axes
    x, y = a * np.cos(t), b * np.sin(t)
    c, s = np.cos(angle), np.sin(angle)
    pix = np.column_stack([center[0] + c * x - s * y, center[1] + s * x + c * y])
    tdeg = np.degrees(np.arctan2(pix[:, 1] - center[1], pix[:, 0] - center[0])) % 360
    vis = ~((tdeg >= gap_deg[0] % 360) & (tdeg <= gap_deg[1] % 360))
    vis &= (pix[:, 0] >= 0) & (pix[:, 0] <= W - 1) & (pix[:, 1] >= 0) & (pix[:, 1] <= H - 1)
    return out, CompositeTruth(pix, vis, np.asarray(center, float), tuple(axes), float(angle))


def score_composite(lp, truth, *, gross_px=1.0):
    """Errors of an extraction against a composited ring: along the true ring's normal, of
    the unflagged points (px); kept = 1-degree bins of image angle about the ring's centre
    where it is visible that hold an unflagged point; gross = |error| > ``gross_px``; z rms
    over the non-gross with the sd across the ring (the covariance's small eigenvalue)."""
    T = truth.pixels
    t = np.roll(T, -1, 0) - np.roll(T, 1, 0)
    t /= np.linalg.norm(t, axis=1)[:, None]
    nrm = np.stack([t[:, 1], -t[:, 0]], -1)
    ok = ~np.asarray(lp.flagged, bool)
    px = lp.pixels[ok]
    k = np.argmin(np.sum((px[:, None, :] - T[None]) ** 2, -1), 1)
    e = np.sum((px - T[k]) * nrm[k], 1)
    e = np.where(truth.visible[k], e, np.inf)              # a point in the gap is gross
    sd = lp.sd_normal[ok]
    c = truth.center
    deg = lambda xy: np.unique(np.floor(np.degrees(np.arctan2(  # noqa: E731
        xy[:, 1] - c[1], xy[:, 0] - c[0])) + 180).astype(int) % 360)
    kept = float(np.isin(deg(T[truth.visible]), deg(px)).mean())
    good = np.abs(e) <= gross_px
    fin = np.isfinite(e)
    med = float(np.median(e[fin])) if fin.any() else np.nan
    return {"kept": kept, "n": int(ok.sum()),
            "robust_sd": float(1.4826 * np.median(np.abs(e[fin] - med))) if fin.any() else np.nan,
            "bias": float(np.mean(e[good])) if good.any() else np.nan,
            "gross": float(np.mean(~good)) if len(e) else np.nan,
            "z_rms": float(np.sqrt(np.mean((e[good] / sd[good]) ** 2))) if good.any() else np.nan}
