"""What the extractor doubts: the mirror's image, saturated blobs, and whether the ring it
found is plausible at all (:func:`check_ring`, raising :class:`~bayescal.errors.ExtractionError`).
"""

from __future__ import annotations

import numpy as np
from scipy.ndimage import (
    binary_closing,
    binary_dilation,
    binary_erosion,
    binary_fill_holes,
    distance_transform_edt,
    gaussian_filter,
    label,
    maximum,
)

from ..errors import ExtractionError
from .peak import bilinear, corner_sum
from .ring import circle_fit

__all__ = ["mirror_disc", "dark_core", "blob_mask", "check_ring", "check_colour", "colour_heights",
           "is_white", "ADVICE", "COLOUR_RATIO", "COLOUR_CORE", "COLOUR_FLANK", "DISC_LIT", "LEAD",
           "PATH_SNR"]

#: a laser lives in one colour channel: the ring's median light (over its lower flank,
#: within COLOUR_CORE px of the point) in the brightest other channel is at most
#: COLOUR_RATIO of that in the laser's channel, or it is no laser of that colour. Measured:
#: the real red rings 0.29-0.34 (eight dark frames), 0.55 (the lit frame's faint ring),
#: rings composited onto the second real sensor's frame 0.11-0.38, the red lasers of three
#: renderers 0.15-0.27; renderer2's white rail returned as the ring in its red rooms without
#: a laser 1.02-1.45 (seeds 0-2): 1.36x margins either side (docs/images.md). At the peak
#: pixel alone the real rings reached 0.47-0.53, refused by the former rule (0.5)
COLOUR_RATIO = 0.75

#: what to try when an extraction is implausible (the command line says it with its options)
ADVICE = ("Try a laser-off image of the same view (background=...), the centre of the mirror's "
          "image (center=(u, v)), or the laser's colour channel (channel=...)")


#: a mirror's image is lit inside, not only at its edge: the median grey level of the disc
#: between 0.4 and 0.85 of its radius (over the image's dark level) is at least DISC_LIT
#: of the 90th percentile at its rim (0.85-1.0). Measured (docs/images.md): 0.64-1.31 on
#: the mirror images of three renderers and the two lit real frames; 0.00-0.02 where a
#: bright laser ring in a dark real frame filled to a disc
DISC_LIT = 0.25


def mirror_disc(raw):
    """Centre (2,) and radius (px) of the mirror's image: the lit disc around the dark
    margin of a catadioptric image, fitted to its outer edge; None when the image has no
    dark margin to find (lit to its corners, or dark everywhere)."""
    step = 4 if min(raw.shape) >= 256 else 2
    small = gaussian_filter(raw[::step, ::step].astype(float), 1.5)
    lo, hi = np.quantile(small, [0.02, 0.9])
    if not hi > lo:
        return None
    # a low threshold and a closing: dark texture at the rim must not bite into the disc
    lit = binary_fill_holes(binary_closing(small > lo + 0.1 * (hi - lo), iterations=3))
    lab, n = label(lit)
    if n == 0:
        return None
    big = lab == 1 + int(np.argmax(np.bincount(lab.ravel())[1:]))
    frac = big.mean()
    if not 0.05 < frac < 0.95:
        return None
    edge = big & ~binary_erosion(big)
    edge[[0, -1], :] = edge[:, [0, -1]] = False        # the image's border is not the disc's
    vv, uu = np.nonzero(edge)
    if len(uu) < 20:
        return None
    c, R, res = circle_fit(np.column_stack([uu, vv]) * step + (step - 1) / 2.0)
    if not np.all(np.isfinite(c)) or np.median(np.abs(res)) > 0.05 * R:
        return None
    # lit inside, not only at its edge: a bright ring in a dark frame fills to a disc too
    vg, ug = np.mgrid[:small.shape[0], :small.shape[1]] * step + (step - 1) / 2.0
    rr = np.hypot(ug - c[0], vg - c[1]) / R
    inner, rim = small[(rr > 0.4) & (rr < 0.85)], small[(rr >= 0.85) & (rr < 1.0)]
    if len(inner) < 20 or len(rim) < 20 or \
            np.median(inner) - lo < DISC_LIT * (np.quantile(rim, 0.9) - lo):
        return None
    return c, R


def dark_core(raw, center, radius):
    """Radius (px) of the dark disc at the centre of the mirror's image (the camera's own
    reflection), 0 if there is none (a lit centre): where the median over azimuth of the grey
    level first rises three quarters of the way from the darkest to the typical lit level."""
    phi = np.linspace(-np.pi, np.pi, 90, endpoint=False)
    r = np.arange(0.0, 0.8 * radius)
    u = np.clip(center[0] + np.cos(phi)[:, None] * r, 0, raw.shape[1] - 1)
    v = np.clip(center[1] + np.sin(phi)[:, None] * r, 0, raw.shape[0] - 1)
    prof = np.median(raw[np.rint(v).astype(int), np.rint(u).astype(int)], axis=0)
    lo, hi = np.min(prof), np.median(prof)
    if not hi > lo or prof[0] > lo + 0.25 * (hi - lo):
        return 0.0
    return float(r[int(np.argmax(prof > lo + 0.75 * (hi - lo)))])


def blob_mask(raw, *, top=None, radius=2, margin=3):
    """Pixels of saturated blobs (lamps, glints), wider than ``2 radius + 1`` px, grown by
    ``margin`` px; a saturated stripe (a near, bright ring) is thinner and stays out."""
    top = float(np.max(raw)) if top is None else top
    sat = raw >= top
    if sat.mean() > 0.2 or not sat.any():                # a washed-out image: not blobs
        return np.zeros(raw.shape, bool)
    disc = np.hypot(*np.mgrid[-radius:radius + 1, -radius:radius + 1]) <= radius
    core = binary_erosion(sat, structure=disc)
    if not core.any():
        return core
    blobs = binary_dilation(core, structure=disc)
    if STRIPE:
        blobs = _without_stripes(blobs)
    return binary_dilation(blobs, iterations=radius + margin)


#: a saturated part no more than STRIPE[0] px from its edge anywhere, with an area over
#: STRIPE[1] discs of that radius, is a clipped stripe, not a lamp
STRIPE = (4.0, 6.0)
#: and so is any part no more than STRIPE_THIN px from its edge (at most ~6 px across): a
#: clipped stripe broken by speckle into short pieces (a third renderer's bright rooms;
#: kept there 0.879 -> 0.965, and renderer2's lamp rooms 0.78-0.93 -> 0.83-0.94)
STRIPE_THIN = 3.0


def _without_stripes(blobs):
    """``blobs`` less its thin parts: a laser stripe clipped on a bright wall is a
    saturated band a few px across and tens along the ring (curved with it), or short
    pieces of one; a lamp is round, as wide as it is long, and wider."""
    lab, n = label(blobs)
    if n == 0:
        return blobs
    idx = np.arange(1, n + 1)
    depth = np.asarray(maximum(distance_transform_edt(blobs), lab, idx))
    area = np.bincount(lab.ravel(), minlength=n + 1)[1:]
    stripe = ((depth <= STRIPE[0]) & (area > STRIPE[1] * np.pi * depth ** 2)) | \
        (depth <= STRIPE_THIN)
    # or straight and thin: its second moments' minor sd under 2 px, a quarter of the major
    vv, uu = np.nonzero(lab)
    ids = lab[vv, uu]
    for j in np.nonzero(~stripe & (area >= 10))[0]:
        m = ids == j + 1
        minor, major = np.sqrt(np.maximum(np.linalg.eigvalsh(np.cov(np.stack([uu[m], vv[m]]))),
                                          0.0))
        stripe[j] = minor < 2.0 and major > 4.0 * minor
    return np.concatenate([[False], ~stripe])[lab]


#: a laser ring is one closed curve, its light there at every azimuth. Where more than a
#: fifth of the ring found is flagged, two things must hold along its whole path: (1) half
#: of its azimuths hold a peak of PATH_SNR noise sds or more (the median over the path,
#: flagged azimuths included): measured 21-290 on laser rings (our 1280x1024 renders over
#: strong texture, seeds 0-11, 23-28 on the three with a fifth flagged; the real dark
#: frames) and 37 on the lit real frame's faint ring, against 0-7.4 on ring-less images
#: (three renderers, the second real sensor's laser-off frame, the lit real frame's wall,
#: our 1280x1024 laser-off renders): 1.7x and 1.6x margins; (2) it holds a point the
#: extractor trusts (on its smooth curve) on LEAD more of its azimuths than the best closed
#: path 8 px or more off it, measured the same way: rings lead by 0.21-0.78 (0.56-0.68
#: where a fifth is flagged), texture alone by -0.26 to 0.37 (a guard where a second
#: ring-like path exists). docs/images.md
PATH_SNR = 12.0
LEAD = 0.2


def check_ring(flagged, center, radius, *, mirror=None, expected=None, min_kept=0.5,
               closure=0, snr=None, rival=None, hinted=False):
    """Raise :class:`~bayescal.errors.ExtractionError` if the ring found is implausible.

    Parameters
    ----------
    flagged : ndarray of bool, shape (N,)
        The extractor's flags, one per azimuth.
    center : ndarray, shape (2,)
        Centre of a circle fitted to the unflagged points, px.
    radius : float
        Its radius, px.
    mirror : tuple or None
        ``(center, radius)`` of the mirror's image, px (None: not judged).
    expected : tuple of float or None
        ``(low, high)``: the ring's expected radius range, px.
    min_kept : float
        Smallest fraction of unflagged azimuths.
    closure : int
        Radial mismatch (px) of the dynamic-programming path after one lap.
    snr : ndarray, shape (N,), or None
        The peak's height over the noise sd at every azimuth of the ring's path (None skips
        the test): a laser ring's median is :data:`PATH_SNR` or more when more than a fifth
        of it is flagged.
    rival : ndarray of bool, shape (M,), or None
        The flags of the best closed path 8 px or more off the ring, measured the same way
        (None skips the test): a laser ring holds trusted points on :data:`LEAD` more of
        its azimuths when more than a fifth of it is flagged.
    hinted : bool
        The search was told where to look (a centre or radius): the messages say so.
    """
    n = len(flagged)
    kept = int(np.count_nonzero(~flagged))
    where = _where(center, radius, hinted, kept)
    if n == 0 or kept < 12:
        raise ExtractionError(f"no laser ring found{' there' if hinted else ''}: {kept} of {n} "
                              "azimuths hold a point the extractor trusts", ADVICE)
    # a clear ring (few points flagged) stands on its own, whatever the texture's best
    if n - kept > 0.2 * n:
        _stands_out(kept / n, snr, rival, where, hinted)
    if kept < min_kept * n:
        raise ExtractionError(f"most of the ring{where} is flagged: {n - kept} of {n} azimuths "
                              f"({100 * (n - kept) / n:.0f} %) are distractors or too faint "
                              f"(at most {100 * (1 - min_kept):.0f} % allowed)", ADVICE)
    if not np.isfinite(radius) or abs(closure) > max(3.0, 0.05 * radius):
        raise ExtractionError(f"the ring found{where} does not close on itself (it ends "
                              f"{closure} px from where it started, after one turn): not a "
                              "laser ring", ADVICE)
    if mirror is not None:
        mc, mr = mirror
        off = float(np.hypot(*(np.asarray(center) - mc)))
        if off > 0.25 * mr or radius > 0.92 * mr:
            raise ExtractionError(
                f"the ring found (centre ({center[0]:.0f}, {center[1]:.0f}), radius "
                f"{radius:.0f} px) is far from the mirror's image (centre ({mc[0]:.0f}, "
                f"{mc[1]:.0f}), radius {mr:.0f} px)",
                ADVICE + ", or the ring's centre and radius range in px (center=(u, v), "
                "radius=(low, high)): a bright rim of the mirror is a closed ring too, and a "
                "fisheye's ring need not sit inside its disc")
    if expected is not None and not expected[0] <= radius <= expected[1]:
        raise ExtractionError(f"the ring found has radius {radius:.0f} px, outside the "
                              f"expected {expected[0]:g}-{expected[1]:g} px", ADVICE)


def _stands_out(f, snr, rival, where, hinted):
    """Raise "no ring stands out" unless the path's median SNR reaches :data:`PATH_SNR` and
    its trusted fraction ``f`` leads the rival path's by :data:`LEAD`."""
    there = " there" if hinted else " of the image"
    if snr is not None:
        s = float(np.median(np.clip(np.nan_to_num(snr, nan=0.0), 0.0, None)))
        if s < PATH_SNR:
            raise ExtractionError(
                f"no ring stands out{there}: along the ring found{where}, half of the "
                f"azimuths hold a peak of {s:.1f} noise sds or less (a laser ring's path "
                f"stands at {PATH_SNR:g} or more) and {100 * (1 - f):.0f} % of it is flagged; "
                "wall texture or a pattern, not a laser ring", ADVICE)
    if rival is not None:
        f_other = float(np.mean(~np.asarray(rival, bool)))
        if f - f_other < LEAD:
            raise ExtractionError(
                f"no ring stands out{there}: the ring found{where} holds a point the extractor "
                f"trusts on {100 * f:.0f} % of its azimuths, the best other closed path "
                f"{100 * f_other:.0f} % (a laser ring, one continuous curve, leads by "
                f"{100 * LEAD:.0f} points or more); wall texture or a pattern, not a laser ring",
                ADVICE)


def _where(center, radius, hinted, kept):
    """`` (centre (u, v), radius R px)`` of the ring found, said when the user gave hints
    and there are enough points to fit it."""
    if not hinted or kept < 3 or not np.isfinite(radius):
        return ""
    return f" (centre ({center[0]:.0f}, {center[1]:.0f}), radius {radius:.0f} px)"


#: the ridge's light in a channel is its mean over the samples within COLOUR_CORE px of the
#: point along the ray, over the lower of its two flanks (the means of the samples
#: COLOUR_FLANK px either side): its area, not its peak. A colour image stored with its
#: chroma at reduced resolution (JPEG, a camera's video stream) or demosaiced keeps a thin
#: stripe's middle pixel in every channel, the laser's colour spread to its sides; over the
#: stripe and those sides the other channels' share is the light's own (real red rings:
#: 0.47-0.53 at the peak pixel, 0.29-0.34 over +-4 px; +-3 and +-5 px gave 0.30-0.37 and
#: 0.30-0.34; docs/images.md)
COLOUR_CORE = 4
COLOUR_FLANK = (6, 7, 8)


def _ridge_heights(image, background, channels, center, pixels):
    """Light (grey levels per px) of a ridge at each of ``pixels`` (N, 2) over the lower of
    its two flanks along the ray from ``center`` (:data:`COLOUR_CORE`,
    :data:`COLOUR_FLANK`), and the value at the pixel: a pair of (N,) arrays for each of
    ``channels`` of ``image`` (H, W, C) (minus ``background``'s, (H, W, C) or (H, W), when
    given), from one read of the samples' pixels."""
    d = pixels - center
    r = np.maximum(np.hypot(d[:, 0], d[:, 1]), 1e-9)
    e = d / r[:, None]
    fl = np.asarray(COLOUR_FLANK, float)
    core = np.arange(-COLOUR_CORE, COLOUR_CORE + 1, dtype=float)
    offs = np.concatenate([-fl, fl, core])                        # all samples at once
    q = center + e[:, None, :] * (r[:, None] + offs[None, :])[..., None]
    _, idx, wts = bilinear(image[..., channels[0]], q[..., 0], q[..., 1])
    px = image[idx[..., 0], idx[..., 1]]                          # (N, S, 4, C)
    bg = None if background is None else background[idx[..., 0], idx[..., 1]]
    m = len(fl)
    out = []
    for k in channels:
        at = px[..., k] if bg is None else \
            px[..., k].astype(float) - (bg[..., k] if bg.ndim == 4 else bg).astype(float)
        v = corner_sum(at * wts)                                  # (N, S), as bilinear's
        low = np.minimum(v[:, :m].mean(axis=1), v[:, m:2 * m].mean(axis=1))
        out.append((v[:, 2 * m:].mean(axis=1) - low, v[:, 2 * m + COLOUR_CORE]))
    return out


def _grey(arr, channel):
    """Whether a colour image ``arr`` (H, W, C) is a grey one stored in colour: its other
    channels within 2 grey levels (of 255 over the type's range) of ``channel`` at 99 % of
    the pixels or more (exactly equal, or a grey JPEG's chroma noise). Integer images are
    compared in integers (the same verdicts, without a float copy of the image)."""
    integer = np.issubdtype(arr.dtype, np.integer)
    top = float(np.iinfo(arr.dtype).max) if integer else float(arr.max())
    tol = 2.0 * max(top, 1e-12) / 255.0
    wide = {1: np.int16, 2: np.int32}.get(arr.dtype.itemsize, np.int64) if integer else float
    mine = arr[..., channel].astype(wide)
    size = mine.size
    return all(np.count_nonzero(np.abs(arr[..., k] - mine) <= tol) / size >= 0.99
               for k in range(3) if k != channel)


def colour_heights(image, background, channel, pixels, center, *, min_points=12):
    """Median ridge height of the points in the laser's colour channel and in the brightest
    other channel (grey levels, over the lower flank 3-5 px away along the ray), or None
    where colour tells nothing: a grey image, a grey image stored in colour (every channel
    within 2 grey levels of the laser's at 99 % of the pixels), or fewer than
    ``min_points`` points where the laser's channel does not clip (a clipped height is a
    lower bound).

    Parameters
    ----------
    image : ndarray, shape (H, W) or (H, W, C)
    background : ndarray or None
        The laser-off image, subtracted channel by channel when given.
    channel : int
        The laser's channel.
    pixels : ndarray, shape (N, 2)
        Points on the ring, px.
    center : ndarray, shape (2,)
        Centre of the radial profiles, px.
    min_points : int, optional

    Returns
    -------
    tuple of float or None
        ``(own, other)``.
    """
    arr = np.asarray(image)
    if arr.ndim != 3 or arr.shape[2] < 3 or len(pixels) < min_points or _grey(arr, channel):
        return None
    c = np.asarray(center, dtype=float)
    order = [channel] + [k for k in range(3) if k != channel]
    heights = _ridge_heights(arr, None if background is None else np.asarray(background),
                             order, c, pixels)
    if np.issubdtype(arr.dtype, np.integer):    # where the laser's channel clips, its height
        raw = heights[0] if background is None else \
            _ridge_heights(arr, None, [channel], c, pixels)[0]      # is unknown
        keep = raw[1] < np.iinfo(arr.dtype).max - 0.5
        if np.count_nonzero(keep) < min_points:
            return None
        heights = [(h[keep], v[keep]) for h, v in heights]
    own = float(np.median(heights[0][0]))
    other = max(float(np.median(h)) for h, _ in heights[1:3])
    return own, other


def is_white(heights):
    """Whether ``(own, other)`` from :func:`colour_heights` is no laser of that colour (the
    other channel above :data:`COLOUR_RATIO` of the laser's); None when colour tells
    nothing."""
    return None if heights is None else bool(heights[0] <= 0 or
                                             heights[1] > COLOUR_RATIO * heights[0])


def check_colour(image, background, channel, pixels, center):
    """Raise :class:`~bayescal.errors.ExtractionError` if the ring found in a colour image
    is as bright in another colour channel as in the laser's (a white rail, a door frame, a
    light edge: a laser lives in one channel); nothing where :func:`colour_heights` says
    colour tells nothing (a grey image, a grey image stored in colour, a ring clipped in
    the laser's channel).

    Parameters
    ----------
    image : ndarray, shape (H, W) or (H, W, C)
    background : ndarray or None
        The laser-off image, subtracted channel by channel when given.
    channel : int
        The laser's channel.
    pixels : ndarray, shape (N, 2)
        The ring's unflagged points, px.
    center : ndarray, shape (2,)
        Centre of the radial profiles, px.
    """
    h = colour_heights(image, background, channel, pixels, center)
    if is_white(h):
        raise ExtractionError(
            f"the ring found is no brighter in the laser's colour channel {channel} than in the "
            f"others (median height {h[0]:.1f} against {h[1]:.1f} grey levels; a laser's other "
            f"channels reach at most {COLOUR_RATIO:g} of it): a white rail or edge, not a laser",
            ADVICE)
