"""Follow the laser ring from frame to frame: :func:`track_laser` and :class:`LaserTracker`.

Between two frames of a moving sensor the ring moves by a few pixels. The full extractor
(:func:`~bayescal.image.extract.extract_laser`) spends its time finding the ring; the
tracker takes the previous frame's ring as its prior: it looks for the ring within
:data:`BAND_PX` of it on :data:`COARSE_RAYS` rays, fits its motion, reads the profiles in a
band of :data:`REACH` px about the moved ring only and measures the points there with the
full extractor's own peak fits, gates and covariances
(:func:`~bayescal.image.extract.measure_ring`), the noise fitted on every
:data:`NOISE_PIXELS` px of evenly spaced rows. The first frame, and any frame where the
ring is lost, goes
through the full extractor; a frame it refuses comes back empty, with the error, and the
sequence goes on (``docs/images.md``).
"""

from __future__ import annotations

import numpy as np
from numpy.lib.stride_tricks import sliding_window_view
from scipy.ndimage import gaussian_filter, gaussian_filter1d, median_filter

from .._validation import check_positive
from ..errors import BayescalError, ExtractionError, InvalidValueError
from .doubt import blob_mask, check_colour, check_ring, mirror_disc
from .extract import OFFSET_SD, extract_laser, measure_ring
from .frames import TrackedPixels, as_frame, iter_frames, per_frame
from .locate import BLOB_MARGIN
from .noise import noise_model
from .read import as_gray, demosaiced_blur
from .ring import R_MIN, circle_fit, ridge_near, ring_model

__all__ = ["LaserTracker", "track_laser", "BAND_PX", "COARSE_RAYS", "REACH",
           "NOISE_PIXELS", "KEEP_MIN", "FOUND_MIN", "SNR_DROP"]

#: how far (px) the ring is looked for about the previous frame's, along the rays
BAND_PX = 8
#: rays of the first look for the moved ring (one per 2 degrees)
COARSE_RAYS = 180
#: samples read either side of the moved ring on each final profile: the search for the
#: peak (3 + 2), the clutter term's reach past it (16) and the running median's half (7)
REACH = 28
#: the noise model is fitted on evenly spaced rows (each with its two neighbours) of about
#: NOISE_PIXELS px in all (every 16th row of 960x720): its sd within 0.97-1.13 of the whole
#: image's at the ring's grey levels, 0.76-1.0 at black, over 12 images of three renderers
NOISE_PIXELS = 43000
#: the fraction of azimuths a followed ring must keep; below it the full extractor runs,
#: whose "no ring stands out" test (more than 20 % flagged) needs the runner-up path
KEEP_MIN = 0.8
#: the fraction of the coarse rays that must find the ring near its fitted motion: with the
#: ring in the band 0.71-0.98 (ours, ours with lamps, renderer2 at 2500 and 4000 mm, seeds
#: 0-2, 800x600, no laser-off image), with the band 14 px off it 0.04-0.55 (0.55: renderer2's
#: rail, which the later checks may still refuse); a ring missed costs a full extraction
FOUND_MIN = 0.6
#: a coarse ray finds the ring where its ridge scores Z_MIN noise sds or more
Z_MIN = 3.0
#: a followed ring whose median SNR falls below SNR_DROP of the last frame's is lost (the
#: band may have caught another ridge as the ring jumped away)
SNR_DROP = 0.5


class _Lost(BayescalError):
    """The ring could not be followed into this frame (the message says why)."""


class _Band:
    """Profiles about ``center`` read only near the ring: the attributes of a
    :class:`~bayescal.image.ring.PolarImage` that :func:`measure_ring` reads, NaN (values,
    base), 0 (high) or False (valid) off the band."""

    def __init__(self, center, phi, radii, sub):
        self.center, self.phi, self.radii, self.sub, self.model = center, phi, radii, sub, None
        shape = (len(phi), len(radii))
        self.values, self.base = np.full(shape, np.nan), np.full(shape, np.nan)
        self.high, self.valid = np.zeros(shape), np.zeros(shape, bool)


class LaserTracker:
    """Follows the laser ring through a sequence of frames, one call per frame.

    Parameters
    ----------
    background : ndarray, optional
        A laser-off image for every frame (a still scene); per-frame ones are passed to
        the call.
    center, channel, n_azimuth, min_snr, gate_px, along_sd, var_floor, radius, \
highpass_px, check, offset_sd
        As :func:`~bayescal.image.extract.extract_laser`, for every frame.
    band_px : float, optional
        How far (px) the ring is looked for about the previous frame's
        (:data:`BAND_PX`); a ring that moved farther is found by the full extractor.
    """

    def __init__(self, *, background=None, center=None, channel=0, n_azimuth=None,
                 min_snr=3.0, gate_px=1.0, along_sd=5.0, var_floor=2.5e-3, radius=None,
                 highpass_px=15, check=True, offset_sd=OFFSET_SD, band_px=BAND_PX):
        self.band_px = int(np.ceil(check_positive(band_px, "band_px")))
        self.background = background
        self.options = dict(center=center, channel=channel, n_azimuth=n_azimuth,
                            min_snr=min_snr, gate_px=gate_px, along_sd=along_sd,
                            var_floor=var_floor, highpass_px=highpass_px,
                            radius=None if radius is None else tuple(map(float, np.ravel(radius))),
                            check=check, offset_sd=offset_sd)
        if center is not None:
            c = np.asarray(center, dtype=float)
            if c.shape != (2,) or not np.all(np.isfinite(c)):
                raise InvalidValueError(f"center must be (u, v) px, finite, got {center!r}")
        self._state = self._shape = self._mirror = self._blur = None
        self._frames = 0

    def reset(self):
        """Forget the previous ring: the next frame goes through the full extractor."""
        self._state, self._frames = None, 0

    def __call__(self, image, *, background=None, name=""):
        """The laser pixels of the next frame.

        Parameters
        ----------
        image : ndarray, shape (H, W) or (H, W, C)
            The frame, as :func:`~bayescal.image.extract.extract_laser` takes it; every
            frame has the first one's size.
        background : ndarray, optional
            This frame's laser-off image (default: the tracker's ``background``).
        name : str, optional

        Returns
        -------
        TrackedPixels
            Empty, with :attr:`~TrackedPixels.error`, when the full extractor refuses the
            frame.
        """
        bg = self.background if background is None else background
        gray = as_gray(image, channel=self.options["channel"], name=f"frame {name!r}")
        if self._shape is None:
            self._shape = gray.shape
            self._blur = demosaiced_blur(image, gray)
            self._mirror = mirror_disc(gray)
        elif gray.shape != self._shape:
            raise InvalidValueError(f"frame {name!r} has shape {gray.shape}, the first frame "
                                    f"{self._shape}: every frame of a sequence must have one size")
        note = ("first frame" if not self._frames else
                "no ring to follow (the last frame was refused)")
        self._frames += 1
        if self._state is not None:
            try:
                return TrackedPixels.of(self._follow(image, gray, bg), tracked=True, name=name)
            except _Lost as lost:
                note = f"lost: {lost}"
        try:
            lp = extract_laser(image, background=bg, **self.options)
        except ExtractionError as exc:
            self._state = None
            return TrackedPixels.refusal(exc, name=name, note=note)
        self._remember(lp)
        return TrackedPixels.of(lp, tracked=False, name=name, note=note)

    def _remember(self, lp):
        """Keep the ring of ``lp`` (its unflagged points about its centre) for the next
        frame."""
        ok = ~lp.flagged & np.all(np.isfinite(lp.pixels), axis=1)
        if ok.sum() < 12:
            self._state = None
            return
        d = lp.pixels[ok] - lp.center
        phi = np.arctan2(d[:, 1], d[:, 0])
        order = np.argsort(phi)
        self._state = (np.asarray(lp.center, float), phi[order], np.hypot(*d.T)[order],
                       float(np.median(lp.snr[ok])))

    def _follow(self, image, gray, bg):
        """The ring followed from the last frame's, measured; raises :class:`_Lost`."""
        o = self.options
        c0, phi0, r0, snr0 = self._state
        sig, var_img, sat, raw = self._signal(image, gray, bg, c0, r0.max())
        pts = _coarse(sig, c0, phi0, r0, self.band_px, o["highpass_px"])
        if o["center"] is not None:
            c = np.asarray(o["center"], float)
            cf, Rf, _ = circle_fit(pts)
            R = float(np.hypot(*(cf - c)) + Rf)
        else:
            c, R, _ = circle_fit(pts)
        if not np.isfinite(R):
            raise _Lost("no circle through the moved ring")
        n = int(o["n_azimuth"]) if o["n_azimuth"] else int(np.clip(np.pi * R, 360, 3600))
        pol, k, on_blob = _band(sig, c, n, pts, o["highpass_px"], sat, raw,
                                margin=1 if sig is not raw else BLOB_MARGIN)
        integer = np.issubdtype(np.asarray(image).dtype, np.integer)
        top = float(np.iinfo(np.asarray(image).dtype).max) if integer and bg is None else None
        lp, _ = measure_ring(sig, var_img, pol, k, on_blob, min_snr=o["min_snr"],
                             gate_px=o["gate_px"], along_sd=o["along_sd"],
                             var_floor=o["var_floor"], flank=bg is not None, top=top,
                             offset_sd=o["offset_sd"])
        self._judge(lp, image, bg, snr0)
        self._remember(lp)
        return lp

    def _judge(self, lp, image, bg, snr0):
        """Raise :class:`_Lost` unless ``lp`` is the ring: enough of it kept, as bright as
        the last frame's, and (``check``) the full extractor's plausibility checks."""
        ok = ~lp.flagged
        if ok.mean() < KEEP_MIN:
            raise _Lost(f"{ok.mean():.0%} of the azimuths kept (at least {KEEP_MIN:.0%})")
        snr = float(np.median(lp.snr[ok]))
        if snr < SNR_DROP * snr0:
            raise _Lost(f"the ring's median SNR fell from {snr0:.1f} to {snr:.1f}")
        if not self.options["check"]:
            return
        cc, RR, _ = circle_fit(lp.pixels[ok])
        try:
            check_ring(lp.flagged, cc, RR, mirror=self._mirror, expected=self.options["radius"],
                       closure=0, gains=(np.nan, np.nan))
            check_colour(image, as_frame(bg), self.options["channel"], lp.pixels[ok], lp.center)
        except ExtractionError as exc:
            raise _Lost(exc.reason) from None

    def _signal(self, image, gray, bg, c0, r_max):
        """The signal (smoothed like the full extractor's where it is read), its noise
        variance (zero far from the ring), the saturated pixels and the raw channel."""
        H, W = gray.shape
        reach = r_max + self.band_px + REACH + 8
        box = (slice(max(0, int(c0[1] - reach)), min(H, int(c0[1] + reach) + 1)),
               slice(max(0, int(c0[0] - reach)), min(W, int(c0[0] + reach) + 1)))
        top = _top(image, gray)
        sat = _Saturated([(gray, top)])
        on = _smoothed(gray, self._blur, box)
        step = max(2, int(round(H * W / NOISE_PIXELS)))
        rows = np.arange(step // 2 + 4, H - 4, step)
        if bg is None:
            model = noise_model(_strips(gray, rows, self._blur), rows=_mid(rows))
            return on, _Variance(model, on), sat, gray
        bg = as_frame(bg)
        bgg = as_gray(bg, channel=self.options["channel"], name="background")
        if bgg.shape != gray.shape:
            raise InvalidValueError(f"background must have the image's shape {gray.shape}, "
                                    f"got {bgg.shape}")
        off = _smoothed(bgg, self._blur, box)
        s_on, s_off = _strips(gray, rows, self._blur), _strips(bgg, rows, self._blur)
        model = noise_model(s_on - s_off, levels=0.5 * (s_on + s_off), rows=_mid(rows))
        sat.images.append((bgg, _top(bg, bgg)))
        return on - off, _Variance(model, 0.5 * (on + off)), sat, gray


class _Variance:
    """The noise variance of each pixel, ``model(level)``, computed where it is read: an
    array's indexing and shape (the peak fits read a few pixels about the ring); as an
    array, all of it."""

    def __init__(self, model, level):
        self.model, self.level, self.shape = model, level, level.shape

    def __getitem__(self, key):
        return self.model(self.level[key])

    def __array__(self, dtype=None, copy=None):
        return np.asarray(self.model(self.level), dtype=dtype)


class _Saturated:
    """Whether each pixel is saturated in one of ``images`` (pairs of a grey image and its
    saturation level), computed where it is read."""

    def __init__(self, images):
        self.images, self.shape = images, images[0][0].shape

    def __getitem__(self, key):
        return np.logical_or.reduce([img[key] >= top for img, top in self.images])


def _top(image, gray):
    """The grey level at which the sensor saturates (the full extractor's rule)."""
    dt = np.asarray(image).dtype
    return float(np.iinfo(dt).max) if np.issubdtype(dt, np.integer) else float(gray.max())


def _smoothed(gray, blur, box):
    """``gray``, smoothed as the full extractor smooths a demosaiced channel inside
    ``box`` (computed there only, with a margin past the Gaussian's reach)."""
    if not blur:
        return gray
    m = int(4.0 * blur + 0.5) + 1
    H, W = gray.shape
    r0, r1 = max(0, box[0].start - m), min(H, box[0].stop + m)
    c0, c1 = max(0, box[1].start - m), min(W, box[1].stop + m)
    out = gray.copy()
    sm = gaussian_filter(gray[r0:r1, c0:c1], blur)
    out[box] = sm[box[0].start - r0:box[0].stop - r0, box[1].start - c0:box[1].stop - c0]
    return out


def _strips(gray, rows, blur):
    """The rows ``rows - 1, rows, rows + 1`` of ``gray`` (smoothed by ``blur``, each strip
    with 3 more rows either side for the Gaussian's reach), stacked: shape (3 m, W)."""
    if not blur:
        return gray[(rows[:, None] + np.arange(-1, 2)[None]).ravel()]
    idx = rows[:, None] + np.arange(-4, 5)[None]
    return gaussian_filter(gray[idx], (0, blur, blur))[:, 3:6].reshape(-1, gray.shape[1])


def _mid(rows):
    """The middle row of each stacked triple of :func:`_strips`."""
    return np.arange(1, 3 * len(rows), 3)


def _bilinear(img, u, v):
    """Bilinear samples of ``img`` at ``(u, v)``, the image's edge repeated beyond it (as
    ``map_coordinates(order=1, mode="nearest")``)."""
    H, W = img.shape
    u = np.clip(u, 0, W - 1)
    v = np.clip(v, 0, H - 1)
    u0 = np.minimum(u.astype(int), W - 2)
    v0 = np.minimum(v.astype(int), H - 2)
    fu, fv = u - u0, v - v0
    flat = img.ravel()
    i = v0 * W + u0
    top = flat[i] * (1 - fu) + flat[i + 1] * fu
    bot = flat[i + W] * (1 - fu) + flat[i + W + 1] * fu
    return top * (1 - fv) + bot * fv


def _running_median(values, half):
    """The running median of ``2 half + 1`` samples along each row, where the window fits:
    shape (n, L - 2 half)."""
    win = sliding_window_view(values, 2 * half + 1, axis=1)
    return np.partition(win, half, axis=-1)[..., half]


def _coarse(sig, c0, phi0, r0, band, highpass_px):
    """The ring moved from the last frame's (``r0`` at ``phi0`` about ``c0``): points
    (COARSE_RAYS, 2) px where each ray finds it, or its fitted motion where a ray does not;
    raises :class:`_Lost` when too few rays find it near that motion, or it moved out of
    the band."""
    m = COARSE_RAYS
    phi = np.linspace(-np.pi, np.pi, m, endpoint=False) + np.pi / m
    rp = np.interp(phi, phi0, r0, period=2 * np.pi)
    h = max(5, int(highpass_px) | 1) // 2
    lo = np.rint(rp).astype(int) - band - h
    rad = lo[:, None] + np.arange(2 * (band + h) + 1)[None]
    e = np.stack([np.cos(phi), np.sin(phi)], -1)
    vals = _bilinear(sig, c0[0] + e[:, :1] * rad, c0[1] + e[:, 1:] * rad)
    high = vals[:, h:-h] - _running_median(vals, h)
    sm = gaussian_filter1d(high, 1.0, axis=1, mode="nearest")
    j = np.clip(np.argmax(sm, axis=1), 1, sm.shape[1] - 2)
    # the noise of the high-pass, robustly over blocks of 6 rays, the ridge (the samples
    # within 3 of each ray's highest) left out: in a band of 17 samples it is a third of them
    quiet = np.abs(np.arange(sm.shape[1])[None] - j[:, None]) > 3
    scale = 1.4826 * np.nanmedian(np.where(quiet, np.abs(sm), np.nan).reshape(m // 6, -1),
                                  axis=1).repeat(6)
    i = np.arange(m)
    z = sm[i, j] / np.maximum(scale, 1e-9)
    a, b, c = sm[i, j - 1], sm[i, j], sm[i, j + 1]
    den = a - 2 * b + c
    frac = np.where(den < 0, 0.5 * (a - c) / np.where(den < 0, den, -1.0), 0.0)
    d = lo + h + j + np.clip(frac, -0.5, 0.5) - rp
    strong = z > Z_MIN
    if strong.sum() < 12:
        raise _Lost(f"the ring was not found within {band} px of the last one")
    motion, _ = ring_model(phi, d, strong.astype(float), order=3)
    found = strong & (np.abs(d - motion) <= 1.5)
    if found.mean() < FOUND_MIN:
        raise _Lost(f"the ring was found within {band} px of the last one on "
                    f"{found.mean():.0%} of the rays (at least {FOUND_MIN:.0%})")
    if np.max(np.abs(motion)) > band - 2:
        raise _Lost(f"the ring moved by up to {np.max(np.abs(motion)):.1f} px (the band "
                    f"follows {band - 2} px)")
    rr = rp + np.where(found, d, motion)
    return c0 + rr[:, None] * e


def _band(sig, c, n, pts, highpass_px, sat, raw, *, margin):
    """The profiles about ``c`` (n azimuths, the full extractor's grid) in a band of
    :data:`REACH` samples about the ring through ``pts``; the peak sample per profile (the
    highest high-passed sample within 2 of the ridge nearest the ring, or of the ring's
    robust model where the two part by 2 px, as the full extractor's path); the blob mask."""
    phi = np.linspace(-np.pi, np.pi, n, endpoint=False) + np.pi / n
    d = pts - c
    a = np.arctan2(d[:, 1], d[:, 0])
    order = np.argsort(a)
    rp = np.interp(phi, a[order], np.hypot(*d.T)[order], period=2 * np.pi)
    h = max(5, int(highpass_px) | 1) // 2
    lo = np.maximum(np.rint(rp).astype(int) - REACH, int(R_MIN))
    L = 2 * REACH + 1
    rad = lo[:, None] + np.arange(L)[None]
    sub = (np.arange(2) - 0.5) * (2 * np.pi / n) / 2
    vals = 0.0
    H, W = sig.shape
    for s in sub:
        u = c[0] + np.cos(phi + s)[:, None] * rad
        v = c[1] + np.sin(phi + s)[:, None] * rad
        vals = vals + _bilinear(sig, u, v) / len(sub)
    valid = (u >= 0) & (u <= W - 1) & (v >= 0) & (v <= H - 1)
    base = _running_median(vals, h)
    high = np.where(valid[:, h:-h], vals[:, h:-h] - base, 0.0)
    # the ring's path: the ridge within 3 of the prediction, blobs not counted
    uc = c[0] + np.cos(phi)[:, None] * rad
    vc = c[1] + np.sin(phi)[:, None] * rad
    blobs = _blobs(sat, raw, uc, vc, margin)
    sm = np.where(blobs[:, h:-h], 0.0, gaussian_filter1d(high, 1.0, axis=1))
    mid = REACH - h
    path = mid - 3 + np.argmax(sm[:, mid - 3:mid + 4], axis=1)
    i = np.arange(n)
    scale = median_filter(1.4826 * np.median(np.abs(sm), axis=1), size=9, mode="wrap")
    z = sm[i, path] / np.maximum(scale, 1e-9)
    k0 = int(lo.min())
    pol = _Band(np.asarray(c, float), phi, np.arange(k0, lo.max() + L, dtype=float), sub)
    cols = lo[:, None] - k0 + np.arange(L)[None]
    rows = i[:, None]
    flat = (rows * len(pol.radii) + cols).ravel()
    core = (rows * len(pol.radii) + cols[:, h:-h]).ravel()
    pol.values.ravel()[flat] = vals.ravel()
    pol.valid.ravel()[flat] = valid.ravel()
    pol.base.ravel()[core] = base.ravel()
    pol.high.ravel()[core] = high.ravel()
    on_blob = np.zeros(pol.values.shape, bool)
    on_blob.ravel()[flat] = blobs.ravel()
    path = lo - k0 + h + path
    k = ridge_near(pol, path, 2)
    model = _model(phi, pol.radii[path], z > 3)
    stray = np.abs(pol.radii[k] - model) > 2.0
    if np.any(stray):
        near = ridge_near(pol, np.rint(model - pol.radii[0]).astype(int), 1)
        k = np.where(stray, near, k)
    pol.model = model
    return pol, k, on_blob


def _model(phi, r, strong, *, points=120):
    """The full extractor's robust Fourier model of the ring's path
    (:func:`~bayescal.image.ring.ring_model`, order 6), fitted to about ``points`` evenly
    spaced profiles and interpolated between them (it is smooth over 3 degrees; the gates
    that read it allow 2-3 px)."""
    sel = slice(None, None, max(1, len(phi) // points))
    model, _ = ring_model(phi[sel], r[sel], strong[sel].astype(float))
    return np.interp(phi, phi[sel], model, period=2 * np.pi)


def _blobs(sat, raw, u, v, margin):
    """Whether each sample ``(u, v)`` lies on a saturated blob (a lamp), as the full
    extractor's mask (:func:`~bayescal.image.doubt.blob_mask`) computed about the band."""
    H, W = raw.shape
    ui = np.clip(np.rint(u).astype(int), 0, W - 1)
    vi = np.clip(np.rint(v).astype(int), 0, H - 1)
    if not _has_core(sat, vi[sat[vi, ui]], ui[sat[vi, ui]]):
        return np.zeros(u.shape, bool)
    pad = 40
    box = (slice(max(0, vi.min() - pad), min(H, vi.max() + pad + 1)),
           slice(max(0, ui.min() - pad), min(W, ui.max() + pad + 1)))
    mask = blob_mask(np.where(sat[box], np.inf, raw[box]), top=np.inf, margin=margin)
    return mask[vi - box[0].start, ui - box[1].start]


def _has_core(sat, vv, uu, radius=2):
    """Whether one of the saturated pixels ``(vv, uu)`` has its whole disc of ``radius`` px
    saturated (a blob's core, which :func:`~bayescal.image.doubt.blob_mask` erodes to find;
    a thin clipped stripe has none). A core farther from the band than the mask grows it
    cannot reach a peak sample, which lies 23 samples or more inside the band."""
    if len(vv) == 0:
        return False
    H, W = sat.shape
    dv, du = np.nonzero(np.hypot(*np.mgrid[-radius:radius + 1, -radius:radius + 1]) <= radius)
    rr = np.clip(vv[:, None] + dv[None] - radius, 0, H - 1)
    cc = np.clip(uu[:, None] + du[None] - radius, 0, W - 1)
    return bool(np.any(np.all(sat[rr, cc], axis=1)))


def track_laser(frames, *, background=None, **options):
    """The laser pixels of every frame of a sequence, each frame's search seeded by the
    previous frame's ring.

    Parameters
    ----------
    frames : str, os.PathLike or iterable
        A folder of images (in the order of their names), a video file (needs PyAV:
        ``pip install bayescal[video]``), or an iterable of images (arrays or paths);
        see :func:`~bayescal.image.frames.iter_frames`.
    background : ndarray, path or sequence of them, optional
        The laser-off image of every frame, or one per frame.
    **options
        Options of :func:`~bayescal.image.extract.extract_laser` (``center``, ``channel``,
        ``radius``, ``along_sd``, ...), and ``band_px`` (:class:`LaserTracker`).

    Returns
    -------
    list of TrackedPixels
        One per frame, like :func:`~bayescal.image.extract.extract_laser`'s result, with
        ``tracked`` (followed from the previous frame) and ``note`` (why the full extractor
        ran); a frame the full extractor refuses is empty (``len == 0``), with its
        ``error``, and the frames after it are extracted anew.

    Examples
    --------
    >>> import bayescal as bc
    >>> img, _ = bc.render_image(bc.SensorParams.paper(), bc.room_walls(2500), rng=0)
    >>> [f.tracked for f in bc.track_laser([img, img, img])]
    [False, True, True]
    """
    tracker = LaserTracker(**options)
    bgs = per_frame(background)
    return [tracker(img, background=as_frame(next(bgs)), name=name)
            for name, img in iter_frames(frames, channel=tracker.options["channel"])]
