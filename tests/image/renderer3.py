"""A third laser-image renderer, written apart from bayescal's own and from renderer2.

Test helpers only (not part of the package). It uses the package's public sensor model
(``bc.project``, ``bc.backproject``, ``bc.SensorParams``) and nothing of its renderer or its
extractor. The image is built the way a physicist would build it:

* **Scene**: a convex room of vertical walls (half-plane polygon, the sensor off-centre), a
  floor and a ceiling, an optional doorway (the laser passes into a dark corridor: a gap in
  the ring) and an optional cabinet in front of a wall (the ring jumps inwards over it).
  Textures on the walls' own coordinates (s along the wall, z height, mm): bricks with
  mortar joints, wood panelling with warped grain, a periodic damask wallpaper, plain paint
  with value noise, and posters with lines of "text" (thin dark bars).
* **Light**: ceiling and wall lamps light the walls with ``I cos(incidence) / d^2``; the
  laser is a cone sheet whose cross-section is a **top-hat** (super-Gaussian of order 8) of
  physical thickness ``sqrt(w0^2 + (theta d)^2)`` mm, irradiance ``cos(incidence) / d^2``
  (Lambertian walls), integrated over each pixel by 5x5 sub-pixel rays in the band where it
  falls. Lamps are bright discs with halos, in the laser-off frame too.
* **Optics**: a defocus pillbox (radius 0.9 px) and a Gaussian (0.35 px), plus veiling glare
  (2 % of the light into an exponential kernel of 15 px); vignetting ``cos^4``; subjective
  **laser speckle** (multiplicative, correlated over ~1 px, contrast 0.3) on the laser light.
* **Sensor**: electrons with PRNU (1 %), **blooming** (charge above the full well spills
  along the column), Poisson shot noise, read noise, then 16-bit linear, or 8-bit with
  **gamma 2.2**; colour images through an RGGB **Bayer mosaic**, demosaiced bilinearly;
  JPEG (real 8x8 DCT blocks via Pillow) when the scenario says so.

The truth is the cone's centre: the laser ray of each azimuth traced to the first surface,
projected with the true sensor (``truth.pixels``), with a visibility flag (doorway, mirror
field, occlusion as seen from the camera).

``render3(scenario, rng)`` returns ``(image, laser_off_or_None, truth)``;
``score3(pixels, cov, flagged, truth)`` scores an extraction as docs/images.md does;
``write_inputs(...)`` writes the files a user would have (image, laser-off image, rough plan).
"""
from __future__ import annotations

import io
from dataclasses import dataclass, field

import numpy as np
from scipy import ndimage

import bayescal as bc

#: The scenarios of the hidden check's list, plus two of our own (doorway + cabinet).
SCENARIOS = ("textured", "lamps", "faint", "red", "cam1280", "noring", "furniture", "bright")

FULL_WELL = 12000.0  # electrons
READ_E = 7.0  # read noise, electrons


@dataclass
class Scenario:
    """The settings of one scenario (see ``scenario_settings``)."""

    name: str
    range_mm: float = 2500.0
    size: tuple = (800, 600)
    texture: float = 1.0  # contrast of the wall textures (0 plain)
    laser_dn: float = 110.0  # the ring's median peak: laser_dn / 255 of the full well, linear
    laser: bool = True
    background: bool = False  # also a laser-off frame
    colour: bool = False
    fmt: str = "png8"  # png8 | png16 | jpeg | rgb8
    n_wall_lamps_on_ring: int = 0
    n_ceiling_lamps: int = 2
    exposure: float = 0.35  # mean wall signal as a fraction of the full well
    doorway: bool = True
    cabinet: bool = False
    speckle: float = 0.3
    lamp_light: float = 0.3  # the lamps' share of the walls' light (see ``irradiance``)
    lamp_soft_mm: float = 900.0  # softening distance of their 1/d^2


def scenario_settings(name):
    """The settings of scenario ``name`` (one of ``SCENARIOS``)."""
    table = {
        "textured": Scenario("textured", fmt="png8", texture=1.0, laser_dn=90.0),
        "lamps": Scenario("lamps", fmt="jpeg", texture=0.6, n_wall_lamps_on_ring=2,
                          n_ceiling_lamps=3, laser_dn=100.0),
        "faint": Scenario("faint", range_mm=4500.0, fmt="png16", texture=0.8, laser_dn=30.0,
                          background=True),
        "red": Scenario("red", colour=True, fmt="rgb8", texture=0.8, laser_dn=100.0),
        "cam1280": Scenario("cam1280", size=(1280, 1024), fmt="png16", texture=0.8,
                            laser_dn=100.0),
        "noring": Scenario("noring", laser=False, fmt="png8", texture=1.0),
        "furniture": Scenario("furniture", range_mm=3000.0, fmt="png8", texture=0.7,
                              laser_dn=100.0, cabinet=True),
        # the textured room lit by brighter lamps (walls near them saturate)
        "bright": Scenario("bright", fmt="png8", texture=1.0, laser_dn=90.0,
                           lamp_light=0.65, lamp_soft_mm=600.0),
    }
    if name not in table:
        raise ValueError(f"scenario {name!r}; expected one of {SCENARIOS}")
    return table[name]


@dataclass
class Room:
    """A convex room: wall k is the line ``n_k . (x, y) = d_k`` (n_k outward, unit)."""

    normals: np.ndarray  # (K, 2)
    dist: np.ndarray  # (K,)
    corners: np.ndarray  # (K, 2): wall k runs from corners[k] to corners[k+1]
    floor: float  # z of the floor (negative, mm)
    ceiling: float  # z of the ceiling
    kinds: list  # texture kind per wall
    seeds: np.ndarray  # texture seed per wall
    door: tuple | None = None  # (wall, s0, s1, height z)
    cabinet: tuple | None = None  # (wall, s0, s1, depth mm, top z)
    posters: list = field(default_factory=list)  # (wall, s0, s1, z0, z1, seed)


@dataclass
class Truth3:
    """What the renderer knows: the true sensor, the ring, the room."""

    params: bc.SensorParams
    azimuth: np.ndarray  # (M,) laser azimuths, rad
    points: np.ndarray  # (M, 3) mm, frame C
    pixels: np.ndarray  # (M, 2) px
    visible: np.ndarray  # (M,) bool
    image_size: tuple
    room: Room
    plan: np.ndarray  # (K, 4) the rough floor plan a user would measure, x0 y0 x1 y1
    scenario: Scenario
    lamp_pixels: np.ndarray  # (L, 2) where the lamps image
    channel: int = 0
    jpeg: bytes | None = None  # the JPEG file's bytes (the image is their decoding)
    hidden: np.ndarray | None = None  # (M,) the scene alone saturates there (lamps)


# ----------------------------------------------------------------- sensor and room


def true_params(size, rng):
    """A sensor near the design values of a camera of ``size`` (W, H)."""
    w, h = size
    scale = min(w, h) / 600.0
    g = 55.0 * scale * (1 + 0.02 * rng.standard_normal())
    return bc.SensorParams(xi=1.0 + 0.02 * rng.standard_normal(), phi=0.0, alpha_u=g,
                           alpha_v=-g * (1 + 0.003 * rng.standard_normal()),
                           u0=w / 2 + 4 * scale * rng.standard_normal(),
                           v0=h / 2 + 4 * scale * rng.standard_normal(),
                           h=200 + 8 * rng.standard_normal(),
                           beta=np.deg2rad(60) + 0.015 * rng.standard_normal())


def make_room(sc, rng):
    """A convex room of 5-7 walls about ``sc.range_mm`` from the axis."""
    k = int(rng.integers(5, 8))
    rng.uniform(0, 2 * np.pi, k)  # unused draws, kept: each seed renders the room measured
    # spread the normals so that no two are closer than 35 deg nor further than 110 deg
    ang = np.linspace(0, 2 * np.pi, k, endpoint=False) + rng.uniform(-0.25, 0.25, k) * 2 * np.pi / k
    ang += rng.uniform(0, 2 * np.pi)
    n = np.stack([np.cos(ang), np.sin(ang)], axis=1)
    d = sc.range_mm * rng.uniform(0.8, 1.15, k)
    corners = np.empty((k, 2))
    for i in range(k):  # corner between wall i-1 and wall i
        a = np.stack([n[i - 1], n[i]])
        corners[i] = np.linalg.solve(a, np.array([d[i - 1], d[i]]))
    kinds = list(rng.choice(["brick", "wood", "paper", "paint"], size=k))
    room = Room(n, d, corners, floor=-1300.0, ceiling=1450.0, kinds=kinds,
                seeds=rng.integers(0, 2**31, k))
    if sc.doorway:
        w = int(rng.integers(k))
        length = wall_length(room, w)
        s0 = rng.uniform(0.15, 0.6) * length
        room.door = (w, s0, min(s0 + 900.0, 0.9 * length), np.inf)  # an opening, floor to ceiling
    if sc.cabinet:
        w = (room.door[0] + 2) % k if room.door else 0
        length = wall_length(room, w)
        s0 = rng.uniform(0.1, 0.5) * length
        room.cabinet = (w, s0, s0 + 1200.0, 600.0, np.inf)  # shelves up to the ceiling
    for w in range(k):  # posters: one or two per wall, some across the laser's height
        for _ in range(int(rng.integers(1, 3))):
            s0 = rng.uniform(0, max(wall_length(room, w) - 700, 1))
            z0 = rng.uniform(-300, 900)
            room.posters.append((w, s0, s0 + rng.uniform(400, 700), z0, z0 + rng.uniform(500, 900),
                                 int(rng.integers(2**31))))
    return room


def wall_length(room, w):
    k = len(room.dist)
    return float(np.linalg.norm(room.corners[(w + 1) % k] - room.corners[w]))


def rough_plan(room, rng, rel_sd=0.02, angle_sd=0.005):
    """The plan a user measures: each wall's distance and angle off by a draw, closed again."""
    k = len(room.dist)
    ang = np.arctan2(room.normals[:, 1], room.normals[:, 0]) + angle_sd * rng.standard_normal(k)
    n = np.stack([np.cos(ang), np.sin(ang)], axis=1)
    d = room.dist * (1 + rel_sd * rng.standard_normal(k))
    c = np.array([np.linalg.solve(np.stack([n[i - 1], n[i]]), [d[i - 1], d[i]]) for i in range(k)])
    return np.concatenate([c, np.roll(c, -1, axis=0)], axis=1)


# ----------------------------------------------------------------- ray tracing


def trace(room, origin, dirs):
    """First hit of rays ``origin + t dirs``: distance t, surface id, wall coordinate s, normal.

    Surface ids: 0..K-1 walls, K floor, K+1 ceiling, K+2 cabinet front, -1 the doorway (dark).
    """
    k = len(room.dist)
    o = np.broadcast_to(origin, dirs.shape)
    t = np.full(dirs.shape[0], np.inf)
    sid = np.full(dirs.shape[0], -2, dtype=int)
    for i in range(k):
        den = dirs[:, :2] @ room.normals[i]
        with np.errstate(divide="ignore", invalid="ignore"):
            ti = (room.dist[i] - o[:, :2] @ room.normals[i]) / den
        ok = (den > 1e-12) & (ti > 0) & (ti < t)
        t[ok], sid[ok] = ti[ok], i
    for zc, idx, sgn in ((room.floor, k, -1), (room.ceiling, k + 1, 1)):
        with np.errstate(divide="ignore", invalid="ignore"):
            ti = (zc - o[:, 2]) / dirs[:, 2]
        ok = (sgn * dirs[:, 2] > 1e-12) & (ti > 0) & (ti < t)
        t[ok], sid[ok] = ti[ok], idx
    p = o + t[:, None] * dirs
    s = np.zeros_like(t)
    wall = (sid >= 0) & (sid < k)
    for i in range(k):
        m = sid == i
        tang = room.corners[(i + 1) % k] - room.corners[i]
        tang = tang / np.linalg.norm(tang)
        s[m] = (p[m, :2] - room.corners[i]) @ tang
    if room.cabinet is not None:
        w, s0, s1, depth, top = room.cabinet
        n = room.normals[w]
        den = dirs[:, :2] @ n
        with np.errstate(divide="ignore", invalid="ignore"):
            tc = (room.dist[w] - depth - o[:, :2] @ n) / den
            pc = o + tc[:, None] * dirs
        tang = room.corners[(w + 1) % k] - room.corners[w]
        tang = tang / np.linalg.norm(tang)
        sc_ = (pc[:, :2] - room.corners[w]) @ tang
        ok = (den > 1e-12) & (tc > 0) & (tc < t) & (sc_ > s0) & (sc_ < s1) & (pc[:, 2] < top)
        t[ok], sid[ok], s[ok], p[ok] = tc[ok], k + 2, sc_[ok] - s0, pc[ok]
    if room.door is not None:
        w, s0, s1, top = room.door
        m = (sid == w) & (s > s0) & (s < s1) & (p[:, 2] < top)
        sid[m] = -1
    normal = np.zeros_like(p)
    wall = (sid >= 0) & (sid < k)
    normal[wall, :2] = -room.normals[sid[wall]]
    normal[sid == k] = (0, 0, 1)
    normal[sid == k + 1] = (0, 0, -1)
    if room.cabinet is not None:
        normal[sid == k + 2, :2] = -room.normals[room.cabinet[0]]
    return t, sid, s, p, normal


# ----------------------------------------------------------------- textures


def _value_noise(x, y, cell, seed):
    """Smooth value noise on a lattice of ``cell`` mm (cubic interpolation)."""
    r = np.random.default_rng(seed)
    gx, gy = x / cell, y / cell
    if gx.size == 0:                    # no hit point on this patch (a poster out of view)
        return np.zeros(0)
    x0, y0 = np.floor(gx.min()) - 2, np.floor(gy.min()) - 2
    nx, ny = int(np.ceil(gx.max() - x0)) + 4, int(np.ceil(gy.max() - y0)) + 4
    lat = r.standard_normal((nx, ny))
    return ndimage.map_coordinates(lat, [gx - x0, gy - y0], order=3, mode="nearest")


def albedo(room, sid, s, p, contrast):
    """RGB albedo (N, 3) of the hit points."""
    k = len(room.dist)
    n = len(sid)
    out = np.full((n, 3), 0.6)
    z = p[:, 2]
    for i in range(k):
        m = sid == i
        if not np.any(m):
            continue
        seed = int(room.seeds[i])
        out[m] = _wall_texture(room.kinds[i], s[m], z[m], seed, contrast)
    for (w, s0, s1, z0, z1, seed) in room.posters:
        m = (sid == w) & (s > s0) & (s < s1) & (z > z0) & (z < z1)
        if np.any(m):
            out[m] = _poster(s[m] - s0, z[m] - z0, seed, contrast)
    m = sid == k  # floor: planks
    if np.any(m):
        g = 0.35 + 0.1 * contrast * _value_noise(p[m, 0] * 0.2, p[m, 1], 200.0, 7)
        joint = (np.mod(p[m, 1], 140.0) < 4.0)
        out[m] = (g * (1 - 0.5 * joint))[:, None] * np.array([1.0, 0.75, 0.5])
    out[sid == k + 1] = 0.85  # ceiling
    m = sid == k + 2  # cabinet: dark wood
    if np.any(m):
        out[m] = _wall_texture("wood", s[m], z[m], 99, contrast) * 0.6
    out[sid == -1] = 0.02  # doorway: a dark corridor
    return np.clip(out, 0.01, 0.98)


def _wall_texture(kind, s, z, seed, c):
    r = np.random.default_rng(seed)
    base = r.uniform(0.45, 0.8, 3)
    if kind == "brick":
        row = np.floor(z / 75.0)
        col = np.floor((s + 0.5 * 225.0 * np.mod(row, 2)) / 225.0)
        jitter = np.random.default_rng(seed + 1).uniform(-1, 1, 4096)
        bid = (row * 131 + col * 17).astype(int) % 4096
        mortar = (np.mod(z, 75.0) < 10.0) | (np.mod(s + 0.5 * 225.0 * np.mod(row, 2), 225.0) < 10.0)
        g = 0.55 + c * (0.15 * jitter[bid] + 0.05 * _value_noise(s, z, 15.0, seed))
        g = np.where(mortar, 0.55 + c * 0.3, g)
        rgb = g[:, None] * np.array([1.0, 0.55, 0.4]) / 0.8
    elif kind == "wood":
        warp = 40.0 * _value_noise(s, z * 0.1, 300.0, seed)
        board = np.floor(s / 120.0)
        phase = 3 * _value_noise(s, z, 60, seed + 2)
        grain = np.sin(2 * np.pi * (s + warp + 37 * board) / 9.0 + phase)
        g = 0.5 + c * (0.12 * grain + 0.08 * _value_noise(s, z, 30.0, seed + 3))
        g = np.where(np.mod(s, 120.0) < 3.0, g * (1 - 0.5 * c), g)
        rgb = g[:, None] * np.array([1.0, 0.7, 0.45])
    elif kind == "paper":  # damask-like periodic wallpaper, period 80 x 110 mm
        a = np.cos(2 * np.pi * s / 80.0) + np.cos(2 * np.pi * z / 110.0)
        b = np.cos(2 * np.pi * (s / 80.0 + z / 110.0))
        motif = np.tanh(3 * (np.abs(a) - 0.9 + 0.3 * b))
        g = 0.6 + c * 0.18 * motif
        rgb = g[:, None] * base / base.mean()
    else:  # paint with slow value noise
        g = 0.65 + c * (0.06 * _value_noise(s, z, 400.0, seed)
                        + 0.03 * _value_noise(s, z, 20.0, seed + 5))
        rgb = g[:, None] * base / base.mean()
    return rgb


def _poster(s, z, seed, c):
    """A poster: light paper, a coloured picture block and lines of text (dark thin bars)."""
    r = np.random.default_rng(seed)
    rgb = np.tile(np.array([0.9, 0.88, 0.82]), (len(s), 1))
    pic = (z > 250) & (s > 40) & (s < 360)
    shade = 1 + 0.3 * _value_noise(s[pic], z[pic], 40.0, seed)
    rgb[pic] = r.uniform(0.15, 0.9, 3) * shade[:, None]
    line = np.floor(z / 16.0)
    in_line = (np.mod(z, 16.0) > 5) & (np.mod(z, 16.0) < 10.5) & (z < 240) & (z > 20)
    glyph = np.floor(s / 7.0)
    glyphs = np.random.default_rng(seed + 9).random(8192)
    ink = glyphs[((line * 977 + glyph) % 8192).astype(int)] < 0.55
    gaps = np.random.default_rng(seed + 10).random(8192)
    word_gap = gaps[((line * 31 + np.floor(s / 45.0)) % 8192).astype(int)] < 0.15
    dark = in_line & ink & ~word_gap & (s > 30) & (s < 500)
    rgb[dark] = 0.9 - c * 0.8
    return rgb


# ----------------------------------------------------------------- lights


def lamps(room, sc, rng, params, truth_fn):
    """Lamp positions (L, 3) and powers: ceiling lamps and wall lamps on the ring."""
    pos, power = [], []
    for _ in range(sc.n_ceiling_lamps):
        rr = sc.range_mm * rng.uniform(0.2, 0.6)
        a = rng.uniform(0, 2 * np.pi)
        pos.append((rr * np.cos(a), rr * np.sin(a), room.ceiling - 150.0))
        power.append(1.0)
    for _ in range(sc.n_wall_lamps_on_ring):
        alpha = rng.uniform(-np.pi, np.pi)
        pt = truth_fn(np.array([alpha]))[0]  # the laser on the wall at that azimuth
        out = pt.copy()
        out[:2] *= 1 - 120.0 / np.hypot(*pt[:2])  # 120 mm before the wall, at the ring's height
        pos.append(tuple(out))
        power.append(0.6)
    return np.array(pos).reshape(-1, 3), np.array(power)


def irradiance(p, normal, lamp_pos, lamp_pow, room_scale, share=0.3, soft=900.0):
    """Ambient irradiance at hit points: uniform + lamps' cos / d^2 (relative units)."""
    e = np.full(len(p), 0.35)
    for lp, pw in zip(lamp_pos, lamp_pow, strict=True):
        v = lp - p
        d2 = np.sum(v * v, axis=1)
        cosi = np.clip(np.sum(v * normal, axis=1) / np.sqrt(d2 + 1e-9), 0, None)
        cosi[p[:, 2] > lp[2] - 50.0] *= 0.1  # shaded lamps: little light above them
        e += pw * share * cosi * room_scale**2 / (d2 + soft**2)
    return e


# ----------------------------------------------------------------- the laser


def laser_dirs(params, alpha):
    """Unit directions (M, 3) of the cone's centre rays at laser azimuths ``alpha``."""
    b = params.beta
    return np.stack([np.sin(b) * np.cos(alpha), np.sin(b) * np.sin(alpha),
                     np.full_like(alpha, np.cos(b))], axis=1)


def laser_irradiance(params, p, normal, sid):
    """The laser sheet's irradiance at hit points (relative): top-hat across the sheet.

    Thickness ``w = sqrt(w0^2 + (theta d)^2)`` mm (half-width, w0 = 1 mm, theta = 0.4 mrad),
    profile ``exp(-(x / w)^8)`` of the distance x across the sheet, irradiance ``g / (w d)``
    (the sheet spreads over its circumference and thickness) times the cosine of incidence.
    """
    apex = np.array([0.0, 0.0, -params.h])
    v = p - apex
    d = np.linalg.norm(v, axis=1)
    theta = np.arctan2(np.hypot(v[:, 0], v[:, 1]), v[:, 2])
    x = (theta - params.beta) * d
    w = np.sqrt(1.0 + (4e-4 * d) ** 2)
    g = np.exp(-np.minimum((np.abs(x) / w) ** 8, 50.0))
    cosi = np.clip(-np.sum(v * normal, axis=1) / np.maximum(d, 1e-9), 0, None)
    e = g / (w * np.maximum(d, 1.0)) * cosi * 2500.0
    e[sid < 0] = 0.0  # the doorway: the light goes on into the dark
    return e


def _mirror_field(params, pixels):
    """Unit rays of pixels and their elevation (rad)."""
    d = bc.backproject(params, pixels)
    bad = ~np.all(np.isfinite(d), axis=-1)  # xi > 1: no ray beyond the sphere's image
    d[bad] = (0.0, 0.0, 1.0)
    el = np.arcsin(np.clip(d[..., 2], -1, 1))
    el[bad] = np.pi / 2
    return d, el


E_MAX = np.deg2rad(55.0)  # the mirror's rim, elevation seen from the focus
E_MIN = np.deg2rad(-58.0)  # below: the camera's own reflection


def truth_ring(params, room, alpha):
    """The cone's centre traced to the room: points (M, 3), pixels (M, 2), visible (M,)."""
    apex = np.array([0.0, 0.0, -params.h])
    t, sid, s, p, _ = trace(room, apex, laser_dirs(params, alpha))
    r = np.linalg.norm(p, axis=1)
    el = np.arcsin(np.clip(p[:, 2] / r, -1, 1))
    tc, _, _, _, _ = trace(room, np.zeros(3), p / r[:, None])
    vis = (sid >= 0) & (el < E_MAX - np.deg2rad(0.5)) & (el > E_MIN) & (np.abs(tc - r) < 1.0)
    return p, bc.project(params, p), vis


def _laser_image(params, room, size, contrast, band_deg=3.0, sub=5):
    """Laser light per pixel (H, W, 3): irradiance times RGB albedo, integrated over each
    pixel's area (sub x sub rays) where the sheet falls; and the trace of the pixel centres."""
    w, h = size
    vv, uu = np.mgrid[0:h, 0:w].astype(float)
    pix = np.stack([uu.ravel(), vv.ravel()], axis=1)
    d, el = _mirror_field(params, pix)
    _, sid, s_, p, nrm = trace(room, np.zeros(3), d)
    apex = np.array([0.0, 0.0, -params.h])
    v = p - apex
    theta = np.arctan2(np.hypot(v[:, 0], v[:, 1]), v[:, 2])
    band = (np.abs(theta - params.beta) < np.deg2rad(band_deg)) & (el < E_MAX) & (el > E_MIN)
    out = np.zeros((h * w, 3))
    idx = np.flatnonzero(band)
    off = (np.arange(sub) + 0.5) / sub - 0.5
    ou, ov = np.meshgrid(off, off)
    sp = (pix[idx, None, :] + np.stack([ou.ravel(), ov.ravel()], axis=1)[None]).reshape(-1, 2)
    ds, els = _mirror_field(params, sp)
    _, sids, ss, ps, ns = trace(room, np.zeros(3), ds)
    e = laser_irradiance(params, ps, ns, sids) * (els < E_MAX)
    e = e[:, None] * albedo(room, sids, ss, ps, contrast)
    out[idx] = e.reshape(len(idx), sub * sub, 3).mean(axis=1)
    return out.reshape(h, w, 3), (el.reshape(h, w), sid, s_, p, nrm)


# ----------------------------------------------------------------- optics and sensor


def psf_kernel():
    """Defocus pillbox (radius 0.9 px) convolved with a Gaussian (0.35 px), 9x9, sum 1."""
    f = 8
    y, x = (np.mgrid[0:9 * f, 0:9 * f] + 0.5) / f - 4.5
    k = (np.hypot(x, y) <= 0.9).astype(float)
    k = ndimage.gaussian_filter(k, 0.35 * f)
    k = k.reshape(9, f, 9, f).sum(axis=(1, 3))
    return k / k.sum()


def optics(img, glare=0.02, glare_px=15.0):
    """PSF and veiling glare (FFT, periodic edges are dark anyway)."""
    core = ndimage.convolve(img, psf_kernel(), mode="nearest")
    h, w = img.shape
    y = np.fft.fftfreq(h) * h
    x = np.fft.fftfreq(w) * w
    kern = np.exp(-np.hypot(*np.meshgrid(x, y)) / glare_px)
    kern /= kern.sum()
    halo = np.real(np.fft.ifft2(np.fft.fft2(img) * np.fft.fft2(kern)))
    return (1 - glare) * core + glare * halo


def speckle(shape, rng, contrast, corr_px=0.8):
    """Multiplicative subjective speckle, mean 1, correlated over ~``corr_px``."""
    f = rng.standard_normal(shape) + 1j * rng.standard_normal(shape)
    f = ndimage.gaussian_filter(f.real, corr_px) + 1j * ndimage.gaussian_filter(f.imag, corr_px)
    i = np.abs(f) ** 2
    return 1 + contrast * (i / i.mean() - 1)


def vignetting(size):
    w, h = size
    vv, uu = np.mgrid[0:h, 0:w]
    r2 = ((uu - w / 2) ** 2 + (vv - h / 2) ** 2) / (1.2 * w) ** 2
    return 1 / (1 + r2) ** 2


def bloom(e, iters=40):
    """Charge above the full well spills up and down its column until absorbed."""
    e = e.copy()
    for _ in range(iters):
        ex = np.clip(e - FULL_WELL, 0, None)
        if not ex.any():
            break
        e = np.minimum(e, FULL_WELL)
        e[1:] += ex[:-1] / 2
        e[:-1] += ex[1:] / 2
    return np.minimum(e, FULL_WELL)


def expose(mean_e, rng):
    """Electrons: Poisson shot noise, blooming, read noise (float electrons)."""
    e = rng.poisson(np.clip(mean_e, 0, 50 * FULL_WELL)).astype(float)
    return bloom(e) + READ_E * rng.standard_normal(e.shape)


def quantise(e, fmt):
    """Electrons to what the file holds: 16-bit linear (pedestal 256), or 8-bit gamma 2.2."""
    lin = np.clip((e + 40.0) / FULL_WELL, 0, 1)
    if fmt == "png16":
        return np.round(256 + lin * (65535 - 256)).astype(np.uint16)
    return np.round(255 * lin ** (1 / 2.2)).astype(np.uint8)


def demosaic(mosaic):
    """Bilinear demosaic of an RGGB mosaic (H, W) -> (H, W, 3)."""
    h, w = mosaic.shape
    yy, xx = np.mgrid[0:h, 0:w]
    masks = [(yy % 2 == 0) & (xx % 2 == 0), (yy + xx) % 2 == 1, (yy % 2 == 1) & (xx % 2 == 1)]
    k_rb = np.array([[0.25, 0.5, 0.25], [0.5, 1, 0.5], [0.25, 0.5, 0.25]])
    k_g = np.array([[0, 0.25, 0], [0.25, 1, 0.25], [0, 0.25, 0]])
    out = np.empty((h, w, 3))
    for c, (m, k) in enumerate(zip(masks, (k_rb, k_g, k_rb), strict=True)):
        out[..., c] = ndimage.convolve(mosaic * m, k, mode="mirror")
    return out


def jpeg_roundtrip(img8, quality=88):
    """The bytes of a real JPEG (Pillow) and the image decoded from them."""
    from PIL import Image

    buf = io.BytesIO()
    Image.fromarray(img8).save(buf, format="JPEG", quality=quality)
    data = buf.getvalue()
    return data, np.asarray(Image.open(io.BytesIO(data)))


# ----------------------------------------------------------------- the image

LIGHT_RGB = np.array([1.0, 0.92, 0.78])  # warm room light
LASER_RGB = np.array([1.0, 0.06, 0.02])  # a red laser (650 nm) in the R, G, B filters
GREY_W = np.array([0.3, 0.5, 0.2])  # a monochrome sensor's response to R, G, B


def _scene(params, room, sc, trace_px, lamp_pos, lamp_pow):
    """Scene radiance (H, W, 3), wall median 1; lamps drawn with halos."""
    w, h = sc.size
    el, sid, s, p, nrm = trace_px
    light = irradiance(p, nrm, lamp_pos, lamp_pow, sc.range_mm, sc.lamp_light, sc.lamp_soft_mm)
    rad = albedo(room, sid, s, p, sc.texture) * light[:, None]
    wall = (sid >= 0) & (sid < len(room.dist))
    rad /= np.median(rad[wall & (el.ravel() < E_MAX)].mean(axis=1))
    rad *= LIGHT_RGB
    el = el.ravel()
    rad[el >= E_MAX] = 0.04  # the mirror's housing
    rim = (el >= E_MAX - np.deg2rad(0.8)) & (el < E_MAX)
    rad[rim] = 0.9  # the mirror's bright rim
    rad[el <= E_MIN] = 0.03  # the camera seen in the mirror
    rad = rad.reshape(h, w, 3)
    vv, uu = np.mgrid[0:h, 0:w]
    for lp, pw in zip(lamp_pos, lamp_pow, strict=True):
        dist = np.linalg.norm(lp)
        el_l = np.arcsin(lp[2] / dist)
        tw, _, _, _, _ = trace(room, np.zeros(3), (lp / dist)[None])
        if not (E_MIN < el_l < E_MAX - np.deg2rad(1)) or tw[0] < dist:
            continue
        q = bc.project(params, lp)
        px_per_rad = abs(params.alpha_u) * (params.xi + params.phi) / (1 - np.sin(el_l))
        r_disc = max(2.5, 50.0 / dist * px_per_rad)
        rr = np.hypot(uu - q[0], vv - q[1])
        halo = 1.5 * np.exp(-rr / 6.0) + 0.3 / (1 + (rr / 10) ** 2)
        blob = 40.0 * pw * (rr <= r_disc) + pw * halo
        rad += blob[..., None] * LIGHT_RGB
    return rad


def render3(scenario, rng=None):
    """Render scenario ``scenario`` (one of ``SCENARIOS``).

    Returns ``(image, laser_off, truth)``: the image as its file holds it (uint8 or uint16,
    (H, W) grey or (H, W, 3) colour; for JPEG the decoded JPEG), the laser-off frame
    (same scene and lamps, no laser, its own noise; None unless the scenario has one) and a
    ``Truth3``.
    """
    rng = np.random.default_rng(rng)
    sc = scenario_settings(scenario)
    params = true_params(sc.size, rng)
    room = make_room(sc, rng)
    room.ceiling = max(room.ceiling, 0.62 * np.max(np.linalg.norm(room.corners, axis=1)))
    alpha = np.linspace(-np.pi, np.pi, 3600, endpoint=False)
    pts, pix, vis = truth_ring(params, room, alpha)
    lamp_pos, lamp_pow = lamps(room, sc, rng, params,
                               lambda a: truth_ring(params, room, a)[0])
    laser, trace_px = _laser_image(params, room, sc.size, sc.texture)
    scene = _scene(params, room, sc, trace_px, lamp_pos, lamp_pow)
    vig = vignetting(sc.size)
    chan = 0
    if sc.colour:
        las = np.stack([optics(laser[..., c]) for c in range(3)], axis=-1) * LASER_RGB
        las_ref = las[..., chan]
        scene = np.stack([optics(scene[..., c]) for c in range(3)], axis=-1)
    else:  # a monochrome sensor: one optics pass on the grey response
        las = optics(laser @ GREY_W)[..., None] * np.ones(3)
        las_ref = las[..., 0]
        scene = optics(scene @ GREY_W)[..., None] * np.ones(3)
    peak = ndimage.map_coordinates(las_ref * vig, [pix[vis, 1], pix[vis, 0]], order=1)
    scale = (sc.laser_dn / 255.0) / (sc.exposure * np.median(peak)) if sc.laser else 0.0
    sp = speckle(las.shape[:2], rng, sc.speckle)[..., None]
    jpeg, on = _sensor(sc, (scene + scale * las * sp) * vig[..., None], rng)
    off = _sensor(sc, scene * vig[..., None], rng)[1] if sc.background else None
    lamp_px = bc.project(params, lamp_pos) if len(lamp_pos) else np.empty((0, 2))
    # where the scene alone saturates the sensor (a lamp), the laser cannot be seen
    scene_e = (scene[..., chan] if sc.colour else scene[..., 0]) * vig * sc.exposure
    hidden = ndimage.map_coordinates(scene_e, [pix[:, 1], pix[:, 0]], order=1, cval=0) > 0.95
    truth = Truth3(params, alpha, pts, pix, vis & sc.laser, sc.size, room,
                   rough_plan(room, rng), sc, lamp_px, chan, jpeg, hidden)
    return on, off, truth


_PRNU = {}


def _sensor(sc, radiance, rng):
    """Radiance (H, W, 3) to the file's pixels."""
    h, w = radiance.shape[:2]
    if (h, w) not in _PRNU:
        _PRNU[(h, w)] = 1 + 0.01 * np.random.default_rng(12345).standard_normal((h, w))
    prnu = _PRNU[(h, w)]
    mean_e = FULL_WELL * sc.exposure
    if not sc.colour:
        e = expose(mean_e * (radiance @ GREY_W) * prnu, rng)
        img = quantise(e, sc.fmt)
        return jpeg_roundtrip(img) if sc.fmt == "jpeg" else (None, img)
    sens = np.array([0.8, 1.0, 0.6])  # raw channel sensitivities, white-balanced after
    yy, xx = np.mgrid[0:h, 0:w]
    cfa = np.where((yy % 2 == 0) & (xx % 2 == 0), 0, np.where((yy % 2 == 1) & (xx % 2 == 1), 2, 1))
    raw = np.take_along_axis(radiance * sens, cfa[..., None], axis=2)[..., 0]
    e = expose(mean_e * raw * prnu, rng)
    rgb = demosaic(e) / sens
    return None, quantise(rgb, "png8")


# ----------------------------------------------------------------- files and scoring


def write_inputs(folder, image, off, truth):
    """Write what a user has: the image file, the laser-off frame, the rough plan, the truth.

    Returns ``(image_path, off_path_or_None, walls_path)``. Formats: 8-bit grey PNG, 16-bit
    PNG, JPEG (the renderer's own bytes) or 8-bit colour PNG, as the scenario says.
    """
    import json
    from pathlib import Path

    import imageio.v3 as iio

    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    if truth.jpeg is not None:
        img_path = folder / "image.jpg"
        img_path.write_bytes(truth.jpeg)
    else:
        img_path = folder / "image.png"
        iio.imwrite(img_path, image)
    off_path = None
    if off is not None:
        off_path = folder / "image_off.png"
        iio.imwrite(off_path, off)
    walls = folder / "walls.csv"
    rows = ["x0,y0,x1,y1"] + [",".join(f"{x:.1f}" for x in r) for r in truth.plan]
    walls.write_text("\n".join(rows) + "\n")
    (folder / "truth3.json").write_text(json.dumps({
        "params": dict(zip(bc.PARAM_NAMES, truth.params.to_array().tolist(), strict=True)),
        "scenario": truth.scenario.name, "image_size": list(truth.image_size)}, indent=1))
    return img_path, off_path, walls


def score3(pixels, cov, flagged, truth, *, gross_px=1.0):
    """Score an extraction against the true ring, as docs/images.md defines the numbers.

    Errors are along the true ring's normal (px, + outwards) of the unflagged points at the
    azimuth (about the true principal point, eqs. (4)-(5)) of each point. ``kept``: the
    fraction of 1-degree azimuth bins where the ring is visible (and no lamp saturates the
    scene under it) that hold an unflagged point;
    ``gross``: the fraction of unflagged points with ``|error| > gross_px`` or at an azimuth
    where no ring is visible (doorway, mirror's rim); ``robust_sd``: 1.4826 MAD of the
    errors of the unflagged points on the ring; ``bias``: mean error of the non-gross;
    ``z_rms``: rms over the non-gross of error / sd, sd the extractor's covariance projected
    on the true normal. Points within 0.3 deg of a jump of the ring (a cabinet's edge) are
    left out of everything.
    """
    p = truth.params
    pixels = np.asarray(pixels, float).reshape(-1, 2)
    cov = np.asarray(cov, float).reshape(-1, 2, 2)
    keep = ~np.asarray(flagged, bool).reshape(-1)
    c = np.array([p.u0, p.v0])
    a_t = truth.azimuth
    m = len(a_t)
    step = 2 * np.pi / m
    tp, vis = truth.pixels, truth.visible.copy()
    jump = np.linalg.norm(np.diff(tp, axis=0, append=tp[:1]), axis=1) > 1.0
    edge = ndimage.binary_dilation(jump | np.roll(jump, 1) | (vis != np.roll(vis, 1)),
                                   iterations=3)
    rel = (pixels - c) / np.array([p.alpha_u, p.alpha_v])
    a = np.arctan2(rel[:, 1], rel[:, 0])
    x = (a - a_t[0]) / step
    i0 = np.floor(x).astype(int) % m
    f = x - np.floor(x)
    i1 = (i0 + 1) % m
    q = (1 - f)[:, None] * tp[i0] + f[:, None] * tp[i1]
    tang = tp[i1] - tp[i0]
    nrm = np.stack([tang[:, 1], -tang[:, 0]], axis=1)
    nrm /= np.linalg.norm(nrm, axis=1, keepdims=True)
    nrm *= np.sign(np.sum(nrm * (q - c), axis=1))[:, None]
    err = np.sum((pixels - q) * nrm, axis=1)
    sd_n = np.sqrt(np.einsum("ni,nij,nj->n", nrm, cov, nrm))
    on = vis[i0] & vis[i1] & ~edge[i0]
    skip = edge[i0] & keep
    use = keep & ~skip
    good = use & on & (np.abs(err) <= gross_px)
    bins_vis = np.zeros(360, bool)
    seen = vis if truth.hidden is None else vis & ~truth.hidden
    np.logical_or.at(bins_vis, (np.arange(m) * 360 // m), seen)
    bins = (np.floor((a + np.pi) / (2 * np.pi) * 360).astype(int)) % 360
    held = np.zeros(360, bool)
    held[bins[use & on]] = True
    n_use = int(np.count_nonzero(use))
    e_on = err[use & on]
    med = float(np.median(e_on)) if len(e_on) else np.nan
    return dict(
        n=len(pixels), n_flagged=int(np.count_nonzero(~keep)), n_scored=n_use,
        kept=float(np.count_nonzero(held & bins_vis) / max(np.count_nonzero(bins_vis), 1)),
        robust_sd=float(1.4826 * np.median(np.abs(e_on - med))) if len(e_on) else np.nan,
        bias=float(np.mean(err[good])) if np.any(good) else np.nan,
        gross=float(1 - np.count_nonzero(good) / n_use) if n_use else np.nan,
        z_rms=float(np.sqrt(np.mean((err[good] / sd_n[good]) ** 2))) if np.any(good) else np.nan,
        errors=err, on_ring=on & use)


def read_laser_csv(path):
    """``(pixels, cov, flagged, image_size)`` from a laser.csv that ``bayescal extract`` wrote."""
    import csv

    lines = open(path).read().splitlines()
    size = None
    for ln in lines:
        if ln.startswith("# image_size:"):
            size = tuple(int(v) for v in ln.split(":")[1].strip().split("x"))
    rows = list(csv.DictReader([ln for ln in lines if not ln.startswith("#")]))
    col = {k: np.array([float(r[k]) for r in rows]) for k in rows[0]}
    pix = np.stack([col["u"], col["v"]], axis=1)
    cov = np.stack([np.stack([col["cov_uu"], col["cov_uv"]], -1),
                    np.stack([col["cov_uv"], col["cov_vv"]], -1)], axis=1)
    return pix, cov, col["flagged"].astype(bool), size


IDENT = ("xi", "gamma_u", "gamma_v", "u0", "v0", "h", "beta")


def identifiable(p):
    """The seven identifiable coordinates of a SensorParams."""
    s = p.xi + p.phi
    return np.array([p.xi, p.alpha_u * s, p.alpha_v * s, p.u0, p.v0, p.h, p.beta])


def _run(cmd, cwd, timeout):
    import os
    import subprocess
    import sys
    import time
    from pathlib import Path

    env = dict(os.environ)
    root = str(Path(__file__).resolve().parents[2])
    env["PYTHONPATH"] = root + os.pathsep + env.get("PYTHONPATH", "")
    t = time.perf_counter()
    out = subprocess.run([sys.executable, "-m", "bayescal", *cmd], cwd=cwd, env=env,
                         capture_output=True, text=True, timeout=timeout)
    return out.returncode, out.stdout, out.stderr, time.perf_counter() - t


def run_chain(scenario, seed, folder, *, background=None, timeout=900):
    """Render, write the files, then ``bayescal extract`` and ``bayescal calibrate --walls``.

    ``background``: use the laser-off frame (default: when the scenario has one). Returns a
    dict: exit codes, stderr lines, the extraction's score (``score3``) and the calibrated
    identifiable parameters' errors in their sds.
    """
    from pathlib import Path

    folder = Path(folder)
    image, off, truth = render3(scenario, seed)
    img, off_path, walls = write_inputs(folder, image, off, truth)
    use_off = (off is not None) if background is None else background
    cmd = ["extract", img.name, "--along-sd", "1", "--out", "ex"]
    if use_off and off_path is not None:
        cmd[2:2] = ["--background", off_path.name]
    rc, so, se, dt = _run(cmd, folder, timeout)
    res = dict(scenario=scenario, seed=seed, background=bool(use_off and off_path),
               extract_cmd="bayescal " + " ".join(cmd), extract_rc=rc,
               extract_out=(so + se).strip(), extract_s=round(dt, 1))
    if rc != 0:
        return res
    pix, cov, fl, size = read_laser_csv(folder / "ex" / "laser.csv")
    sc = score3(pix, cov, fl, truth)
    res.update({k: v for k, v in sc.items() if k not in ("errors", "on_ring")})
    ccmd = ["calibrate", "ex/laser.csv", "--walls", walls.name, "--out", "cal"]
    rc, so, se, dt = _run(ccmd, folder, timeout)
    res.update(calibrate_cmd="bayescal " + " ".join(ccmd), calibrate_rc=rc,
               calibrate_err=se.strip()[-600:], calibrate_s=round(dt, 1))
    if rc in (0, 1) and (folder / "cal" / "result.json").exists():
        r = bc.load_result(folder / "cal" / "result.json")
        est = identifiable(r.params)
        sd = np.sqrt(np.diag(r.covariance_identifiable))
        z = (est - identifiable(truth.params)) / sd
        res["param_z"] = dict(zip(IDENT, np.round(z, 2).tolist(), strict=True))
        res["param_sd"] = dict(zip(IDENT, sd.tolist(), strict=True))
        res["max_abs_z"] = float(np.max(np.abs(z)))
    return res


def main(argv=None):
    """``python tests/image/renderer3.py OUT [--seeds 0 1 2] [--scenarios ...]``: the table."""
    import argparse
    import json
    from pathlib import Path

    ap = argparse.ArgumentParser()
    ap.add_argument("out")
    ap.add_argument("--seeds", type=int, nargs="+", default=[0, 1, 2])
    ap.add_argument("--scenarios", nargs="+", default=list(SCENARIOS))
    ap.add_argument("--no-background", action="store_true")
    a = ap.parse_args(argv)
    out = Path(a.out)
    out.mkdir(parents=True, exist_ok=True)
    with open(out / "results.jsonl", "a") as fh:
        for name in a.scenarios:
            for seed in a.seeds:
                bg = False if a.no_background else None
                tag = f"{name}_{seed}" + ("_nobg" if a.no_background else "")
                res = run_chain(name, seed, out / tag, background=bg)
                fh.write(json.dumps(res) + "\n")
                fh.flush()
                print(json.dumps({k: v for k, v in res.items()
                                  if k not in ("extract_out", "calibrate_err", "param_sd")}),
                      flush=True)


if __name__ == "__main__":
    main()
