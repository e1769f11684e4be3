"""Follow the laser ring from frame to frame: :func:`track_laser`, :class:`LaserTracker`.

Between two frames of a moving sensor the ring moves by a few pixels. The full extractor
(:func:`~bayescal.image.extract.extract_laser`) spends its time finding the ring; the
tracker takes the previous frame's ring as its prior: it looks for the ring within
:data:`BAND_PX` of it on :data:`COARSE_RAYS` rays (then, if it is not there, within
:data:`WIDE` times as far), fits its motion, and measures the moved ring with the full
extractor's own measurement (:func:`~bayescal.image.measure.measure_ring`, each profile's
peak looked for within :data:`SEARCH_PX` of the prediction) on the profiles the full
extractor reads for that ring (:func:`~bayescal.image.measure.ring_rays`). The noise is
fitted on every :data:`NOISE_PIXELS` px of evenly spaced rows, and read where the peaks
are. The first frame, and any frame where the ring is lost, goes through the full
extractor; a frame it refuses comes back empty, with the error, and the sequence goes on
(``docs/images.md``).
"""

from __future__ import annotations

from dataclasses import dataclass, fields

import numpy as np
from numpy.lib.stride_tricks import sliding_window_view
from scipy.ndimage import gaussian_filter, gaussian_filter1d

from .._validation import check_positive
from ..errors import BayescalError, ExtractionError, InvalidValueError
from .doubt import blob_mask, check_colour, check_ring, mirror_disc
from .extract import extract_laser
from .measure import (
    BLOB_MARGIN,
    MEASURE_MARGIN,
    OFFSET_SD,
    SEARCH_PX,
    LaserPixels,
    LaserSignal,
    background_gray,
    clip_level,
    measure_ring,
    measure_settled,
    ring_azimuths,
    saturation_level,
)
from .noise import noise_model
from .peak import bilinear
from .read import as_frame, as_gray, demosaiced_blur, iter_frames, per_frame
from .ring import circle_fit, ring_circle, ring_model, ring_rays

__all__ = ["LaserTracker", "TrackedPixels", "track_laser", "BAND_PX", "WIDE",
           "COARSE_RAYS", "SEARCH_PX", "NOISE_PIXELS", "KEEP_MIN", "FOUND_MIN", "SNR_DROP"]

#: how far (px) the ring is looked for about the previous frame's, along the rays
BAND_PX = 8
#: where the ring is not within BAND_PX, it is looked for again WIDE times as far (the real
#: pipe frames' ring moved 16 px between two of them)
WIDE = 4
#: rays of the first look for the moved ring (one per 2 degrees)
COARSE_RAYS = 180
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


@dataclass(frozen=True)
class TrackedPixels(LaserPixels):
    """One frame's laser pixels (as :class:`~bayescal.image.measure.LaserPixels`) and how
    they were found.

    Attributes
    ----------
    tracked : bool
        True: followed from the previous frame's ring; False: the full extractor ran (the
        first frame, a frame after a refused one, or one where the tracker lost the ring).
    name : str
        The frame's name (a file's stem, ``frame 3``).
    note : str
        Why the full extractor ran (``first frame``, ``lost: ...``); empty when tracked.
    error : ExtractionError or None
        The full extractor's refusal: the frame has no points then (``len == 0``).
    """

    tracked: bool = False
    name: str = ""
    note: str = ""
    error: ExtractionError | None = None

    @property
    def refused(self):
        """bool: the extractor refused the frame (no points; see :attr:`error`)."""
        return self.error is not None

    @classmethod
    def of(cls, lp, **kw):
        """A :class:`LaserPixels` with the tracker's attributes ``kw``."""
        return cls(**{f.name: getattr(lp, f.name) for f in fields(LaserPixels)}, **kw)

    @classmethod
    def refusal(cls, error, **kw):
        """An empty frame that carries the extractor's ``error``."""
        return cls(pixels=np.zeros((0, 2)), covariance=np.zeros((0, 2, 2)), snr=np.zeros(0),
                   flagged=np.zeros(0, bool), center=np.full(2, np.nan), error=error, **kw)


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
        How far (px) the ring is looked for about the previous frame's (:data:`BAND_PX`;
        then :data:`WIDE` times as far); a ring that moved farther is found by the full
        extractor.
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
                       float(np.median(lp.snr[ok])), ring_circle(lp.pixels, ~ok))

    def _follow(self, image, gray, bg):
        """The ring followed from the last frame's, measured; raises :class:`_Lost`."""
        o = self.options
        c0, phi0, r0, snr0, circle = self._state
        signal = self._signal(image, gray, bg, c0, r0.max() + WIDE * self.band_px)
        try:
            pts, motion = _coarse(signal.signal, c0, phi0, r0, self.band_px, o["highpass_px"])
        except _Lost:                   # farther than the band: look again, wider
            pts, motion = _coarse(signal.signal, c0, phi0, r0, WIDE * self.band_px,
                                  o["highpass_px"])
        # the last ring's circle moved as the ring did: the motion's mean is its radius's
        # change, its first harmonic its centre's shift (the moved ring's own circle would
        # differ from the one its measured points give by the rays' noise, and read other
        # profiles 4 times as often: 5 of 72 real-like frames measured twice)
        phi = ring_azimuths(len(motion))
        shift = 2 * np.mean(motion[:, None] * np.stack([np.cos(phi), np.sin(phi)], -1), 0)
        if not np.all(np.isfinite(circle[0])) or not np.isfinite(circle[1]):
            raise _Lost("no circle through the last ring")
        c, n = ring_rays(circle[0] + shift, circle[1] + np.mean(motion), center=o["center"],
                         n_azimuth=o["n_azimuth"])
        phi = ring_azimuths(n)
        d = pts - c
        a = np.arctan2(d[:, 1], d[:, 0])
        order = np.argsort(a)
        radii = np.interp(phi, a[order], np.hypot(*d.T)[order], period=2 * np.pi)
        kw = {k: o[k] for k in ("min_snr", "gate_px", "along_sd", "var_floor", "highpass_px",
                                "offset_sd")}
        lp = measure_ring(signal, c, radii, search_px=SEARCH_PX, **kw)
        # its own circle's profiles (those the full extractor reads), if they are others
        lp = measure_settled(signal, lp, center=o["center"], n_azimuth=o["n_azimuth"], **kw)
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
        hinted = self.options["center"] is not None or self.options["radius"] is not None
        try:
            check_ring(lp.flagged, cc, RR, mirror=None if hinted else self._mirror,
                       expected=self.options["radius"], closure=0, hinted=hinted)
            check_colour(image, as_frame(bg), self.options["channel"], lp.pixels[ok], lp.center)
        except ExtractionError as exc:
            raise _Lost(exc.reason) from None

    def _signal(self, image, gray, bg, c0, reach):
        """The laser's signal (:class:`~bayescal.image.measure.LaserSignal`) as the full
        extractor's, smoothed (a demosaiced channel) only within ``reach`` + the measurement's
        margin of ``c0``; its noise variance and saturated blobs computed where they are read,
        the noise model fitted on a sample of rows."""
        H, W = gray.shape
        reach = reach + MEASURE_MARGIN + 8
        box = (slice(max(0, int(c0[1] - reach)), min(H, int(c0[1] + reach) + 1)),
               slice(max(0, int(c0[0] - reach)), min(W, int(c0[0] + reach) + 1)))
        top, clip = saturation_level(image, gray), clip_level(image)
        on = _smoothed(gray, self._blur, box)
        step = max(2, int(round(H * W / NOISE_PIXELS)))
        rows = np.arange(step // 2 + 4, H - 4, step)
        if bg is None:
            model = noise_model(_strips(gray, rows, self._blur), rows=_mid(rows))
            sat = _Saturated([(gray, top)])
            return LaserSignal(on, _Variance(model, on), gray, sat,
                               _Blobs(sat, gray, BLOB_MARGIN), clip, False)
        bg = as_frame(bg)
        bgg = background_gray(bg, self.options["channel"], gray.shape)
        off = _smoothed(bgg, self._blur, box)
        s_on, s_off = _strips(gray, rows, self._blur), _strips(bgg, rows, self._blur)
        model = noise_model(s_on - s_off, levels=0.5 * (s_on + s_off), rows=_mid(rows))
        sat = _Saturated([(gray, top), (bgg, saturation_level(bg, bgg))])
        return LaserSignal(on - off, _Variance(model, 0.5 * (on + off)), gray, sat,
                           _Blobs(sat, gray, 1), clip, True)


class _Variance:
    """The noise variance of each pixel, ``model(level)``, computed where it is read: an
    array's indexing and shape (the peak fits read a few pixels about the ring)."""

    def __init__(self, model, level):
        self.model, self.level, self.shape = model, level, level.shape

    def __getitem__(self, key):
        return self.model(self.level[key])


class _Saturated:
    """Whether each pixel is saturated in one of ``images`` (pairs of a grey image and its
    saturation level), computed where it is read."""

    def __init__(self, images):
        self.images, self.shape = images, images[0][0].shape

    def __getitem__(self, key):
        return np.logical_or.reduce([img[key] >= top for img, top in self.images])


class _Blobs:
    """The saturated blobs (:func:`~bayescal.image.doubt.blob_mask` of the full extractor's
    signal), computed about the pixels where they are read: an array's indexing by two
    integer index arrays ``(rows, columns)``."""

    def __init__(self, sat, raw, margin):
        self.sat, self.raw, self.margin, self.shape = sat, raw, margin, raw.shape

    def __getitem__(self, key):
        vi, ui = key
        hit = self.sat[vi, ui]
        if not _has_core(self.sat, vi[hit], ui[hit]):
            return np.zeros(np.shape(vi), bool)
        pad = 40
        H, W = self.shape
        box = (slice(max(0, vi.min() - pad), min(H, vi.max() + pad + 1)),
               slice(max(0, ui.min() - pad), min(W, ui.max() + pad + 1)))
        mask = blob_mask(np.where(self.sat[box], np.inf, self.raw[box]), top=np.inf,
                         margin=self.margin)
        return mask[vi - box[0].start, ui - box[1].start]


def _has_core(sat, vv, uu, radius=2):
    """Whether one of the saturated pixels ``(vv, uu)`` has its whole disc of ``radius`` px
    saturated (a blob's core, which :func:`~bayescal.image.doubt.blob_mask` erodes to find;
    a thin clipped stripe has none). A core farther from the profiles than the mask grows it
    cannot reach a peak sample, which lies :data:`~bayescal.image.measure.MEASURE_MARGIN`
    samples inside them."""
    if len(vv) == 0:
        return False
    H, W = sat.shape
    dv, du = np.nonzero(np.hypot(*np.mgrid[-radius:radius + 1, -radius:radius + 1]) <= radius)
    rr = np.clip(vv[:, None] + dv[None] - radius, 0, H - 1)
    cc = np.clip(uu[:, None] + du[None] - radius, 0, W - 1)
    return bool(np.any(np.all(sat[rr, cc], axis=1)))


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


def _coarse(sig, c0, phi0, r0, band, highpass_px):
    """The ring moved from the last frame's (``r0`` at ``phi0`` about ``c0``): points
    (COARSE_RAYS, 2) px where each ray finds it, or its fitted motion where a ray does not,
    and that motion (COARSE_RAYS,) px along the rays (:func:`ring_azimuths`);
    raises :class:`_Lost` when too few rays find it near that motion, or it moved out of
    the band."""
    m = COARSE_RAYS
    phi = ring_azimuths(m)
    rp = np.interp(phi, phi0, r0, period=2 * np.pi)
    h = max(5, int(highpass_px) | 1) // 2
    lo = np.rint(rp).astype(int) - band - h
    rad = lo[:, None] + np.arange(2 * (band + h) + 1)[None]
    e = np.stack([np.cos(phi), np.sin(phi)], -1)
    vals = bilinear(sig, c0[0] + e[:, :1] * rad, c0[1] + e[:, 1:] * rad)[0]
    win = sliding_window_view(vals, 2 * h + 1, axis=1)
    high = vals[:, h:-h] - np.partition(win, h, axis=-1)[..., h]      # the running median's
    sm = gaussian_filter1d(high, 1.0, axis=1, mode="nearest")
    j = np.clip(np.argmax(sm, axis=1), 1, sm.shape[1] - 2)
    # the noise of the high-pass, robustly over blocks of 6 rays, the ridge (the samples
    # within 3 of each ray's highest) left out: in a band of 17 samples it is a third of them
    quiet = np.abs(np.arange(sm.shape[1])[None] - j[:, None]) > 3
    scale = 1.4826 * _nanmedian_rows(np.where(quiet, np.abs(sm), np.nan).reshape(m // 6, -1))
    scale = scale.repeat(6)
    i = np.arange(m)
    z = sm[i, j] / np.maximum(scale, 1e-9)
    a, b, c = sm[i, j - 1], sm[i, j], sm[i, j + 1]
    den = a - 2 * b + c
    frac = np.where(den < 0, 0.5 * (a - c) / np.where(den < 0, den, -1.0), 0.0)
    d = lo + h + j + np.clip(frac, -0.5, 0.5) - rp
    strong = z > Z_MIN
    if strong.sum() < 12:
        raise _Lost(f"the ring was not found within {band} px of the last one")
    motion, _ = ring_model(phi, d, strong.astype(float), order=3, iters=4)
    found = strong & (np.abs(d - motion) <= 1.5)
    if found.mean() < FOUND_MIN:
        raise _Lost(f"the ring was found within {band} px of the last one on "
                    f"{found.mean():.0%} of the rays (at least {FOUND_MIN:.0%})")
    if np.max(np.abs(motion)) > band - 2:
        raise _Lost(f"the ring moved by up to {np.max(np.abs(motion)):.1f} px (the band "
                    f"follows {band - 2} px)")
    rr = rp + np.where(found, d, motion)
    return c0 + rr[:, None] * e, motion


def _nanmedian_rows(x):
    """``np.nanmedian(x, axis=1)`` of a 2-D array (by one sort: NaN sorts last)."""
    s = np.sort(x, axis=1)
    c = np.count_nonzero(np.isfinite(x), axis=1)
    i = np.arange(len(x))
    return np.where(c > 0, 0.5 * (s[i, np.maximum((c - 1) // 2, 0)] + s[i, np.maximum(c // 2, 0)]),
                    np.nan)


def track_laser(frames, *, background=None, **options):
    """The laser pixels of every frame of a sequence, each frame's search seeded by the
    previous frame's ring.

    Parameters
    ----------
    frames : str, os.PathLike or iterable
        A folder of images (in the order of their names), a video file (needs PyAV:
        ``pip install bayescal[video]``), or an iterable of images (arrays or paths);
        see :func:`~bayescal.image.read.iter_frames`.
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

