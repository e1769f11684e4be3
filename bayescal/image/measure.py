"""The laser's signal in an image, and its points measured along a ring whose path is known.

:func:`laser_signal` turns an image (and a laser-off image) into the laser's signal, its
noise variance per pixel and the saturated blobs; :func:`measure_ring` measures the laser's
points along a ring's path (a centre and a radius per azimuth): one sub-pixel peak per
azimuth (a weighted Gaussian fit to five samples), its variance propagated from the image
noise, and the gates that flag distractors. :func:`~bayescal.image.extract.extract_laser`
first locates the ring (:mod:`bayescal.image.locate`), then measures it here; a tracker
that predicts the path from the previous frame measures it the same way. Method and
measurements: ``docs/images.md``.
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from types import SimpleNamespace

import numpy as np
from scipy.ndimage import gaussian_filter, median_filter

from .._validation import check_positive
from ..errors import InvalidValueError
from .doubt import blob_mask
from .noise import clutter_variance, noise_model, ring_scatter_scale, scatter_factor
from .peak import path_peaks
from .read import as_gray, demosaiced_blur
from .ring import R_MIN, PolarImage, ridge_near, ring_circle, ring_curve, ring_model, ring_rays

__all__ = ["LaserPixels", "LaserSignal", "laser_signal", "measure_ring", "measure_polar",
           "measure_settled", "ring_azimuths", "OFFSET_SD", "BLOB_MARGIN", "MEASURE_MARGIN",
           "SEARCH_PX", "background_gray", "clip_level", "saturation_level"]

#: sd (px, per axis) of a displacement of the ring as a whole that the per-point covariances
#: leave out: wall texture under the stripe moves many neighbouring peaks the same way,
#: measured 0.01-0.04 px per image on two renderers (docs/images.md)
OFFSET_SD = 0.02

#: px by which a saturated blob (a lamp) is grown without a laser-off image, its halo's
#: reach (of the points 3 px out that it flagged on renderer2's lamp rooms, 30-93 % lay
#: within 0.5 px of the truth; 2 instead of 3 keeps 2 % more of the azimuths, measured)
BLOB_MARGIN = 2


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
    offset_sd : float
        Standard deviation (px, each axis) of an error shared by every point: a
        translation of the ring as a whole, beyond the per-point covariances. A common
        translation of the pixels is a shift of ``(u0, v0)``: pass it to the calibration
        (``calibrate_simultaneous(..., offset_sd=lp.offset_sd)``), which adds its variance
        to theirs.
    """

    pixels: np.ndarray
    covariance: np.ndarray
    snr: np.ndarray
    flagged: np.ndarray
    center: np.ndarray
    offset_sd: float = 0.0

    def __len__(self):
        return len(self.pixels)

    @property
    def sd_normal(self):
        """ndarray, shape (N,): sd along the ring's normal, px (smallest eigenvalue)."""
        return np.sqrt(np.linalg.eigvalsh(self.covariance)[:, 0])



@dataclass(frozen=True)
class LaserSignal:
    """The laser's signal in one image, ready to be searched and measured.

    Attributes
    ----------
    signal : ndarray, shape (H, W)
        The laser's channel (minus the laser-off image's, if one was given), grey levels;
        a channel demosaiced from a Bayer mosaic is smoothed first.
    variance : ndarray, shape (H, W)
        Its noise variance per pixel, grey levels^2.
    raw : ndarray, shape (H, W)
        The laser's channel as read (the mirror's disc and its dark core are found on it).
    saturated : ndarray of bool, shape (H, W)
        Pixels at the sensor's top (in either image).
    blobs : ndarray of bool, shape (H, W)
        Saturated blobs (lamps, glints) grown by their halo; thin clipped stripes excluded.
    top : float or None
        Grey level at which the laser's channel of an integer image clips (a clipped
        stripe's centre is its plateau's middle; with a laser-off image, where ``raw``
        clips); None for a float image.
    flank : bool
        The signal is a laser-off difference (the peak's baseline slope from its flanks).
    """

    signal: np.ndarray
    variance: np.ndarray
    raw: np.ndarray
    saturated: np.ndarray
    blobs: np.ndarray
    top: float | None
    flank: bool


def laser_signal(image, *, background=None, channel=0):
    """The laser's signal, its noise variance and the saturated blobs of an image.

    Parameters
    ----------
    image : ndarray, shape (H, W) or (H, W, C)
        The image with the laser on (8 or 16 bit, or float).
    background : ndarray, shape (H, W) or (H, W, C), optional
        The same view with the laser off, subtracted (the noise of both exposures).
    channel : int, optional
        Colour channel of the laser in a colour image.

    Returns
    -------
    LaserSignal
    """
    sig, var, raw, sat = _signal(image, background, channel)
    # with a laser-off image only the saturated pixels stay (the rest of a lamp cancels)
    blobs = blob_mask(np.where(sat, np.inf, raw), top=np.inf,
                      margin=1 if background is not None else BLOB_MARGIN)
    return LaserSignal(sig, var, raw, sat, blobs, clip_level(image), background is not None)


def ring_azimuths(n):
    """The azimuths (rad, shape (n,)) of a ring's ``n`` profiles: the middle of each of n
    equal sectors from -pi (of each degree for n = 360)."""
    return np.linspace(-np.pi, np.pi, int(n), endpoint=False) + np.pi / int(n)


#: px of profile kept on either side of a ring's path when it is measured: the peak's
#: baseline (a running median over ``highpass_px``), the clutter term's samples (up to 16
#: px from the peak) and the search near the ring's curve all stay inside it
MEASURE_MARGIN = 32


def measure_ring(signal, center, radius, *, model=None, search_px=0, min_snr=3.0,
                 gate_px=1.0, along_sd=5.0, var_floor=2.5e-3, highpass_px=15,
                 offset_sd=OFFSET_SD):
    """The laser's points along a ring whose path is known, with their covariances and
    flags: the full extractor's measurement step (:func:`~bayescal.image.extract.
    extract_laser` locates the ring, then calls this with its path).

    Parameters
    ----------
    signal : LaserSignal
        From :func:`laser_signal`.
    center : array_like, shape (2,)
        Centre of the radial profiles, px.
    radius : array_like, shape (n,)
        The path: the radius (px) of the ring's peak at each of the ``n`` azimuths
        :func:`ring_azimuths` gives; rounded to the profiles' 1-px samples.
    model : ndarray, shape (n,), optional
        A smooth model of the ring's radius (px) for the gate against points far off it;
        by default a robust Fourier series through ``radius``.
    search_px : int, optional
        Look for each profile's highest sample within this many px of ``radius`` (0: take
        the path's samples as they are; a path predicted from another frame needs 2-3).
    min_snr, gate_px, along_sd, var_floor, highpass_px, offset_sd
        As in :func:`~bayescal.image.extract.extract_laser`.

    Returns
    -------
    LaserPixels
        One point per azimuth, flagged where the gates doubt it.
    """
    lp, gates = _measure(signal, center, radius, model=model, search_px=search_px,
                         highpass_px=highpass_px, min_snr=min_snr, gate_px=gate_px,
                         along_sd=along_sd, var_floor=var_floor)
    offset_sd = check_positive(offset_sd, "offset_sd", allow_zero=True)
    return replace(lp, offset_sd=offset_sd, flagged=lp.flagged | gates["astray"])


#: px within which a profile's peak is looked for about a ring's radius carried over from
#: other profiles (:func:`measure_settled`) or from the previous frame (the ring tracker's);
#: the path's own peak is its highest sample within 2 px of the located path
SEARCH_PX = 2


def measure_settled(signal, lp, *, center=None, n_azimuth=None, **kw):
    """``lp`` (a ring :func:`measure_ring` measured) measured again on the profiles
    :func:`~bayescal.image.ring.ring_rays` gives for its circle (of its unflagged points,
    :func:`~bayescal.image.ring.ring_circle`) when it was measured on others: each
    profile's peak looked for within :data:`SEARCH_PX` of the ring's radius there. Two
    measurements of one ring (the full extractor's, the ring tracker's) then read the same
    profiles. ``center``, ``n_azimuth`` (the user's) and ``kw`` as :func:`measure_ring`."""
    ok = ~lp.flagged & np.all(np.isfinite(lp.pixels), axis=1)
    if ok.sum() < 12:
        return lp
    c, n = ring_rays(*ring_circle(lp.pixels, ~ok), center=center, n_azimuth=n_azimuth)
    if n == len(lp) and np.array_equal(c, lp.center):
        return lp
    d = lp.pixels[ok] - c
    a = np.arctan2(d[:, 1], d[:, 0])
    order = np.argsort(a)
    radius = np.interp(ring_azimuths(n), a[order], np.hypot(*d.T)[order], period=2 * np.pi)
    return measure_ring(signal, c, radius, search_px=SEARCH_PX, **kw)


def _measure(signal, center, radius, *, model=None, search_px=0, highpass_px=15, **kw):
    """:func:`measure_ring` before the strict off-curve gate: the points and every gate's
    flags (a dict of (n,) bool; "astray" is left out of comparisons between rings)."""
    c = np.asarray(center, dtype=float)
    r = np.asarray(radius, dtype=float)
    if c.shape != (2,) or not np.all(np.isfinite(c)):
        raise InvalidValueError(f"center must be (u, v) px, finite, got {center!r}")
    if r.ndim != 1 or len(r) < 12 or not np.all(np.isfinite(r)) or np.any(r <= 0):
        raise InvalidValueError(f"radius must be positive and finite, one per azimuth (12 or "
                                f"more), got shape {r.shape}")
    r0 = R_MIN + max(0.0, np.floor(r.min() - MEASURE_MARGIN - R_MIN))
    radii = np.arange(r0, r.max() + MEASURE_MARGIN + 1.0)
    pol = PolarImage(signal.signal, c, ring_azimuths(len(r)), radii, highpass_px)
    k = np.clip(np.rint(r - r0).astype(int), 2, len(radii) - 3)
    if search_px:
        k = ridge_near(pol, k, int(search_px))
    if model is None:       # fitted to every n // 180-th profile: within 0.07 px of the fit
        # to all (real frames); the gate it serves allows 3 px
        sel = slice(None, None, max(1, len(k) // 180))
        fit = ring_model(pol.phi[sel], radii[k][sel], np.ones(len(k))[sel])[0]
        model = np.interp(pol.phi, pol.phi[sel], fit, period=2 * np.pi)
    return measure_polar(signal, pol, k, model, pol.sample_mask(signal.blobs), **kw)


def measure_polar(signal, pol, k, model, on_blob, **kw):
    """The points at samples ``k`` (n,) of profiles ``pol`` already taken (a ring
    candidate's), with the ring's ``model`` (n,) px and the blobs at the samples
    ``on_blob`` (n, K): :func:`_measure`'s points and flags, the same wherever the
    profiles reach :data:`MEASURE_MARGIN` px beyond the path on either side."""
    pol.model = np.asarray(model, dtype=float)
    # where the laser's channel clips, as read (on a laser-off difference too)
    clip = None if signal.top is None else \
        (pol.sample(signal.raw) if signal.flank else pol.values) >= signal.top - 0.5
    return _rescued(signal.signal, signal.variance, pol, k, on_blob, flank=signal.flank,
                    clip=clip, **kw)


def _rescued(sig, var_img, pol, k, on_blob, **kw):
    """:func:`_points`, then once more where points lay off the ring's robust curve, each
    such profile's peak looked for within 1 px of the curve (where a rail or a text bar
    crossing the stripe took the path, the laser's own peak is often still there), and
    where they stay off, a third time with a Gaussian through 3 samples instead of 5 (a
    ridge 2 px away pulls a 5-sample fit: the curve ran within 0.5 px of the truth at
    63-81 % of such points, which were 1-3 px off it, on renderer2's lamp rooms)."""
    kw["fits"] = {}                 # each pass refits only the profiles whose peak moved
    lp, gates, curve = _points(sig, var_img, pol, k, on_blob, **kw)
    off = gates["off curve"] | gates["astray"]
    if not off.any():
        return lp, gates
    near = ridge_near(pol, np.rint(np.nan_to_num(curve, nan=0.0) - pol.radii[0]).astype(int), 1)
    k = np.where(off, near, k)
    lp, gates, _ = _points(sig, var_img, pol, k, on_blob, curve=curve, **kw)
    still = off & (gates["off curve"] | gates["astray"])
    if still.any():
        lp, gates, _ = _points(sig, var_img, pol, k, on_blob, curve=curve, narrow=still, **kw)
    return lp, gates


def _points(sig, var_img, pol, k, on_blob, *, min_snr, gate_px, along_sd, var_floor,
            flank=False, curve=None, narrow=None, clip=None, fits=None):
    """Sub-pixel points on the path, their covariances and flags; ``flank``: the slope of
    the peak's baseline from its flanks (on a laser-off difference, whose background is
    flat) instead of the running median's (which follows the wall texture of one image)."""
    n = len(pol.phi)
    i = np.arange(n)
    r, var_r, height, snr, chi2, width = path_peaks(sig, var_img, pol, k, flank, narrow, clip,
                                                    fits)
    # misfit beyond noise (texture under the stripe, the stripe's shape) inflates every
    # variance: the median of chi2/2 with 2 degrees of freedom is ln 2 for a fit that
    # matches; fits through a clipped sample are left out of that median (on a bright
    # near ring with a laser-off image they misfit 20x more than the others, measured)
    good = np.isfinite(chi2)
    if clip is not None:
        free = ~clip[i[:, None], np.clip(k[:, None] + np.arange(-2, 3)[None], 0,
                                         clip.shape[1] - 1)].any(axis=1)
        good = good & free if np.any(good & free) else good
    scale = max(1.0, float(np.median(chi2[good])) / np.log(2.0)) if good.any() else 1.0
    var_r = np.maximum(scale, np.nan_to_num(chi2, nan=scale)) * var_r + var_floor
    win = max(5, n // 36) | 1
    r_s = median_filter(r, size=win, mode="wrap")
    var_r = var_r * scatter_factor(r - r_s, var_r, 3 * win)
    # profiles closer than 2 px share pixels: their errors correlate, so each counts for
    # less (the ring's information per px of its length stays that of 2-px spacing)
    var_r = var_r * np.maximum(1.0, 2.0 / np.maximum(r * 2 * np.pi / n, 1e-3))
    w_s = median_filter(width, size=win, mode="wrap")
    # the gates use the smaller of a point's sd and the typical sd of its neighbourhood: a
    # misfit that inflates a point's own variance must not also excuse it from being off
    # the ring (nor, 3 gate_px off it, a neighbourhood of such points)
    sd_loc = np.sqrt(np.minimum(var_r, median_filter(var_r, size=win, mode="wrap")))
    # no gate on a peak's brightness: the laser's light is the wall's reflectance times the
    # beam, 4x its neighbours' on a light patch of a wall patterned at the stripe's scale
    # (such a "glint" gate flagged 143 points of our 1280x1024 renders over strong texture,
    # seeds 0-11, 137 by it alone: 129 of those within 0.5 px of the truth, none beyond 1
    # px; on renderer2's lamp rooms, glints on the ring, and renderer3's it flagged none
    # alone); a glint beside the ring's line is off its curve
    gates = {"off ring": np.abs(r - r_s) > np.clip(4 * sd_loc, gate_px, 3 * gate_px),
             "off model": np.abs(r - pol.model) > np.maximum(3 * gate_px, 5 * sd_loc),
             "faint": snr < max(min_snr, DIM * _median(snr)), "no peak": ~np.isfinite(r),
             "misfit": chi2 > 30 * scale, "wide": width > 3 * w_s,
             "lamp": on_blob[i, k], "edge": ~pol.valid[i, k]}
    flagged = np.logical_or.reduce(list(gates.values()))
    # a run of points on another ridge (a rail, a text bar) for a few degrees moves the
    # running median with it: a wider, robust local quadratic of the ring does not follow it
    curve = ring_curve(pol.phi, r, ~flagged, half_deg=CURVE[0]) if curve is None else curve
    gates["off curve"] = np.abs(np.nan_to_num(r - curve)) > np.maximum(CURVE[1] * gate_px,
                                                                       CURVE[2] * sd_loc)
    gates["astray"] = _astray(r - curve, flagged, sd_loc, gate_px)
    flagged = flagged | gates["off curve"]
    clutter = _clutter(pol, k, var_img, width, height, fits)
    var_r = var_r + clutter
    var_r = var_r * _scatter_scale(r, var_r, ~flagged & np.isfinite(r), clutter, flank)
    pix = pol.center + r[:, None] * np.stack([np.cos(pol.phi), np.sin(pol.phi)], -1)
    cov = _covariances(pol.phi, r, r_s, np.minimum(np.nan_to_num(var_r, nan=VAR_MAX), VAR_MAX),
                       along_sd)
    lp = LaserPixels(pixels=pix, covariance=cov, snr=snr, flagged=flagged,
                     center=np.asarray(pol.center, dtype=float))
    return lp, gates, curve


def _clutter(pol, k, var_img, width, height, cache):
    """:func:`~bayescal.image.noise.clutter_variance` of each profile, taken from the last
    pass (``cache``, a dict) where its peak (``k``, ``width``, ``height``) is the same (each
    profile's term is its own: the same numbers)."""
    last = cache.get("clutter") if cache is not None else None
    if last is None:
        out = clutter_variance(pol, k, var_img, width, height)
    else:
        same = (k == last[0]) & _same(width, last[1]) & _same(height, last[2])
        out, j = last[3].copy(), np.nonzero(~same)[0]
        if len(j):
            sub = SimpleNamespace(high=pol.high[j], phi=pol.phi[j], radii=pol.radii,
                                  center=pol.center)
            out[j] = clutter_variance(sub, k[j], var_img, width[j], height[j])
    if cache is not None:
        cache["clutter"] = (k.copy(), width.copy(), height.copy(), out)
    return out


def _same(a, b):
    """Elementwise: equal, or both NaN."""
    return (a == b) | (np.isnan(a) & np.isnan(b))


#: without a laser-off image, over a textured wall, the ring's scatter about its neighbours
#: overstates its errors (the running median under the peak leaves errors that alternate in
#: sign a few profiles apart): on 36 renderer images (three renderers) it came to 1.00-1.67
#: x the variances where their z rms against the truth was 0.82-1.42 (applied whole, 1.00
#: -> 0.81 on one). Only its excess over SCATTER_EXCESS scales them there; real walls under
#: a laser's speckle (rings composited on the second real sensor's frame) gave 2.1-4.2 x,
#: with z rms 1.45-1.89 against the truth before, 1.24-1.50 after (docs/images.md)
SCATTER_EXCESS = 1.7


def _scatter_scale(r, var, ok, clutter, flank):
    """The factor on the variances from the ring's scatter about its neighbours
    (:func:`~bayescal.image.noise.ring_scatter_scale`): whole on a laser-off difference or
    where beside most of the stripe only noise is left (a dark frame, the laser the only
    light; the clutter term zero), its excess over :data:`SCATTER_EXCESS` elsewhere."""
    scale = ring_scatter_scale(r, var, ok)
    if flank or np.count_nonzero(clutter[ok] == 0) > 0.5 * np.count_nonzero(ok):
        return scale
    return max(1.0, scale / SCATTER_EXCESS)


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


#: the largest radial variance given, px^2 (sd 10 px: a point that unsure carries nothing;
#: unbounded, flagged rows carried 1e4-1e16 px^2 whose 2x2 covariances rounded to
#: indefinite)
VAR_MAX = 100.0


#: a point whose peak is below DIM x the ring's median SNR is "faint" too: where the laser
#: goes through a doorway or onto black, the path bridges the gap on noise (a third
#: renderer's doorways: SNR 3-6 against 60-160 on the ring; gross 1.2-2.8 % -> 0-1.8 %
#: in its 8-bit rooms, kept 0-0.6 % lower; on ours kept up to 0.9 % lower, renderer2's
#: unchanged)
DIM = 0.07


def _median(x):
    """Median of the finite values of ``x`` (0 if none)."""
    x = x[np.isfinite(x)]
    return float(np.median(x)) if len(x) else 0.0


#: the ring's robust curve (:func:`~bayescal.image.ring.ring_curve`): half-window (deg), and
#: its gate at max(CURVE[1] gate_px, CURVE[2] sd)
CURVE = (30.0, 1.0, 4.0)

#: the strict off-curve gate ("astray", see _astray): max(ASTRAY[0] gate_px, ASTRAY[1] x the
#: ring's robust scatter about its curve, min(CURVE[2] sd, gate_px))
ASTRAY = (0.8, 3.0)


def _astray(res, flagged, sd_loc, gate_px):
    """Points off the ring's robust curve by more than a point of the ring strays: farther
    than ``ASTRAY[0] gate_px`` and ``ASTRAY[1]`` robust sds of the kept points' residuals
    ``res`` (px), and farther than their own gate's ``CURVE[2]`` sds, capped at ``gate_px``.

    Without a laser-off image, texture under the stripe and a rail or a text bar beside it
    inflate a point's own sd where they also pull it off the ring: a gate in the point's
    own sds lets them through (1-3 px off the truth, 2-4 % of the points of renderer2's
    rooms, measured), a gate in the ring's scatter does not. Its flags do not count when
    candidate rings are compared: a laser ring near the camera strays from its curve more
    than a rail does."""
    res = np.nan_to_num(res, nan=np.inf)
    kept = ~flagged & np.isfinite(res)
    s_ring = 1.4826 * float(np.median(np.abs(res[kept]))) if kept.any() else 0.0
    gate = np.maximum(max(ASTRAY[0] * gate_px, ASTRAY[1] * s_ring),
                      np.minimum(CURVE[2] * sd_loc, gate_px))
    return np.isfinite(res) & (np.abs(res) > gate)


def _signal(image, background, channel):
    """The laser's signal (the image, or the image minus the laser-off image), its noise
    variance per pixel, the raw image and its saturation level."""
    img = as_gray(image, channel=channel, name="image")
    top = saturation_level(image, img)
    # a Bayer channel is smoothed (saturation is judged on the pixels as read)
    blur = demosaiced_blur(image, img)
    smooth = (lambda x: gaussian_filter(x, blur)) if blur else (lambda x: x)
    if background is None:
        s = smooth(img)
        return s, noise_model(s)(s), img, img >= top
    bg = background_gray(background, channel, img.shape)
    # var(on - off) = var(on) + var(off) = 2a + b (on + off): fitted on the difference, where
    # the texture cancels, against the mean level of the two exposures
    on, off = smooth(img), smooth(bg)
    mean = 0.5 * (on + off)
    var_img = noise_model(on - off, levels=mean)(mean)
    return on - off, var_img, img, (img >= top) | (bg >= saturation_level(background, bg))


def background_gray(background, channel, shape):
    """The laser-off image's grey channel (:func:`~bayescal.image.read.as_gray`), checked to
    have the image's ``shape``."""
    bg = as_gray(background, channel=channel, name="background")
    if bg.shape != tuple(shape):
        raise InvalidValueError(f"background must have the image's shape {tuple(shape)}, "
                                f"got {bg.shape}")
    return bg


def clip_level(image):
    """The grey level at which an integer image clips (a clipped stripe's centre is its
    plateau's middle); None for a float image (its maximum need not be a clip)."""
    integer = np.issubdtype(np.asarray(image).dtype, np.integer)
    return saturation_level(image, None) if integer else None


def saturation_level(image, gray):
    """The grey level at which the sensor saturates: the integer type's top, else the
    image's maximum."""
    dt = np.asarray(image).dtype
    return float(np.iinfo(dt).max) if np.issubdtype(dt, np.integer) else float(gray.max())
