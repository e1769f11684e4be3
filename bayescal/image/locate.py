"""Where the laser ring runs: a first pass over every radius, the circles it suggests, and
the ring's path about each of them (:func:`ring_candidates`).

A rail around the room, a door frame or a poster's edge can be a thin closed ridge as bright
as a faint laser ring, and the radius most azimuths share may be theirs. So the first pass
offers up to three circles (the histogram's two highest peaks and the best closed path off
the first one's ring), each followed by a constrained path; the extractor keeps the ring
whose points it trusts most (:func:`bayescal.image.extract.extract_laser`).
"""

from __future__ import annotations

import numpy as np

from .doubt import dark_core, mirror_disc
from .measure import ring_azimuths
from .peak import fit_peaks
from .ring import (
    PATH_CAP,
    QUANTUM_SD,
    circle_fit,
    polar_image,
    ridge_crest,
    ridge_near,
    ring_model,
    ring_path,
    ring_priors,
    ring_rays,
)

__all__ = ["RingCandidate", "ring_candidates", "stripe_widths", "parts_alike", "PRIOR_TOL",
           "PRIOR_SLOPE", "WIDTH_SAME", "WIDTH_JUMP"]

#: the path's cost for straying from the ring's circle: free within max(PRIOR_TOL[0] px,
#: PRIOR_TOL[1] x the ridge's sd about the circle), then PRIOR_SLOPE sds per px
PRIOR_TOL = (3.0, 4.0)
PRIOR_SLOPE = 1.0
#: the outer fraction of the mirror's disc left out of the search: a bright rim (a
#: thin annulus 6-7 % inside the disc's fitted edge, in a third renderer's images) is a
#: closed ring too; the laser rings of our and renderer2's rooms reach 38 % and 67 % of it
RIM = 0.15


def _start(raw, center, radius, highpass_px):
    """Centre of the first profiles, the search's outer radius and the mirror's disc (a
    user's radius outranks the disc: a fisheye's ring need not sit inside it)."""
    mirror = mirror_disc(raw)
    H, W = raw.shape
    if center is not None:
        c = np.asarray(center, dtype=float)
    elif mirror is not None:
        c = mirror[0]
    else:
        c = np.array([(W - 1) / 2.0, (H - 1) / 2.0])
    corners = np.array([[0, 0], [W - 1, 0], [0, H - 1], [W - 1, H - 1]], float)
    r_max = float(np.max(np.hypot(*(corners - c).T)))
    band = radius
    if mirror is not None and radius is None:   # the mirror's rim is a circle too: stay inside
        r_max = min(r_max, mirror[1] - max(8.0, RIM * mirror[1]))
    # the ring lies outside the camera's own dark reflection (its edge is a circle too)
    core = dark_core(raw, c, mirror[1] if mirror is not None else 0.5 * min(H, W))
    if core > 0:                    # past the high-pass's reach from its edge
        lo = core + 0.5 * highpass_px + 2.0
        band = (lo, r_max) if radius is None else (max(radius[0], lo), radius[1])
    if radius is not None:
        r_max = min(r_max, float(radius[1]) + 8.0)
    return c, r_max, mirror, band


def _score_without_blobs(pol, blobs):
    """Zero the ridge score on saturated blobs: a lamp neither attracts nor repels the path."""
    on = pol.sample_mask(blobs)
    pol.score[on] = 0.0
    return on


def _locate(sig, blobs, c, r_max, *, n, highpass_px, r_band=None, runner_up=False,
            prior=None, floor=0.0):
    """Polar image around ``c``, the ring's path in it (the peak sample's radius index per
    azimuth), its closure, the blob mask in polar coordinates, the path's robust model and
    (``runner_up``) the best closed path 8 px or more off it (a RingCandidate, else None)."""
    r_min = 0.0 if r_band is None else r_band[0] - highpass_px
    pol = polar_image(sig, c, n_azimuth=n, r_max=r_max, highpass_px=highpass_px, r_min=r_min,
                      floor=floor)
    if r_band is not None:
        pol.score[:, (pol.radii < r_band[0]) | (pol.radii > r_band[1])] = 0.0
    on_blob = _score_without_blobs(pol, blobs)
    free = pol.score
    if prior is not None:
        # the ring is nearly a circle about ``c`` (radius, tolerance px): a cost for
        # straying farther from it, PRIOR_SLOPE noise sds per azimuth per px
        far = np.maximum(np.abs(pol.radii[None, :] - np.reshape(prior[0], (-1, 1)))
                         - prior[1], 0.0)
        pol.score = pol.score - PRIOR_SLOPE * far
    pol.free = free
    # the cost comes off the capped score: a ridge scoring past the cap would otherwise pay
    # for its detour out of its excess (a rail 20 px off the ring over a quarter of it,
    # scoring 10-30 sds, tied with the ring's capped 8)
    path, closure, gain = ring_path(pol.score if prior is None else
                                    np.minimum(free, PATH_CAP) - PRIOR_SLOPE * far,
                                    tie=free)
    rival = None
    if runner_up:
        off = pol.score.copy()
        off[np.abs(pol.radii[None, :] - pol.radii[path][:, None]) <= 8] = 0.0
        other, other_closure, _ = ring_path(off)
        rival = RingCandidate(pol, *_peaks(pol, other, off), other_closure, on_blob)
    best, model = _peaks(pol, path, pol.score)
    pol.gain = gain
    return pol, best, closure, on_blob, model, rival


def _peaks(pol, path, score):
    """The peak sample per azimuth along a path (n,) and the path's robust model (n,) px."""
    n = len(path)
    # the highest ridge sample within 2 px of the path (the path moves in whole steps), or,
    # where the path ran on the flank of a ridge scoring past the cap (a bright stripe on
    # a black background does over several px), within 2 px of that ridge's crest
    crest = ridge_crest(pol, path)
    capped = pol.free[np.arange(n), path] >= PATH_CAP
    track = np.where(capped & (np.abs(crest - path) > 2), crest, path)
    best = ridge_near(pol, track, 2)
    # a sector where the path left the ring for a brighter ridge (a rail, a poster's edge
    # crossing it): the ring elsewhere predicts where it runs there; look within 1 px of that
    # (the model through those peaks, not the path: on a bright stripe the path may run on
    # its flank, 2 px inside the crest, over a sector, and a model 3 px off the ring flags
    # its points there "off model": real frames' rings, 25-45 points)
    z = score[np.arange(n), path]
    model, _ = ring_model(pol.phi, pol.radii[best], (z > 3).astype(float))
    stray = np.abs(pol.radii[best] - model) > 2.0
    if np.any(stray):
        near = ridge_near(pol, np.rint(model - pol.radii[0]).astype(int), 1)
        # not where the sample near the model is the flank of the path's own peak: the ring
        # strays 2 px from its Fourier model there (real frames' rings over 20-30 azimuths;
        # a room's corner), and the fit on that flank is 0.5 px off its crest
        flank = ridge_crest(pol, near, reach=4) == best
        best = np.where(stray & ~flank, near, best)
    return best, model


class RingCandidate:
    """One ring the image may hold.

    Attributes
    ----------
    pol : PolarImage
        Its profiles.
    k : ndarray of int, shape (n,)
        The peak sample's radius index per azimuth.
    closure : int
        The path's mismatch after one turn, px.
    on_blob : ndarray of bool, shape (n, K)
        Saturated blobs at the profiles' samples.
    model : ndarray, shape (n,)
        A robust Fourier model of its radius, px.
    """

    def __init__(self, pol, k, model, closure, on_blob):
        self.pol, self.k, self.model, self.closure, self.on_blob = pol, k, model, closure, on_blob

    @property
    def center(self):
        """ndarray, shape (2,): centre of its profiles, px."""
        return self.pol.center

    @property
    def radii(self):
        """ndarray, shape (n,): its path, the peak sample's radius per azimuth, px (what
        :func:`~bayescal.image.measure.measure_ring` measures)."""
        return self.pol.radii[self.k]


def ring_candidates(signal, center, radius, *, n_azimuth, highpass_px, runner_up):
    """The rings the image may hold, best guess first, the best closed path off the first
    pass's ring, and the mirror's disc.

    Two passes: 360 profiles over every radius from the mirror's centre (the circles that
    most azimuths share, the circle of its own path), then, per circle, the final profiles
    about its centre, in a band about its radius, with a cost for straying from it; a
    further circle is the best closed path 4 px or more off the first ring (a faint ring
    beside a rail that the histogram merges with it).

    Parameters
    ----------
    signal : LaserSignal
        :func:`~bayescal.image.measure.laser_signal` of the image.
    center, radius
        The user's hints (None: not given), as in
        :func:`~bayescal.image.extract.extract_laser`.
    n_azimuth : int or None
    highpass_px : int
    runner_up : bool
        Also return the best closed path 8 px or more off the first pass's ring.

    Returns
    -------
    candidates : list of RingCandidate
    rival : RingCandidate or None
        The best closed path 8 px or more off the first pass's ring, in the first pass's
        profiles (with ``runner_up``): on texture alone it is as good a ring as the best.
    mirror : tuple or None
        ``(centre, radius)`` of the mirror's image, px.
    """
    sig, blobs = signal.signal, signal.blobs
    floor = 0.0 if signal.top is None else QUANTUM_SD
    c0, r_max, mirror, band0 = _start(signal.raw, center, radius, highpass_px)
    pol, k0, _, _, _, rival = _locate(sig, blobs, c0, r_max, n=360, highpass_px=highpass_px,
                                      r_band=band0, runner_up=runner_up, floor=floor)
    priors = [p for p in ring_priors(pol) if np.hypot(*(p[0] - c0)) < 0.5 * p[1]]
    # the first pass's own path: where the ring is off the profiles' centre (a fisheye's
    # ring, an off-centre camera), it crosses many radii and shares none with many azimuths
    own = _path_circle(pol, k0)
    if own is not None and all(np.hypot(*(own[0] - p[0])) + abs(own[1] - p[1]) > 3.0
                               for p in priors):
        priors.append(own)
    args = dict(c0=c0, r_max=r_max, band0=band0, center=center, n_azimuth=n_azimuth,
                highpass_px=highpass_px, floor=floor)
    if not priors:
        return [_second_pass(sig, blobs, None, **args)], rival, mirror
    out = [_second_pass(sig, blobs, p, **args) for p in priors]
    other = _beside(out[0])
    if other is not None and all(np.hypot(*(other[0] - p[0])) + abs(other[1] - p[1]) > 3.0
                                 for p in priors):
        out.append(_second_pass(sig, blobs, other, **args))
    return out, rival, mirror


def _path_circle(pol, k, *, score=None, z_min=3.0):
    """The circle (centre, radius, sd) through a path's samples ``k`` (n,) that score
    ``z_min`` or more (in ``score``, default the unpenalised score); None if fewer than a
    quarter of the azimuths do."""
    z = (pol.free if score is None else score)[np.arange(len(k)), k]
    if np.count_nonzero(z >= z_min) < 0.25 * len(k):
        return None
    r = pol.radii[k]
    pts = pol.center + r[:, None] * np.stack([np.cos(pol.phi), np.sin(pol.phi)], -1)
    c, R, res = circle_fit(pts[z >= z_min])
    if not np.isfinite(R):
        return None
    return c, R, 1.4826 * float(np.median(np.abs(res - np.median(res))))


def _beside(cand, *, gap=4.0, z_min=3.0):
    """The circle (centre, radius, sd) of the best closed path ``gap`` px or more off a
    candidate's ring, through its samples scoring ``z_min`` or more; None if too few."""
    pol = cand.pol
    off = pol.free.copy()
    off[np.abs(pol.radii[None, :] - pol.radii[cand.k][:, None]) < gap] = 0.0
    return _path_circle(pol, ring_path(off)[0], score=off, z_min=z_min)


def _radius_along(p, R, c, phi):
    """The radius (n,) px about ``c`` at which each ray of azimuth ``phi`` (n,) crosses the
    circle of centre ``p`` (2,) and radius ``R`` px (``c`` inside it)."""
    e = np.stack([np.cos(phi), np.sin(phi)], -1)
    b = e @ (np.asarray(p, float) - c)
    return b + np.sqrt(np.maximum(R ** 2 - np.sum((p - c) ** 2) + b ** 2, 0.0))


def _second_pass(sig, blobs, prior, *, c0, r_max, band0, center, n_azimuth, highpass_px,
                 floor):
    """The final profiles about a circle ``prior`` (centre, radius, sd; None: about ``c0``
    over the whole band) and the ring's path through them."""
    if prior is not None:
        # the profiles the measurement reads for this circle (ring_rays: its centre on a
        # grid), the circle's radius along each of them
        c, n = ring_rays(prior[0], prior[1], center=center, n_azimuth=n_azimuth)
        R = float(np.hypot(*(prior[0] - c)) + prior[1]) if center is not None else prior[1]
        R_phi = _radius_along(prior[0], prior[1], c, ring_azimuths(n))
        tol = max(PRIOR_TOL[0], PRIOR_TOL[1] * prior[2])
    else:
        c, R, R_phi, tol = c0, 100.0, 100.0, 8.0
        n = int(n_azimuth) if n_azimuth else int(np.clip(np.pi * R, 360, 3600))
    band = band0
    if prior is not None:
        band = (0.7 * R, 1.3 * R) if center is None else (0.5 * R, 1.5 * R)
        band = band if band0 is None else (max(band[0], band0[0]), min(band[1], band0[1]))
    r_max = min(r_max, band[1] + highpass_px) if band is not None else r_max
    pol, k, closure, on_blob, model, _ = _locate(
        sig, blobs, c, r_max, n=n, highpass_px=highpass_px, r_band=band,
        prior=None if center is not None else (R_phi, tol), floor=floor)
    return RingCandidate(pol, k, model, closure, on_blob)


#: where one candidate ring leaves another over a sector and follows another ridge there (a
#: rail, a door frame), its stripe changes width where it leaves, the ring that runs on does
#: not: |log| of the median width (the peak fit's sd) where the two run apart over that where
#: they agree. Measured without a laser-off image, on the pairs that share half their path or
#: more (renderer2's tilted, faint, red, textured, lamp, 1280x1024, near and cam1280 rooms;
#: 27 pairs of a laser ring, gross < 5 %, and a ring on a rail over a sector, gross > 20 %):
#: laser rings 0.00-0.10, the rail's 0.32-0.58 in 22 of 27 (0.06-0.10 in five, where the
#: rail is as wide as the laser: near rooms, cam1280, and the fractions decide); the real
#: dark frames' rings 0.02-0.10 on such pairs (0.01-0.18 on all). WIDTH_SAME is 2x the
#: laser's largest, WIDTH_JUMP 3x it and under the rail's smallest where it differs
WIDTH_SAME = 0.2
WIDTH_JUMP = 0.3


def stripe_widths(signal, cand):
    """The stripe's width (the sd of a Gaussian through 5 samples, px, (n,)) at each peak
    sample of a candidate's path (:class:`RingCandidate`), over the profile's running
    median."""
    pol, k = cand.pol, cand.k
    i = np.arange(len(k))
    base = pol.base[i[:, None], k[:, None] + np.arange(-2, 3)[None]]
    return fit_peaks(signal.signal, signal.variance, pol.center, pol.phi, pol.radii[k], base,
                     sub=pol.sub)[5]


def parts_alike(width, kept, apart):
    """|log| of the median ``width`` (n,) of the ``kept`` (n,) points where a ring runs
    ``apart`` (n,) from another over that where they agree (NaN when either part has no
    kept point): small where the ring runs on one ridge, large where it changes ridges."""
    a, b = kept & apart & np.isfinite(width), kept & ~apart & np.isfinite(width)
    if not a.any() or not b.any():
        return np.nan
    return float(abs(np.log(np.median(width[a]) / np.median(width[b]))))
