"""Laser pixels from an image, with a covariance per point.

:func:`extract_laser` reads radial profiles from a centre inside the ring, finds
one sub-pixel peak per azimuth (a weighted Gaussian fit to five samples), rejects
distractors by ring consistency, and propagates the image noise through the fit
to each point's variance along the ring's normal. The method and its measured
accuracy are in ``docs/images.md``.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np
from scipy.ndimage import gaussian_filter, median_filter

from .._validation import check_positive
from ..errors import InvalidValueError
from .doubt import check_colour, check_ring, colour_heights, is_white
from .locate import ring_candidates
from .noise import clutter_variance, noise_model, ring_scatter_scale, scatter_factor
from .peak import fit_peaks, flank_baseline
from .read import as_gray, demosaiced_blur, read_image
from .ring import circle_fit, ridge_near, ring_curve

__all__ = ["LaserPixels", "extract_laser", "measure_ring", "laser_frame", "IMAGE_SUFFIXES",
           "OFFSET_SD"]

#: sd (px, per axis) of a displacement of the ring as a whole that the per-point covariances
#: leave out: wall texture under the stripe moves many neighbouring peaks the same way,
#: measured 0.01-0.04 px per image on two renderers (docs/images.md)
OFFSET_SD = 0.02

#: how much larger a fraction of its azimuths another candidate ring must keep to replace the
#: first (the circle most azimuths share). Measured without a laser-off image: renderer2's
#: tilted cone beside its rail (rng 6) has its laser ring 0.011 ahead of a ring that follows
#: the rail for half its turn; the closest wrong ring came 0.003 behind the laser's
CHOICE_MARGIN = 0.01


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


def _signal(image, background, channel):
    """The laser's signal (the image, or the image minus the laser-off image), its noise
    variance per pixel, the raw image and its saturation level."""
    img = as_gray(image, channel=channel, name="image")
    top = _saturation(image, img)
    # a Bayer channel is smoothed (saturation is judged on the pixels as read)
    blur = demosaiced_blur(image, img)
    smooth = (lambda x: gaussian_filter(x, blur)) if blur else (lambda x: x)
    if background is None:
        s = smooth(img)
        return s, noise_model(s)(s), img, img >= top
    bg = as_gray(background, channel=channel, name="background")
    if bg.shape != img.shape:
        raise InvalidValueError(
            f"background must have the image's shape {img.shape}, got {bg.shape}")
    # var(on - off) = var(on) + var(off) = 2a + b (on + off): fitted on the difference, where
    # the texture cancels, against the mean level of the two exposures
    on, off = smooth(img), smooth(bg)
    mean = 0.5 * (on + off)
    var_img = noise_model(on - off, levels=mean)(mean)
    return on - off, var_img, img, (img >= top) | (bg >= _saturation(background, bg))


def _clip_level(image, background):
    """The grey level at which an integer image without a laser-off image clips (a clipped
    stripe's centre is its plateau's middle); None otherwise (a float image's maximum need
    not be a clip, and a laser-off difference clips at no one level)."""
    integer = np.issubdtype(np.asarray(image).dtype, np.integer)
    return _saturation(image, None) if background is None and integer else None


def _saturation(image, gray):
    """The grey level at which the sensor saturates: the integer type's top, else the
    image's maximum."""
    dt = np.asarray(image).dtype
    return float(np.iinfo(dt).max) if np.issubdtype(dt, np.integer) else float(gray.max())


def extract_laser(image, *, background=None, center=None, channel=0, n_azimuth=None,
                  min_snr=3.0, gate_px=1.0, along_sd=5.0, var_floor=2.5e-3, radius=None,
                  highpass_px=15, check=True, offset_sd=OFFSET_SD):
    """Extract the laser centre line, one sub-pixel point per image azimuth.

    Radial profiles from a centre inside the ring are high-passed by subtracting their
    running median (``highpass_px`` long), which removes wall shading, texture steps and
    the mirror's edge; the ring is the closed ridge through the profiles found by dynamic
    programming over azimuth (the ring is continuous: one point per azimuth, small radial
    steps between neighbours), which wall texture, lamps and glints off the ring do not
    follow. A rail or a door frame can be such a ridge too: each circle the first pass
    suggests gets its own path, and the ring that keeps the most azimuths wins. Each point
    is then a Gaussian fit to five samples, its variance propagated from the image noise;
    points off a robust local curve of the ring are looked for again near it, then flagged
    (``docs/images.md``).

    Parameters
    ----------
    image : ndarray, shape (H, W) or (H, W, C)
        The image with the laser on (8 or 16 bit, or float).
    background : ndarray, shape (H, W) or (H, W, C), optional
        The same view with the laser off: the search runs on the difference, with the noise
        of both exposures.
    center : array_like, shape (2,), optional
        Centre of the radial profiles ``(u, v)`` px (e.g. ``(u0, v0)``); by default the
        centre of the mirror's image, then of a circle fitted to the ring found.
    channel : int, optional
        Colour channel of the laser in a colour image (0 red, 1 green, 2 blue). A channel
        demosaiced from a Bayer mosaic (every other pixel the mean of its neighbours) is
        smoothed first (:func:`~bayescal.image.read.demosaiced_blur`).
    n_azimuth : int, optional
        Number of profiles; default one per 2 px of the ring's circumference.
    min_snr : float, optional
        Points whose peak is below ``min_snr`` noise sds are flagged.
    gate_px : float, optional
        Points farther than ``gate_px`` (or 5 of their sds) from the smoothed ring are
        flagged.
    along_sd : float, optional
        Standard deviation given along the ring, px (a point may slide along it).
    var_floor : float, optional
        Variance added along the normal, px^2 (interpolation and model error).
    radius : tuple of float, optional
        ``(low, high)``: the ring's expected radius around the centre, px; the search
        stays inside it, and a ring found outside it is an error.
    highpass_px : int, optional
        Length of the running median subtracted from each profile, px (several times the
        stripe's width).
    check : bool, optional
        Raise :class:`~bayescal.errors.ExtractionError` when the ring found is implausible
        (False returns it, flagged as it is).
    offset_sd : float, optional
        Standard deviation (px, each axis) of a translation of the whole ring, reported as
        :attr:`LaserPixels.offset_sd` (default :data:`OFFSET_SD`, measured).

    Returns
    -------
    LaserPixels

    Raises
    ------
    ExtractionError
        No ring, most of it flagged (fewer than half of the azimuths kept), a path that
        does not close, a ring off the mirror's image or outside ``radius``, or in a colour
        image a ring as bright in another channel as in ``channel`` (no laser).

    Examples
    --------
    >>> import numpy as np
    >>> import bayescal as bc
    >>> img, truth = bc.render_image(bc.SensorParams.paper(), bc.room_walls(2500), rng=0)
    >>> lp = bc.extract_laser(img)
    >>> lp.pixels.shape[1], lp.covariance.shape[1:]
    (2, (2, 2))
    """
    offset_sd = check_positive(offset_sd, "offset_sd", allow_zero=True)
    sig, var_img, raw, sat = _signal(image, background, channel)
    if center is not None:
        c = np.asarray(center, dtype=float)
        if c.shape != (2,) or not np.all(np.isfinite(c)):
            raise InvalidValueError(f"center must be (u, v) px, finite, got {center!r}")
    if radius is not None:
        radius = tuple(float(x) for x in np.ravel(radius))
        if len(radius) != 2 or not 0 <= radius[0] < radius[1]:
            raise InvalidValueError(
                f"radius must be (low, high) px with 0 <= low < high, got {radius!r}")
    cands, gains, mirror = ring_candidates(sig, raw, sat, center, radius, n_azimuth=n_azimuth,
                                           highpass_px=highpass_px, runner_up=check)
    lp, cand, gates = _choose(cands, sig, var_img, min_snr=min_snr, gate_px=gate_px,
                              along_sd=along_sd, var_floor=var_floor,
                              flank=background is not None,
                              top=_clip_level(image, background),
                              colour=lambda px, c: colour_heights(image, background, channel,
                                                                  px, c, min_points=6))
    lp = replace(lp, offset_sd=offset_sd, flagged=lp.flagged | gates["astray"])
    if check:
        ok = ~lp.flagged
        cc, RR, _ = circle_fit(lp.pixels[ok]) if ok.sum() >= 3 else (lp.center, np.nan, None)
        check_ring(lp.flagged, cc, RR, mirror=mirror, expected=radius, closure=cand.closure,
                   gains=gains)
        check_colour(image, background, channel, lp.pixels[ok], lp.center)
    return lp


def _choose(cands, sig, var_img, *, colour=None, **kw):
    """The candidate ring whose points the extractor trusts most: the first (the circle most
    azimuths share), unless another ring that runs apart from it (1.5 px or more away over
    a tenth of its azimuths or more) keeps a larger fraction of its azimuths by more than
    :data:`CHOICE_MARGIN`. In a colour image (``colour(pixels, center)``: the points' colour
    heights, :func:`~bayescal.image.doubt.colour_heights`) where the two run apart, the one
    whose points there are the laser's colour wins over one whose points are white,
    whatever the fractions."""
    first = best = None
    for cand in cands:
        lp, gates = _rescued(sig, var_img, cand.pol, cand.k, cand.on_blob, **kw)
        if first is None:
            first = best = lp, cand, gates
            continue
        d = np.hypot(*(lp.pixels[:, None, :] - first[0].pixels[None]).T)
        apart, apart_f = np.min(d, axis=0) > 1.5, np.min(d, axis=1) > 1.5
        if np.mean(apart) < 0.1:
            continue
        lead = np.mean(~lp.flagged) > np.mean(~best[0].flagged) + CHOICE_MARGIN
        if colour is not None:
            w = is_white(colour(lp.pixels[apart & ~lp.flagged], lp.center))
            w_f = is_white(colour(first[0].pixels[apart_f & ~first[0].flagged], lp.center))
            lead = (lead and not (w and w_f is False)) or (w is False and w_f)
        if lead:
            best = lp, cand, gates
    return best


def measure_ring(sig, var_img, pol, k, on_blob, *, offset_sd=OFFSET_SD, **kw):
    """The ring's points given where it runs: the extractor's peak fits, gates and
    covariances (steps 7-10 of ``docs/images.md``) on the profiles ``pol`` at the peak
    samples ``k``, without the search that found them (the ring tracker's,
    :mod:`bayescal.image.track`, follows the ring from the last frame instead).

    ``sig``, ``var_img`` (H, W): the signal and its noise variance per pixel; ``pol``: the
    profiles (a :class:`~bayescal.image.ring.PolarImage`'s ``values``, ``base``, ``high``,
    ``valid``, ``radii``, ``phi``, ``sub``, ``center`` and ``model``, read within 28 samples
    of ``k``); ``k`` (n,): each profile's peak sample; ``on_blob`` (n, K): samples on a
    saturated blob; ``kw``: ``min_snr``, ``gate_px``, ``along_sd``, ``var_floor`` (as
    :func:`extract_laser`), ``flank`` (a laser-off difference), ``top`` (the clip level).
    Returns the :class:`LaserPixels` and the gates, ``{name: flags (n,)}``.
    """
    lp, gates = _rescued(sig, var_img, pol, k, on_blob, **kw)
    return replace(lp, offset_sd=offset_sd, flagged=lp.flagged | gates["astray"]), gates


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
            flank=False, curve=None, narrow=None, top=None, fits=None):
    """Sub-pixel points on the path, their covariances and flags; ``flank``: the slope of
    the peak's baseline from its flanks (on a laser-off difference, whose background is
    flat) instead of the running median's (which follows the wall texture of one image)."""
    n = len(pol.phi)
    i = np.arange(n)
    r, var_r, height, snr, chi2, width = _fit(sig, var_img, pol, k, flank, narrow, top, fits)
    # misfit beyond noise (saturation, texture under the stripe) inflates every variance:
    # the median of chi2/2 with 2 degrees of freedom is ln 2 for a fit that matches
    good = np.isfinite(chi2)
    scale = max(1.0, float(np.median(chi2[good])) / np.log(2.0)) if good.any() else 1.0
    var_r = np.maximum(scale, np.nan_to_num(chi2, nan=scale)) * var_r + var_floor
    win = max(5, n // 36) | 1
    r_s = median_filter(r, size=win, mode="wrap")
    var_r = var_r * scatter_factor(r - r_s, var_r, 3 * win)
    # profiles closer than 2 px share pixels: their errors correlate, so each counts for
    # less (the ring's information per px of its length stays that of 2-px spacing)
    var_r = var_r * np.maximum(1.0, 2.0 / np.maximum(r * 2 * np.pi / n, 1e-3))
    h_s = median_filter(np.maximum(height, 0), size=win, mode="wrap")
    w_s = median_filter(width, size=win, mode="wrap")
    # the gates use the smaller of a point's sd and the typical sd of its neighbourhood: a
    # misfit that inflates a point's own variance must not also excuse it from being off
    # the ring (nor, 3 gate_px off it, a neighbourhood of such points)
    sd_loc = np.sqrt(np.minimum(var_r, median_filter(var_r, size=win, mode="wrap")))
    gates = {"off ring": np.abs(r - r_s) > np.clip(4 * sd_loc, gate_px, 3 * gate_px),
             "off model": np.abs(r - pol.model) > np.maximum(3 * gate_px, 5 * sd_loc),
             "faint": snr < max(min_snr, DIM * _median(snr)), "no peak": ~np.isfinite(r),
             "misfit": chi2 > 30 * scale, "glint": height > 4 * h_s, "wide": width > 3 * w_s,
             "lamp": on_blob[i, k], "edge": ~pol.valid[i, k]}
    flagged = np.logical_or.reduce(list(gates.values()))
    # a run of points on another ridge (a rail, a text bar) for a few degrees moves the
    # running median with it: a wider, robust local quadratic of the ring does not follow it
    curve = ring_curve(pol.phi, r, ~flagged, half_deg=CURVE[0]) if curve is None else curve
    gates["off curve"] = np.abs(np.nan_to_num(r - curve)) > np.maximum(CURVE[1] * gate_px,
                                                                       CURVE[2] * sd_loc)
    gates["astray"] = _astray(r - curve, flagged, sd_loc, gate_px)
    flagged = flagged | gates["off curve"]
    var_r = var_r + clutter_variance(pol, k, var_img, width, height)
    if flank:       # on a laser-off difference: the ring's scatter, neighbours left out
        var_r = var_r * ring_scatter_scale(r, var_r, ~flagged & np.isfinite(r))
    pix = pol.center + r[:, None] * np.stack([np.cos(pol.phi), np.sin(pol.phi)], -1)
    cov = _covariances(pol.phi, r, r_s, np.minimum(np.nan_to_num(var_r, nan=VAR_MAX), VAR_MAX),
                       along_sd)
    lp = LaserPixels(pixels=pix, covariance=cov, snr=snr, flagged=flagged,
                     center=np.asarray(pol.center, dtype=float))
    return lp, gates, curve


def _fit(sig, var_img, pol, k, flank, narrow=None, top=None, fits=None):
    """The peaks at samples ``k``: a Gaussian through 5 samples, or through the 3 middle
    ones where ``narrow`` (n,) (a neighbouring ridge 2 px away shares a 5-sample window);
    where the peak is clipped at ``top`` (the sensor's saturation), the middle of the
    clipped run (:func:`_plateau`). ``fits`` (a dict) keeps the 5-sample fits for the next
    pass, which refits only the profiles whose peak sample moved (the same numbers)."""
    i = np.arange(len(pol.phi))
    base = flank_baseline(pol.values, k, pol.base[i, k]) if flank else \
        pol.base[i[:, None], k[:, None] + np.arange(-2, 3)[None]]
    redo = i if not fits else np.nonzero(k != fits["k"])[0]
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
    if top is not None:
        _plateau(pol, k, top, out)
    return out


def _plateau(pol, k, top, out):
    """Peaks clipped at the sensor's saturation ``top``: a Gaussian through a flat top is
    no estimate (1-1.5 px off on a third renderer's clipped stripes); the middle of the run
    of clipped samples is, to the quantisation of its two ends (variance 1/24 px^2). Updates
    ``out`` (r, var, height, snr, chi2, width) in place."""
    v = pol.values
    n, K = v.shape
    i = np.arange(n)
    clipped = v >= top - 0.5
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
    from ..errors import ExtractionError, UsageError

    try:
        lp = extract_laser(read_image(path, raw=True), center=center)
    except ExtractionError as exc:          # the reason only: the advice names Python's arguments
        raise UsageError(f"{path}: cannot extract laser pixels ({exc.reason})") from None
    except (OSError, ValueError) as exc:
        raise UsageError(f"{path}: cannot extract laser pixels ({exc})") from None
    keep = ~np.asarray(lp.flagged, bool)
    if not keep.any():
        raise UsageError(f"{path}: the extractor found no laser pixels it trusts")
    return path, lp.pixels[keep], lp.covariance[keep]
