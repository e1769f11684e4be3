"""Laser pixels from an image, with a covariance per point.

:func:`extract_laser` locates the laser ring (:mod:`bayescal.image.locate`: radial profiles
from a centre inside it, the ring as the closed ridge through them), then measures it
(:func:`~bayescal.image.measure.measure_ring`: one sub-pixel peak per azimuth, a weighted
Gaussian fit to five samples, its variance propagated from the image noise, distractors
flagged by the ring's consistency), and doubts what it found
(:mod:`bayescal.image.doubt`). The method and its measured accuracy are in
``docs/images.md``.
"""

from __future__ import annotations

import numpy as np

from .._validation import check_positive
from ..errors import InvalidValueError
from .doubt import check_colour, check_ring, colour_heights, is_white
from .locate import WIDTH_JUMP, WIDTH_SAME, parts_alike, ring_candidates, stripe_widths
from .measure import (
    OFFSET_SD,
    LaserPixels,
    laser_signal,
    measure_polar,
    measure_ring,
    measure_settled,
)
from .read import IMAGE_SUFFIXES, read_image
from .ring import circle_fit

__all__ = ["LaserPixels", "extract_laser", "laser_frame", "IMAGE_SUFFIXES", "OFFSET_SD",
           "measure_ring", "CHOICE_MARGIN"]

#: how much larger a fraction of its azimuths another candidate ring must keep to replace the
#: first (the circle most azimuths share). Measured without a laser-off image: renderer2's
#: tilted cone beside its rail (rng 6) has its laser ring 0.011 ahead of a ring that follows
#: the rail for half its turn; the closest wrong ring came 0.003 behind the laser's
CHOICE_MARGIN = 0.01


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
    signal = laser_signal(image, background=background, channel=channel)
    if center is not None:
        c = np.asarray(center, dtype=float)
        if c.shape != (2,) or not np.all(np.isfinite(c)):
            raise InvalidValueError(f"center must be (u, v) px, finite, got {center!r}")
    if radius is not None:
        radius = tuple(float(x) for x in np.ravel(radius))
        if len(radius) != 2 or not 0 <= radius[0] < radius[1]:
            raise InvalidValueError(
                f"radius must be (low, high) px with 0 <= low < high, got {radius!r}")
    cands, rival, mirror = ring_candidates(signal, center, radius, n_azimuth=n_azimuth,
                                           highpass_px=highpass_px, runner_up=check)
    kw = dict(min_snr=min_snr, gate_px=gate_px, along_sd=along_sd, var_floor=var_floor,
              highpass_px=highpass_px)
    cand = _choose(cands, signal, colour=lambda px, c: colour_heights(
        image, background, channel, px, c, min_points=6), **kw)
    # the chosen ring measured afresh: the same points as measure_ring gives its path
    lp = measure_ring(signal, cand.center, cand.radii, model=cand.model, offset_sd=offset_sd,
                      **kw)
    # on the profiles of the ring's own circle: the ring tracker reads the same ones
    lp = measure_settled(signal, lp, center=center, n_azimuth=n_azimuth, offset_sd=offset_sd,
                         **kw)
    if check:
        ok = ~lp.flagged
        cc, RR, _ = circle_fit(lp.pixels[ok]) if ok.sum() >= 3 else (lp.center, np.nan, None)
        other = None if rival is None else measure_ring(signal, rival.center, rival.radii,
                                                         model=rival.model, **kw)
        # a user's hint outranks the mirror's disc (a fisheye's ring need not sit in it)
        hinted = center is not None or radius is not None
        check_ring(lp.flagged, cc, RR, mirror=None if hinted else mirror, expected=radius,
                   closure=cand.closure, snr=lp.snr,
                   rival=None if other is None else other.flagged, hinted=hinted)
        check_colour(image, background, channel, lp.pixels[ok], lp.center)
    return lp


def _choose(cands, signal, *, colour=None, **kw):
    """The candidate ring whose points the extractor trusts most (measured on its own
    profiles, :func:`~bayescal.image.measure.measure_polar`). Each candidate in turn
    challenges the best so far (at first the circle most azimuths share): it wins if it
    runs apart from it (1.5 px or more away over a tenth of its azimuths or more) and keeps
    a larger fraction of its azimuths by more than :data:`CHOICE_MARGIN` (the strict
    off-curve gate's flags left out). Where the two share half their paths or more, the one
    whose stripe keeps its width where they part wins over one whose stripe changes width
    there (it left the ring for another ridge: :func:`~bayescal.image.locate.parts_alike`),
    whatever the fractions. In a colour image (``colour(pixels, center)``: the points'
    colour heights, :func:`~bayescal.image.doubt.colour_heights`) where the two run apart,
    the one whose points there are the laser's colour wins over one whose points are white,
    whatever else."""
    if len(cands) == 1:
        return cands[0]
    best = None
    kw = {k: v for k, v in kw.items() if k != "highpass_px"}
    for cand in cands:
        lp, _ = measure_polar(signal, cand.pol, cand.k, cand.model, cand.on_blob, **kw)
        if best is None:
            best = lp, cand, stripe_widths(signal, cand)
            continue
        b, _, w_b = best
        d = np.hypot(*(lp.pixels[:, None, :] - b.pixels[None]).T)
        apart, apart_b = np.min(d, axis=0) > 1.5, np.min(d, axis=1) > 1.5
        if np.mean(apart) < 0.1:
            continue
        w = stripe_widths(signal, cand)
        lead = np.mean(~lp.flagged) > np.mean(~b.flagged) + CHOICE_MARGIN
        if max(np.mean(apart), np.mean(apart_b)) <= 0.5:
            j, j_b = parts_alike(w, ~lp.flagged, apart), parts_alike(w_b, ~b.flagged, apart_b)
            lead = (lead or (j <= WIDTH_SAME and j_b > WIDTH_JUMP)) and \
                not (j_b <= WIDTH_SAME and j > WIDTH_JUMP)
        if colour is not None:
            white = is_white(colour(lp.pixels[apart & ~lp.flagged], lp.center))
            white_b = is_white(colour(b.pixels[apart_b & ~b.flagged], b.center))
            lead = (lead and not (white and white_b is False)) or (white is False and white_b)
        if lead:
            best = lp, cand, w
    return best[1]



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
