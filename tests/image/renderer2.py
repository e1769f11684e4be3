"""A second renderer of omnidirectional laser images, written apart from the package's own.

It exists to test the laser extractor on images that the package did not make: its wall
textures, beam profile, lamps, vignetting and sensor noise are its own. Only the sensor model's
public functions are shared (``bc.backproject`` to render, ``bc.project`` and ``bc.cone_point``
for the truth), so the true ring is the geometry's, not a by-product of the rendering.

Pixel convention: ``image[v, u]`` is the pixel whose centre is at ``(u, v)`` (integer
coordinates at pixel centres); the truth pixels use the same convention.

Use (tests in ``tests/image`` import it as ``renderer2``; from other test folders,
``from image.renderer2 import render_scenario``, ``from image.score import score_extraction``)::

    image, off, truth = render_scenario("textured_2500", rng=0)   # or render2(params, ...)
    s = score_extraction(extracted_pixels, truth, flagged=flags)  # kept, bias, robust_sd, gross

Scenarios (:data:`SCENARIOS`): textured_2500, faint_4000_off, lamps, red_colour, red_bayer,
cam1280, no_ring, tilted, near_1200, clean_2500 (no texture, lamps or noise). ``truth`` is a
:class:`Truth2`: per azimuth sample (720 by default) the 3-D point, its pixel, a visibility
mask, the ring's normal, the rendered peak; ``truth.center`` is the principal point.

How an image is made, for each pixel whose ray reaches the mirror:
- the ray (``bc.backproject``) meets a vertical wall of the polygonal room, the floor or the
  ceiling; the hit point's material gives an RGB albedo (value noise at four scales, wood
  planks with grain, brick rows, posters with text bars and sharp edges, a bright rail,
  a door, skirting, floor tiles, ceiling panels);
- lighting: ambient with a slow azimuthal gradient plus pools around the lamps;
- lamps and glints: emitters (saturating core and a halo) at 3-D points, some on the ring;
- the laser: at a wall point, its distance (mm, in the wall, across the line) from the line
  where the cone meets that wall, through a Lorentzian, super-Gaussian or Gaussian profile whose
  width grows with the distance from the apex; brightness falls with distance, varies with
  azimuth and with the wall's albedo; pixels near the line are supersampled k x k (box
  filter), then multiplied by per-pixel speckle;
- optics: a Gaussian PSF, lens vignetting about the image centre and darkening towards the
  mirror's rim; outside the mirror the camera housing with a bright metal rim, at the centre
  the camera's own dark reflection;
- sensor: PRNU and hot pixels (fixed, shared by both frames), Poisson shot noise, read noise,
  black level, quantisation to 8, 12 or 16 bits; colour through an optional RGGB mosaic and
  bilinear demosaic. The laser-off frame is the same scene with its own noise, lamp flicker and
  a small exposure jitter.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from scipy import ndimage

import bayescal as bc

LASER_CHANNELS = {None: None, "red": np.array([1.0, 0.07, 0.02]),
                  "green": np.array([0.10, 1.0, 0.12])}
BEAM = dict(profile="lorentzian", width_mm=8.0, divergence=0.02, power=2.0, speckle=0.15,
            supersample=3, azimuth_ripple=0.25, albedo=0.6)
NOISE = dict(gain=8.0, read=6.0, black=3.0, bits=8, prnu=0.01, hot=1e-4, psf=0.55,
             exposure_jitter=0.005, flicker=0.03, bayer=False)
TEXTURE = dict(contrast=1.0, posters=2, rail=True, door=True, materials=None)
VIGNETTING = dict(corner=0.45, rim=0.3)


@dataclass
class Truth2:
    """The true laser ring of one rendered image, per azimuth sample.

    azimuth : (n,) rad, the horizontal direction of the lit wall point from the axis.
    points : (n, 3) mm, the cone's intersection with the room's walls (frame C).
    pixels : (n, 2) px, ``bc.project(params, points)``; NaN where not imaged.
    visible : (n,) bool, the ring is drawn there and imaged inside the mirror and the image.
    normal : (n, 2) unit image normal of the ring, pointing away from ``center``.
    near_lamp : (n,) bool, a lamp or glint alone nearly saturates the ring there (> 200 grey
        levels within 2 px).
    peak : (n,) rendered laser peak over the background, in 8-bit grey levels (no noise).
    """

    azimuth: np.ndarray
    points: np.ndarray
    pixels: np.ndarray
    visible: np.ndarray
    normal: np.ndarray
    near_lamp: np.ndarray
    peak: np.ndarray
    center: np.ndarray
    params: bc.SensorParams
    laser_pose: object
    walls: np.ndarray
    image_size: tuple
    ring: bool
    colour: str | None
    noise_sd: float
    info: dict = field(default_factory=dict)


# -- room geometry ------------------------------------------------------------------------

def _room(params, walls, laser_pose, range_mm):
    """Floor and ceiling heights (mm, frame C) that keep the whole lit ring on the walls."""
    verts = walls[:, 0, :]
    zc = bc.cone_point(params, verts, laser=laser_pose)[:, 2]
    top = np.nanmax(zc) if np.any(np.isfinite(zc)) else range_mm
    return -params.h - 650.0, max(1.25 * top + 350.0, 1500.0)


def _hit(rays, walls, floor_z, ceil_z):
    """First surface hit by unit rays (n, 3): point (n, 3), kind (n,), wall index, perimeter
    position (mm). kind 0 wall, 1 floor, 2 ceiling."""
    dx, dy, dz = rays.T
    s = np.hypot(dx, dy)
    with np.errstate(divide="ignore", invalid="ignore"):
        cx, cy = dx / s, dy / s
        a = walls[:, 0, :]
        e = walls[:, 1, :] - a
        det = -cx[:, None] * e[:, 1] + e[:, 0] * cy[:, None]
        th = (-a[:, 0] * e[:, 1] + e[:, 0] * a[:, 1]) / det
        q = (cx[:, None] * a[:, 1] - cy[:, None] * a[:, 0]) / det
    ok = (th > 0) & (q >= 0) & (q <= 1)
    th = np.where(ok, th, np.inf)
    j = np.argmin(th, axis=1)
    t = np.take_along_axis(th, j[:, None], 1)[:, 0] / np.where(s > 0, s, np.nan)
    t = np.where(np.isfinite(t), t, np.inf)
    z = t * dz
    kind = np.zeros(len(rays), int)
    with np.errstate(divide="ignore", invalid="ignore"):
        up = z > ceil_z
        down = ~(z >= floor_z)
        t = np.where(up, ceil_z / dz, np.where(down, floor_z / dz, t))
    kind[up], kind[down] = 2, 1
    lengths = np.hypot(e[:, 0], e[:, 1])
    start = np.concatenate([[0.0], np.cumsum(lengths)[:-1]])
    qj = np.take_along_axis(q, j[:, None], 1)[:, 0]
    perim = start[j] + qj * lengths[j]
    return rays * t[:, None], kind, j, perim


# -- textures --------------------------------------------------------------------------------

class _Noise2:
    """Value noise on an integer lattice (hashed table, smoothstep interpolation)."""

    def __init__(self, rng, size=257):
        self.table = rng.random((size, size))
        self.size = size

    def __call__(self, x, y):
        i, j = np.floor(x), np.floor(y)
        fx, fy = x - i, y - j
        fx, fy = fx * fx * (3 - 2 * fx), fy * fy * (3 - 2 * fy)
        i = i.astype(np.int64) % self.size
        j = j.astype(np.int64) % self.size
        i1, j1 = (i + 1) % self.size, (j + 1) % self.size
        t = self.table
        top = t[i, j] * (1 - fx) + t[i1, j] * fx
        bot = t[i, j1] * (1 - fx) + t[i1, j1] * fx
        return top * (1 - fy) + bot * fy

    def octaves(self, x, y, scales, amps):
        return sum(a * (self(x / s + 31.7 * k, y / s - 17.3 * k) - 0.5)
                   for k, (s, a) in enumerate(zip(scales, amps, strict=True)))


def _plaster(n, a, z, base):
    v = n.octaves(a, z, (900.0, 260.0, 70.0, 14.0), (0.25, 0.18, 0.10, 0.06))
    return base * (1 + v)[:, None]


def _wood(n, a, z, base):
    plank = np.floor(z / 130.0)
    gap = (z - 130.0 * plank) < 6.0
    warp = 40.0 * n(a / 400.0, z / 90.0 + 3.0)
    grain = 0.5 + 0.5 * np.sin(2 * np.pi * (z + warp) / 11.0)
    tone = 0.8 + 0.4 * n(plank * 5.3, 0.5 + 0.0 * a)
    v = tone * (0.85 + 0.3 * grain ** 3)
    v = np.where(gap, 0.25, v)
    return base * v[:, None]


def _brick(n, a, z, base):
    row = np.floor(z / 75.0)
    off = np.where(row % 2 == 0, 0.0, 112.0)
    col = np.floor((a + off) / 225.0)
    mortar = ((z - 75.0 * row) < 10.0) | (((a + off) - 225.0 * col) < 10.0)
    tone = 0.75 + 0.5 * n(col * 3.1 + 0.5, row * 2.7 + 0.5)
    rough = 1 + n.octaves(a, z, (30.0, 8.0), (0.15, 0.1))
    v = np.where(mortar, 1.45, tone * rough)
    return base * v[:, None]


MATERIALS = {"plaster": (_plaster, (0.80, 0.78, 0.72)), "wood": (_wood, (0.55, 0.38, 0.22)),
             "brick": (_brick, (0.55, 0.27, 0.20)), "paint": (_plaster, (0.35, 0.50, 0.62))}


def _wall_albedo(tex, a, z, wall, scene):
    """RGB albedo (n, 3) of wall points at perimeter position ``a`` and height ``z`` (mm)."""
    n = scene["noise"]
    out = np.empty((len(a), 3))
    for w, name in enumerate(scene["materials"]):
        m = wall == w
        if np.any(m):
            fn, base = MATERIALS[name]
            out[m] = fn(n, a[m], z[m], np.asarray(base))
    mean = out.mean(axis=0)
    out = mean + tex["contrast"] * (out - mean)
    for (a0, a1, z0, z1, colour, ink, pitch) in scene["posters"]:
        m = (a >= a0) & (a < a1) & (z >= z0) & (z < z1)
        if np.any(m):
            line = ((z[m] - z0) % pitch) < 0.45 * pitch
            word = n(a[m] / 60.0, np.floor((z[m] - z0) / pitch) * 7.1) > 0.35
            out[m] = np.where((line & word)[:, None], ink, colour)
    for (z0, z1, colour) in scene["bands"]:
        m = (z >= z0) & (z < z1)
        out[m] = colour
    if scene["door"] is not None:
        a0, a1, ztop = scene["door"]
        m = (a >= a0) & (a < a1) & (z < ztop)
        frame = m & ((a < a0 + 60) | (a >= a1 - 60) | (z >= ztop - 60))
        out[m] = (0.30, 0.20, 0.12)
        out[frame] = (0.92, 0.92, 0.90)
    return np.clip(out, 0.02, 1.0)


def _floor_ceiling_albedo(P, kind, scene):
    n = scene["noise"]
    out = np.empty((len(P), 3))
    x, y = P[:, 0], P[:, 1]
    fl = kind == 1
    tile = (np.floor(x[fl] / 330.0) + np.floor(y[fl] / 330.0)) % 2
    grout = ((x[fl] % 330.0) < 8) | ((y[fl] % 330.0) < 8)
    v = (0.45 + 0.2 * tile) * (1 + n.octaves(x[fl], y[fl], (200.0, 40.0), (0.2, 0.1)))
    out[fl] = np.where(grout, 0.2, v)[:, None] * np.array([0.9, 0.85, 0.8])
    ce = kind == 2
    panel = ((x[ce] % 600.0) < 15) | ((y[ce] % 600.0) < 15)
    out[ce] = np.where(panel, 0.55, 0.9)[:, None] * np.array([1.0, 1.0, 0.97])
    return out


def make_scene(rng, walls, ring_z, floor_z, *, texture=None):
    """Random materials, posters, bands and a door for a room (``ring_z``: the laser's
    height on each wall, mm, so that posters and the rail meet or flank the ring)."""
    tex = {**TEXTURE, **(texture or {})}
    nw = len(walls)
    names = list(MATERIALS)
    mats = tex["materials"] or [names[k] for k in rng.integers(0, len(names), nw)]
    lengths = np.hypot(*(walls[:, 1] - walls[:, 0]).T)
    start = np.concatenate([[0.0], np.cumsum(lengths)[:-1]])
    posters = []
    for _ in range(int(tex["posters"]) * nw):
        w = rng.integers(nw)
        width = rng.uniform(400, 1100)
        a0 = start[w] + rng.uniform(0, max(lengths[w] - width, 1.0))
        z0 = ring_z[w] + rng.uniform(-700, 100)
        colour = rng.uniform(0.1, 0.95, 3)
        ink = np.clip(1.0 - colour + rng.normal(0, 0.05, 3), 0.03, 1)
        posters.append((a0, a0 + width, z0, z0 + rng.uniform(400, 900), colour, ink,
                        rng.uniform(25, 70)))
    bands = []
    if tex["rail"]:
        zr = float(np.median(ring_z)) + rng.choice([-1, 1]) * rng.uniform(180, 320)
        bands.append((zr, zr + 30.0, np.array([0.95, 0.95, 0.93])))
    door = None
    if tex["door"]:
        w = rng.integers(nw)
        a0 = start[w] + rng.uniform(0, max(lengths[w] - 900, 1.0))
        door = (a0, a0 + 900.0, floor_z + 2050.0)
    return dict(noise=_Noise2(rng), materials=mats, posters=posters, bands=bands, door=door,
                tex=tex)


# -- lamps -------------------------------------------------------------------------------------

def make_lamps(rng, params, walls, laser_pose, floor_z, ceil_z, *, on_ring=2, off_ring=2,
               glints_on=3, glints_off=3, ceiling=2):
    """Lamps (radius 40-90 mm, saturating) and glints (radius 15-30 mm) as dicts with ``pos``
    (3,) mm, ``radius`` mm, ``level`` grey levels, ``pool`` (lights the walls around it)."""
    lamps = []

    def wall_point(dz):
        az = rng.uniform(-np.pi, np.pi)
        rho = _polygon_distance(np.array([az]), walls)[0] - 60.0
        xy = rho * np.array([np.cos(az), np.sin(az)])
        z = bc.cone_point(params, xy, laser=laser_pose)[2] + dz
        return np.array([xy[0], xy[1], z])

    for k in range(on_ring + off_ring):
        dz = rng.uniform(-30, 30) if k < on_ring else rng.choice([-1, 1]) * rng.uniform(150, 600)
        lamps.append(dict(pos=wall_point(dz), radius=rng.uniform(40, 90),
                          level=rng.uniform(900, 3000), pool=0.35))
    for k in range(glints_on + glints_off):
        dz = rng.uniform(-15, 15) if k < glints_on else rng.uniform(-400, 400)
        lamps.append(dict(pos=wall_point(dz), radius=rng.uniform(15, 30),
                          level=rng.uniform(1500, 4000), pool=0.0))
    for _ in range(ceiling):
        r = rng.uniform(300, 900)
        az = rng.uniform(-np.pi, np.pi)
        lamps.append(dict(pos=np.array([r * np.cos(az), r * np.sin(az), ceil_z - 30]),
                          radius=150.0, level=3000.0, pool=0.5))
    return lamps


def _lamp_light(rays, P, lamps):
    """Per lamp: light emitted along each ray and pool light on each hit point, (L, n) each
    (a frame weights them by its flicker)."""
    emit = np.zeros((len(lamps), len(rays)))
    pool = np.zeros((len(lamps), len(rays)))
    for k, lamp in enumerate(lamps):
        c = lamp["pos"]
        dist = np.linalg.norm(c)
        r = lamp["radius"] / dist
        cosang = rays @ (c / dist)
        near = cosang > np.cos(min(40 * r, np.pi))
        ang = np.arccos(np.clip(cosang[near], -1, 1))
        core = np.clip((r - ang) / (0.15 * r) + 0.5, 0, 1)
        halo = 0.12 * np.exp(-np.maximum(ang - r, 0) / (1.5 * r))
        emit[k, near] = lamp["level"] * (core + halo)
        if lamp["pool"]:
            pool[k] = lamp["pool"] / (1 + np.sum((P - c) ** 2, axis=1) / 700.0 ** 2)
    return emit, pool


# -- the laser -------------------------------------------------------------------------------

def _polygon_distance(az, walls):
    """Horizontal distance (mm) from the axis to the first wall along azimuths ``az``."""
    rays = np.stack([np.cos(az), np.sin(az), np.zeros_like(az)], axis=-1)
    P, _, _, _ = _hit(rays, walls, -np.inf, np.inf)
    return np.hypot(P[:, 0], P[:, 1])


def _apex(params, laser_pose):
    pose = np.zeros(4) if laser_pose is None else np.asarray(
        laser_pose.to_array() if isinstance(laser_pose, bc.LaserPose) else laser_pose, float)
    return np.array([pose[2], pose[3], -params.h])


def _profile(d, w, kind):
    x = 2.0 * d / w
    if kind == "lorentzian":
        return 1.0 / (1.0 + x * x)
    if kind == "supergauss":
        return np.exp(-np.log(2.0) * x ** 4)
    if kind == "gauss":
        return np.exp(-np.log(2.0) * x * x)
    raise ValueError(f"beam profile must be 'lorentzian', 'supergauss' or 'gauss', got {kind!r}")


def _laser_geometry(P, j, params, laser_pose, walls, apex):
    """Signed distance (mm) across the laser line in the wall, the distance from the apex
    (mm) and the cosine of incidence, for wall points ``P`` (n, 3) on walls ``j``."""
    e = walls[j, 1] - walls[j, 0]
    e /= np.linalg.norm(e, axis=1, keepdims=True)
    xy = P[:, :2]
    zc = bc.cone_point(params, xy, laser=laser_pose)[:, 2]
    eps = 5.0
    slope = (bc.cone_point(params, xy + eps * e, laser=laser_pose)[:, 2]
             - bc.cone_point(params, xy - eps * e, laser=laser_pose)[:, 2]) / (2 * eps)
    d = (P[:, 2] - zc) / np.sqrt(1.0 + slope ** 2)
    R = P - apex
    L = np.linalg.norm(R, axis=1)
    normal = np.stack([-e[:, 1], e[:, 0]], axis=1)
    cos_inc = np.abs(np.sum(R[:, :2] * normal, axis=1)) / L
    return np.where(np.isfinite(d), d, np.inf), L, cos_inc


def _laser_layer(rays, P, kind, j, uv, ctx):
    """Laser brightness (n,) at pixels ``uv`` (n, 2) whose centre rays hit ``P``:
    pixel-centre value, replaced by the k x k box average near the line."""
    params, pose, walls, apex, beam = (ctx[k] for k in ("params", "pose", "walls", "apex",
                                                       "beam"))
    out = np.zeros(len(P))
    wall = kind == 0
    d, L, cos_inc = _laser_geometry(P[wall], j[wall], params, pose, walls, apex)
    w = beam["width_mm"] + beam["divergence"] * L
    out[wall] = _profile(d, w, beam["profile"])
    k = int(beam["supersample"])
    band = np.zeros(len(P), bool)
    band[wall] = np.abs(d) < 5.0 * w
    if k > 1 and np.any(band):
        off = (np.arange(k) + 0.5) / k - 0.5
        ou, ov = (a.ravel() for a in np.meshgrid(off, off))
        sub = (uv[band][:, None, :] + np.stack([ou, ov], 1)[None]).reshape(-1, 2)
        r2 = bc.backproject(params, sub)
        bad = ~np.all(np.isfinite(r2), axis=1)
        r2[bad] = (0.0, 0.0, -1.0)
        P2, kind2, j2, _ = _hit(r2, walls, ctx["floor_z"], ctx["ceil_z"])
        val = np.zeros(len(P2))
        m = (kind2 == 0) & ~bad
        d2, L2, _ = _laser_geometry(P2[m], j2[m], params, pose, walls, apex)
        val[m] = _profile(d2, beam["width_mm"] + beam["divergence"] * L2, beam["profile"])
        out[band] = val.reshape(-1, k * k).mean(axis=1)
    gain = np.zeros(len(P))
    ratio = np.clip(ctx["L_ref"] / L, 0.3, 3.0) ** beam["power"]
    gain[wall] = ratio * cos_inc / ctx["cos_ref"]
    return out * gain


def _ripple(rng, amount):
    """Azimuthal brightness of the laser ring: 1 + a few random harmonics, >= 0.35."""
    c = rng.normal(0, 1, 4) / np.sqrt(4)
    ph = rng.uniform(0, 2 * np.pi, 4)
    return lambda az: np.clip(1 + amount * sum(c[k] * np.cos((k + 1) * az + ph[k])
                                               for k in range(4)), 0.35, None)


def _truth_geometry(params, laser_pose, walls, n_azimuth):
    az = np.linspace(-np.pi, np.pi, n_azimuth, endpoint=False)
    rho = _polygon_distance(az, walls)
    xy = rho[:, None] * np.stack([np.cos(az), np.sin(az)], axis=1)
    P = bc.cone_point(params, xy, laser=laser_pose)
    ok = np.all(np.isfinite(P), axis=1)
    pix = np.full((n_azimuth, 2), np.nan)
    if np.any(ok):
        pix[ok] = bc.project(params, P[ok])
    return az, P, pix


def _ring_normal(pix, center):
    tang = np.roll(pix, -1, axis=0) - np.roll(pix, 1, axis=0)
    n = np.stack([tang[:, 1], -tang[:, 0]], axis=1)
    n /= np.linalg.norm(n, axis=1, keepdims=True)
    flip = np.sum(n * (pix - center), axis=1) < 0
    n[flip] *= -1
    return n


# -- optics and sensor ------------------------------------------------------------------------

def _vignetting(uv, image_size, frac, vig):
    """Lens falloff about the image centre times the mirror's darkening towards its rim."""
    W, H = image_size
    c = np.array([(W - 1) / 2, (H - 1) / 2])
    r2 = np.sum((uv - c) ** 2, axis=1)
    rc2 = np.sum(c ** 2)
    k = ((1.0 / (1.0 - vig["corner"])) ** 0.5 - 1.0) / rc2
    return (1.0 / (1.0 + k * r2) ** 2) * (1.0 - vig["rim"] * np.clip(frac, 0, 1) ** 2)


HOUSING = 14.0


def _mirror_box(params, image_size, mirror):
    """Flat indices of the pixels in the box around the mirror's image (its rim ring at the
    top elevation plus 8 deg, projected at 360 azimuths, plus 3 px); the whole image if that
    ring is not imaged everywhere."""
    W, H = image_size
    az = np.linspace(-np.pi, np.pi, 360, endpoint=False)
    el = np.radians(min(mirror[1] + 8.0, 89.0))
    ring = np.stack([np.cos(az) * np.cos(el), np.sin(az) * np.cos(el),
                     np.full_like(az, np.sin(el))], axis=1)
    pix = bc.project(params, ring)
    if not np.all(np.isfinite(pix)):
        lo, hi = (0, 0), (W - 1, H - 1)
    else:
        lo = np.maximum(np.floor(pix.min(axis=0)) - 3, 0).astype(int)
        hi = np.minimum(np.ceil(pix.max(axis=0)) + 3, [W - 1, H - 1]).astype(int)
    vv, uu = np.mgrid[lo[1]:hi[1] + 1, lo[0]:hi[0] + 1]
    return (vv * W + uu).ravel()


def _housing(uv, elev, ok, mirror, center):
    """Grey levels outside the mirror: dark housing, a bright metal rim, the camera's own dark
    reflection at the centre."""
    ang = np.arctan2(uv[:, 1] - center[1], uv[:, 0] - center[0])
    out = np.full(len(uv), HOUSING)
    rim = ok & (elev >= mirror[1]) & (elev < mirror[1] + 5.0)
    out[rim] = 95.0 * (0.75 + 0.25 * np.cos(3 * ang[rim]))
    hole = ok & (elev <= mirror[0])
    out[hole] = 8.0
    return out


def _demosaic(raw):
    """Bilinear demosaic of an RGGB mosaic (H, W) -> (H, W, 3)."""
    H, W = raw.shape
    yy, xx = np.mgrid[0:H, 0:W]
    masks = [(yy % 2 == 0) & (xx % 2 == 0), (yy + xx) % 2 == 1, (yy % 2 == 1) & (xx % 2 == 1)]
    k_rb = np.array([[1, 2, 1], [2, 4, 2], [1, 2, 1]]) / 4.0
    k_g = np.array([[0, 1, 0], [1, 4, 1], [0, 1, 0]]) / 4.0
    return np.stack([ndimage.convolve(raw * m, k, mode="mirror")
                     for m, k in zip(masks, (k_rb, k_g, k_rb), strict=True)], axis=-1)


def _sensor(img, rng, cfg, fixed):
    """Float image (H, W, C) in 8-bit grey levels -> quantised sensor output."""
    bits = int(cfg["bits"]) if cfg else 8
    top = 2 ** bits - 1
    x = img.copy()
    if cfg:
        x *= fixed["prnu"][..., None]
        bayer = cfg["bayer"] and x.shape[-1] == 3
        if bayer:
            H, W = x.shape[:2]
            yy, xx = np.mgrid[0:H, 0:W]
            ch = np.where((yy % 2 == 0) & (xx % 2 == 0), 0,
                          np.where((yy % 2 == 1) & (xx % 2 == 1), 2, 1))
            x = np.take_along_axis(x, ch[..., None], axis=-1)
        e = rng.poisson(np.maximum(x, 0) * cfg["gain"]).astype(float)
        x = (e + rng.normal(0.0, cfg["read"], x.shape)) / cfg["gain"] + cfg["black"]
        x[fixed["hot"]] += 120.0
        if bayer:
            x = _demosaic(x[..., 0])
    x = np.clip(np.round(x * 2 ** (bits - 8)), 0, top)
    x = x.astype(np.uint8 if bits == 8 else np.uint16)
    return x[..., 0] if x.shape[-1] == 1 else x


def _fixed_pattern(rng, shape, cfg):
    if not cfg:
        return None
    return dict(prnu=1.0 + cfg["prnu"] * rng.standard_normal(shape),
                hot=rng.random(shape) < cfg["hot"])


# -- the renderer ---------------------------------------------------------------------------------

LUMA = np.array([0.30, 0.59, 0.11])
LAMP_RGB = np.array([1.0, 0.96, 0.88])


def _setup(params, range_mm, laser_pose, walls, n_azimuth):
    walls = bc.room_walls(range_mm) if walls is None else np.asarray(walls, float)
    floor_z, ceil_z = _room(params, walls, laser_pose, range_mm)
    az, P_t, pix_t = _truth_geometry(params, laser_pose, walls, n_azimuth)
    apex = _apex(params, laser_pose)
    ok = np.all(np.isfinite(P_t), axis=1)
    dirs = np.stack([np.cos(az), np.sin(az), np.zeros_like(az)], axis=1)
    _, _, j_t, _ = _hit(dirs, walls, -np.inf, np.inf)
    _, L_t, cos_t = _laser_geometry(np.where(ok[:, None], P_t, 0.0), j_t, params, laser_pose,
                                    walls, apex)
    mids = bc.cone_point(params, walls.mean(axis=1), laser=laser_pose)[:, 2]
    ring_z = np.where(np.isfinite(mids), mids, np.nanmedian(mids))
    return dict(params=params, pose=laser_pose, walls=walls, floor_z=floor_z, ceil_z=ceil_z,
                apex=apex, L_ref=float(np.median(L_t[ok])), cos_ref=float(np.median(cos_t[ok])),
                ring_z=ring_z, truth=(az, P_t, pix_t))


def _surfaces(rays, ctx, scene, colour, rng):
    """Hit points, RGB albedo, ambient light and the laser's albedo factor per ray."""
    P, kind, j, perim = _hit(rays, ctx["walls"], ctx["floor_z"], ctx["ceil_z"])
    albedo = np.empty((len(P), 3))
    wall = kind == 0
    albedo[wall] = _wall_albedo(scene["tex"], perim[wall], P[wall, 2], j[wall], scene)
    albedo[~wall] = _floor_ceiling_albedo(P[~wall], kind[~wall], scene)
    az0 = rng.uniform(-np.pi, np.pi)
    ambient = 1.0 + 0.2 * np.cos(np.arctan2(P[:, 1], P[:, 0]) - az0)
    alb_c = albedo @ LUMA if colour is None else albedo @ (LASER_CHANNELS[colour]
                                                          / LASER_CHANNELS[colour].sum())
    return P, kind, j, albedo, ambient, alb_c


def render2(params, *, range_mm, image_size=(800, 600), laser_pose=None, walls=None,
            texture=None, lamps=None, laser=True, laser_peak=110.0, scene_level=170.0,
            colour=None, vignetting=None, beam=None, noise=None, mirror=(-58.0, 40.0),
            background=True, n_azimuth=720, rng=None):
    """Render one laser image (and its laser-off frame) of a polygonal room.

    params : bc.SensorParams. range_mm : room size (``bc.room_walls(range_mm)`` unless
    ``walls`` (W, 2, 2) mm is given). laser_pose : bc.LaserPose or None (aligned).
    texture, beam, noise, vignetting : dicts overriding :data:`TEXTURE`, :data:`BEAM`,
    :data:`NOISE`, :data:`VIGNETTING`; ``noise=False`` renders without noise (quantised only).
    lamps : None, a list of lamp dicts, or a dict of :func:`make_lamps` counts.
    laser : False renders no ring. laser_peak, scene_level : brightness in 8-bit grey levels
    (the laser on a white wall at the median ring distance; a wall of albedo 1).
    colour : None (grey), 'red' or 'green' (RGB image, the laser in that channel).
    mirror : (min, max) elevation in degrees that the mirror images.
    Returns ``(image, background or None, Truth2)``; images are uint8 (H, W[, 3]), or uint16
    for 12 or 16 bits.
    """
    rng = np.random.default_rng(rng)
    if colour not in LASER_CHANNELS:
        raise ValueError(f"colour must be None, 'red' or 'green', got {colour!r}")
    beam = {**BEAM, **(beam or {})}
    ncfg = None if noise is False else {**NOISE, **(noise or {})}
    vig = {**VIGNETTING, **(vignetting or {})}
    ctx = _setup(params, range_mm, laser_pose, walls, n_azimuth)
    ctx["beam"] = beam
    scene = make_scene(rng, ctx["walls"], ctx["ring_z"], ctx["floor_z"], texture=texture)
    if isinstance(lamps, dict):
        lamps = make_lamps(rng, params, ctx["walls"], laser_pose, ctx["floor_z"],
                           ctx["ceil_z"], **lamps)
    lamps = list(lamps or [])
    W, H = image_size
    flat = _mirror_box(params, image_size, mirror)
    uv = np.stack([flat % W, flat // W], axis=1).astype(float)
    rays, ok = bc.backproject(params, uv, return_valid=True)
    elev = np.full(len(uv), np.nan)
    elev[ok] = np.degrees(np.arcsin(np.clip(rays[ok, 2], -1, 1)))
    inside = ok & (elev > mirror[0]) & (elev < mirror[1])
    idx = flat[inside]
    r_in = rays[inside]
    uv_in = uv[inside]
    P, kind, j, albedo, ambient, alb_c = _surfaces(r_in, ctx, scene, colour, rng)
    las = np.zeros(len(idx))
    if laser:
        las = _laser_layer(r_in, P, kind, j, uv_in, ctx)
        g = _ripple(rng, beam["azimuth_ripple"])
        las *= g(np.arctan2(P[:, 1] - ctx["apex"][1], P[:, 0] - ctx["apex"][0]))
        s = beam["albedo"]
        las *= laser_peak * ((1 - s) + s * np.clip(alb_c / 0.6, 0, 1.5))
        if beam["speckle"] > 0:
            m = 1.0 / beam["speckle"] ** 2
            las *= rng.gamma(m, 1.0 / m, len(las))
    frac = (elev[inside] - mirror[0]) / (mirror[1] - mirror[0])
    V = _vignetting(uv_in, image_size, frac, vig)
    center = np.array([params.u0, params.v0])
    house = np.full(H * W, HOUSING)
    house[flat] = _housing(uv, elev, ok, mirror, center)
    C = 1 if colour is None else 3
    mix = LUMA[None] if colour is None else np.eye(3)
    chan = np.ones(1) if colour is None else LASER_CHANNELS[colour]
    fl = 1.0 if not ncfg else 1.0 + ncfg["flicker"] * rng.uniform(-1, 1, (2, len(lamps)))
    fl = np.broadcast_to(fl, (2, len(lamps)))
    psf = NOISE["psf"] if ncfg is None else ncfg["psf"]

    emit_l, pool_l = _lamp_light(r_in, P, lamps)

    def frame(flicker, laser_on, exposure):
        emit, pool = flicker @ emit_l, flicker @ pool_l
        rgb = scene_level * albedo * (ambient + pool)[:, None] + emit[:, None] * LAMP_RGB
        val = rgb @ mix.T + (las[:, None] * chan if laser_on else 0.0)
        img = np.repeat(house[:, None], C, axis=1)
        img[idx] = V[:, None] * val * exposure
        img = img.reshape(H, W, C)
        return np.stack([ndimage.gaussian_filter(img[..., c], psf) for c in range(C)], -1), emit

    fixed = _fixed_pattern(rng, (H, W), ncfg)
    img_f, emit = frame(fl[0], True, 1.0)
    image = _sensor(img_f, rng, ncfg, fixed)
    bg = None
    if background:
        jit = 1.0 + (ncfg["exposure_jitter"] * rng.standard_normal() if ncfg else 0.0)
        bg_f, _ = frame(fl[1], False, jit)
        bg = _sensor(bg_f, rng, ncfg, fixed)
    truth = _truth(ctx, image_size, mirror, laser, colour, (idx, las, V, emit, psf),
                   img_f, ncfg)
    return image, bg, truth


def _truth(ctx, image_size, mirror, laser, colour, layers, img_f, ncfg):
    W, H = image_size
    idx, las, V, emit, psf = layers
    az, P_t, pix_t = ctx["truth"]
    params = ctx["params"]
    center = np.array([params.u0, params.v0])
    fin = np.all(np.isfinite(pix_t), axis=1)
    el = np.degrees(np.arctan2(P_t[:, 2], np.hypot(P_t[:, 0], P_t[:, 1])))
    vis = fin & (pix_t[:, 0] >= 0) & (pix_t[:, 0] <= W - 1) & (pix_t[:, 1] >= 0)
    vis &= (pix_t[:, 1] <= H - 1) & (el > mirror[0] + 1) & (el < mirror[1] - 1) & bool(laser)
    ui = np.clip(np.round(np.nan_to_num(pix_t[:, 0])).astype(int), 0, W - 1)
    vi = np.clip(np.round(np.nan_to_num(pix_t[:, 1])).astype(int), 0, H - 1)
    lamp_mask = np.zeros(H * W, bool)
    lamp_mask[idx] = V * emit > 200.0
    lamp_mask = ndimage.binary_dilation(lamp_mask.reshape(H, W), iterations=2)
    las_img = np.zeros(H * W)
    las_img[idx] = V * las
    las_img = ndimage.maximum_filter(ndimage.gaussian_filter(las_img.reshape(H, W), psf), 3)
    chan = 0 if colour is None else int(np.argmax(LASER_CHANNELS[colour]))
    bgl = np.maximum(img_f[..., chan][vi, ui] - las_img[vi, ui], 0)
    sd = 0.0 if not ncfg else float(np.median(np.sqrt(bgl[vis] / ncfg["gain"] + (
        ncfg["read"] / ncfg["gain"]) ** 2))) if np.any(vis) else np.nan
    normal = _ring_normal(np.where(fin[:, None], pix_t, center), center)
    return Truth2(azimuth=az, points=P_t, pixels=np.where(fin[:, None], pix_t, np.nan),
                  visible=vis, normal=normal, near_lamp=lamp_mask[vi, ui] & vis,
                  peak=np.where(vis, las_img[vi, ui], 0.0), center=center, params=params,
                  laser_pose=ctx["pose"], walls=ctx["walls"], image_size=tuple(image_size),
                  ring=bool(laser), colour=colour, noise_sd=sd,
                  info=dict(floor_z=ctx["floor_z"], ceil_z=ctx["ceil_z"], mirror=mirror))


# -- scenarios ----------------------------------------------------------------------------------

def camera_1280():
    """A 1280x1024 paracatadioptric camera like the real one measured on chessboards
    (xi 1.134, gamma 318, centre (642.5, 522.9)), with a flatter laser cone (beta 1.25 rad) so
    that the ring falls inside its mirror (elevations -62 to 25 deg)."""
    g = 318.0 / 1.134
    return bc.SensorParams(xi=1.134, phi=0.0, alpha_u=g, alpha_v=-g, u0=642.5, v0=522.9,
                           h=200.0, beta=1.25)


SCENARIOS = {
    # walls whose texture (posters with text bars, wood grain, brick, a bright rail near the
    # ring) has edges as strong as the laser
    "textured_2500": dict(range_mm=2500, laser_peak=110.0,
                          texture=dict(contrast=1.6, posters=3, materials=None)),
    # a faint far ring: peaks of ~30-100 grey levels over a pixel noise sd near 10
    "faint_4000_off": dict(range_mm=4000, laser_peak=115.0, scene_level=120.0,
                           noise=dict(gain=0.7, read=4.0), texture=dict(posters=1)),
    # lamps and glints on and off the ring, flickering between the two frames
    "lamps": dict(range_mm=3000, laser_peak=130.0, noise=dict(flicker=0.05),
                  lamps=dict(on_ring=2, off_ring=3, glints_on=3, glints_off=4, ceiling=2)),
    "red_colour": dict(range_mm=2500, laser_peak=130.0, colour="red"),
    "red_bayer": dict(range_mm=2500, laser_peak=130.0, colour="red", noise=dict(bayer=True)),
    "cam1280": dict(range_mm=3000, laser_peak=120.0, image_size=(1280, 1024),
                    mirror=(-62.0, 25.0), beam=dict(divergence=0.006, width_mm=4.0),
                    lamps=dict(on_ring=1, off_ring=2, glints_on=1, glints_off=2, ceiling=1)),
    "no_ring": dict(range_mm=2500, laser=False, texture=dict(contrast=1.4),
                    lamps=dict(on_ring=1, off_ring=2, glints_on=2, glints_off=2, ceiling=1)),
    "tilted": dict(range_mm=2500, laser_peak=120.0,
                   laser_pose=bc.LaserPose(tilt_x=0.03, tilt_y=-0.02, offset_x=6.0,
                                           offset_y=-4.0)),
    "near_1200": dict(range_mm=1200, laser_peak=150.0),
    # no texture, no lamps, no noise: for checking the truth itself
    "clean_2500": dict(range_mm=2500, noise=False, beam=dict(speckle=0.0),
                       texture=dict(contrast=0.0, posters=0, rail=False, door=False)),
}


def scenario(name):
    """Keyword arguments of :func:`render2` for a named scenario (``params`` included)."""
    if name not in SCENARIOS:
        raise ValueError(f"unknown scenario {name!r}; expected one of {sorted(SCENARIOS)}")
    kw = {k: (dict(v) if isinstance(v, dict) else v) for k, v in SCENARIOS[name].items()}
    kw["params"] = camera_1280() if name == "cam1280" else bc.SensorParams.paper()
    return kw


def render_scenario(name, rng=None, **overrides):
    """``render2(**scenario(name), rng=rng)`` with keyword overrides."""
    kw = scenario(name)
    kw.update(overrides)
    params = kw.pop("params")
    return render2(params, rng=rng, **kw)
