"""Rendered images of the laser ring: the ground truth of the image pipeline.

:func:`render_image` traces every pixel back through the unified model to the
room (vertical walls, a floor, a ceiling), lights the surface with ambient light
and the laser cone, and adds lamps, a specular ghost of the ring, the lens
point-spread function, shot and read noise and quantisation. The physics is in
``docs/images.md``.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.ndimage import gaussian_filter

from .._validation import check_positive, resolve_rng
from ..errors import InvalidValueError
from ..sensor.camera import backproject, project
from ..sensor.laser import cone_point
from ..sensor.parameters import SensorParams, as_param_array
from ..sensor.pose import LaserPose, as_pose_array, pose_rotation
from .simulate import _ray_polygon_distance

__all__ = ["RenderTruth", "render_image"]


@dataclass(frozen=True)
class RenderTruth:
    """What a rendered image shows, exactly.

    Attributes
    ----------
    pixels : ndarray, shape (M, 2)
        The laser centre line in the image, px, one point per azimuth in
        ``azimuth`` (the projection of the cone's centre on the walls).
    points : ndarray, shape (M, 3)
        The same points in frame C, mm.
    azimuth : ndarray, shape (M,)
        Azimuth of each point around the sensor axis, rad.
    background : ndarray or None, shape (H, W)
        The laser-off image (same exposure, independent noise), or None.
    """

    pixels: np.ndarray
    points: np.ndarray
    azimuth: np.ndarray
    background: np.ndarray | None = None


def _surface(rays, walls, floor_z, ceiling_z):
    """Distance along each ray to the room, and texture coordinates (s, z) mm."""
    horiz = np.hypot(rays[:, 0], rays[:, 1])
    az = np.arctan2(rays[:, 1], rays[:, 0])
    rho, wall = _ray_polygon_distance(az, walls)
    with np.errstate(divide="ignore", invalid="ignore"):
        t = rho / horiz
        z = t * rays[:, 2]
        t = np.where(z > ceiling_z, ceiling_z / rays[:, 2], t)
        t = np.where(z < floor_z, floor_z / rays[:, 2], t)
    P = t[:, None] * rays
    a = walls[wall, 0]
    s = np.hypot(P[:, 0] - a[:, 0], P[:, 1] - a[:, 1]) + 3000.0 * wall
    on_wall = np.isclose(np.hypot(P[:, 0], P[:, 1]), rho)
    s = np.where(on_wall, s, P[:, 0])
    tz = np.where(on_wall, P[:, 2], P[:, 1])
    return P, s, tz


def _albedo(s, tz, texture, rng):
    """Smooth patterns plus rectangular posters (sharp edges), albedo in (0.05, 1)."""
    alb = np.full(s.shape, 0.45)
    for scale in (900.0, 300.0, 90.0, 30.0):
        k = rng.normal(size=2) / scale * 2 * np.pi
        alb += texture * 0.35 * np.sin(k[0] * s + k[1] * tz + rng.uniform(0, 2 * np.pi))
    for _ in range(int(60 * texture)):
        c = rng.uniform([0.0, -1500.0], [20000.0, 3000.0])
        size = rng.uniform(50.0, 600.0, 2)
        inside = (np.abs(s - c[0]) < size[0]) & (np.abs(tz - c[1]) < size[1])
        alb = np.where(inside, alb + rng.uniform(-0.3, 0.3), alb)
    return np.clip(alb, 0.05, 1.0)


def _beam(P, params, pose):
    """Laser irradiance per unit power: Gaussian in the angle off the cone, 1/d^2.

    The angle is taken from the cone's apex ``(offset_x, offset_y, -h)`` against its axis
    (``docs/conventions.md``); the zero pose is the paper's cone."""
    d = P - np.array([pose[2], pose[3], -params.h])
    axis = pose_rotation(pose)[:, 2]
    along = d @ axis
    across = np.linalg.norm(d - along[:, None] * axis, axis=1)
    off = np.arctan2(across, along) - params.beta
    return off, 1e6 / np.sum(d * d, axis=1)


def _ring_truth(params, walls, n, pose):
    az = np.linspace(-np.pi, np.pi, n, endpoint=False)
    rho, _ = _ray_polygon_distance(az, walls)
    xy = np.stack([rho * np.cos(az), rho * np.sin(az)], axis=-1)
    pts = cone_point(params, xy, laser=LaserPose.from_array(pose))
    return az, pts, project(params, pts)


def _lamps(shape, params, walls, n_lamps, rng):
    """Bright blobs (px) where lamps hang on the walls, above and below the ring."""
    img = np.zeros(shape)
    if n_lamps == 0:
        return img
    az = rng.uniform(-np.pi, np.pi, n_lamps)
    rho, _ = _ray_polygon_distance(az, walls)
    ring_z = rho / np.tan(params.beta) - params.h
    z = ring_z + rng.choice([-1.0, 1.0], n_lamps) * rng.uniform(0.05, 0.3, n_lamps) * rho
    uv = project(params, np.stack([0.98 * rho * np.cos(az), 0.98 * rho * np.sin(az), z], -1))
    yy, xx = np.mgrid[0:shape[0], 0:shape[1]]
    for (u, v), w in zip(uv, rng.uniform(1.0, 3.0, n_lamps), strict=True):
        if np.isfinite(u):
            img += np.exp(-0.5 * ((xx - u) ** 2 + (yy - v) ** 2) / w ** 2)
    return img


def _expose(signal, rng, *, full_well, read_noise, bits):
    """Shot (Poisson, electrons) and read noise, saturation, quantisation."""
    electrons = rng.poisson(np.clip(signal, 0, None) * full_well).astype(float)
    electrons += rng.normal(0.0, read_noise, signal.shape)
    levels = 2 ** bits - 1
    dn = np.clip(np.rint(electrons / full_well * levels), 0, levels)
    return dn.astype(np.uint8 if bits == 8 else np.uint16)


def _check_render_args(params, walls, shape, bits):
    params = SensorParams.from_array(as_param_array(params))
    walls = np.asarray(walls, dtype=float)
    if walls.ndim != 3 or walls.shape[1:] != (2, 2):
        raise InvalidValueError(
            f"room must be wall segments of shape (W, 2, 2) mm, got {walls.shape}")
    if len(shape) != 2 or min(shape) < 16:
        raise InvalidValueError(f"shape must be (height, width) >= 16 px, got {shape!r}")
    if bits not in (8, 16):
        raise InvalidValueError(f"bits must be 8 or 16, got {bits!r}")
    return params, walls


def render_image(params, room, *, shape=(600, 800), floor_z=-1500.0, ceiling_z=None,
                 beam_deg=0.12, psf_px=0.8, laser_power=12.0, ambient=0.15, texture=1.0,
                 n_lamps=0, ghost=0.0, ghost_deg=4.0, full_well=20000.0, read_noise=10.0, bits=8,
                 fov_deg=(-50.0, 65.0), with_background=False, n_truth=3600, rng=None,
                 laser=None):
    """Render the camera image of the laser ring in a room.

    Parameters
    ----------
    params : SensorParams or ndarray, shape (8,)
        The true sensor.
    room : ndarray, shape (W, 2, 2)
        Vertical walls as horizontal segments ``[(x0, y0), (x1, y1)]`` in mm around
        the axis (e.g. :func:`bayescal.room_walls`).
    shape : tuple of int, optional
        ``(height, width)`` of the image, px.
    floor_z, ceiling_z : float, optional
        Heights of the floor and ceiling in frame C, mm; the default ceiling lies
        500 mm above the highest point of the ring.
    beam_deg : float, optional
        Standard deviation of the laser sheet's angular thickness, deg.
    psf_px : float, optional
        Standard deviation of the Gaussian point-spread function, px.
    laser_power : float, optional
        Peak laser irradiance, in units of the full well, at 1000 mm on a white wall.
    ambient : float, optional
        Ambient light on a white wall, in units of the full well.
    texture : float, optional
        Contrast of the wall texture (0: plain walls; 1: patterns and posters).
    n_lamps : int, optional
        Lamps on the walls near the ring (saturating blobs).
    ghost : float, optional
        Relative brightness of a specular ghost: a partial second ring over about
        a quarter of the azimuths.
    ghost_deg : float, optional
        Angle of the ghost off the cone, deg (4 deg is about 6 px in the paper's
        sensor; within 2 deg the ghost merges with the stripe).
    full_well : float, optional
        Electrons at saturation (shot noise: Poisson in electrons).
    read_noise : float, optional
        Read noise, electrons rms.
    bits : {8, 16}, optional
        Depth of the output image.
    fov_deg : tuple of float, optional
        Elevations (deg) seen through the mirror; outside, the image is black.
    with_background : bool, optional
        Also render the laser-off image (``truth.background``).
    n_truth : int, optional
        Number of azimuths of the true centre line.
    rng : numpy.random.Generator, int or None, optional
        Texture, lamps and noise.
    laser : LaserPose or array_like, shape (4,), optional
        Tilt and offset of the laser cone (``docs/conventions.md``); default the
        paper's cone, coaxial with the camera.

    Returns
    -------
    image : ndarray of uint8 or uint16, shape (H, W)
    truth : RenderTruth
        The true centre line (pixels, 3D points, azimuths) and the laser-off image.

    Examples
    --------
    >>> import bayescal as bc
    >>> img, truth = bc.render_image(bc.SensorParams.paper(), bc.room_walls(2500), rng=0)
    >>> img.shape, truth.pixels.shape[1]
    ((600, 800), 2)
    """
    params, walls = _check_render_args(params, room, tuple(shape), bits)
    for name, val in (("beam_deg", beam_deg), ("full_well", full_well)):
        check_positive(val, name)
    for name, val in (("psf_px", psf_px), ("read_noise", read_noise), ("ghost", ghost)):
        check_positive(val, name, allow_zero=True)
    rng = resolve_rng(rng)
    pose = np.zeros(4) if laser is None else as_pose_array(laser, "laser")
    if pose.shape != (4,):
        raise InvalidValueError(f"laser must be one pose (4,), got shape {pose.shape}")
    az, pts, uv_true = _ring_truth(params, walls, int(n_truth), pose)
    ok = np.all(np.isfinite(uv_true), axis=1)
    az, pts, uv_true = az[ok], pts[ok], uv_true[ok]
    if ceiling_z is None:
        ceiling_z = float(np.max(pts[:, 2])) + 500.0
    H, W = shape
    yy, xx = np.mgrid[0:H, 0:W]
    pix = np.stack([xx.ravel(), yy.ravel()], axis=-1).astype(float)
    rays = backproject(params, pix)
    elev = np.degrees(np.arcsin(np.clip(rays[:, 2], -1, 1)))
    seen = np.isfinite(elev) & (elev > fov_deg[0]) & (elev < fov_deg[1])
    P, s, tz = _surface(np.where(seen[:, None], rays, [1.0, 0.0, 0.0]), walls, floor_z, ceiling_z)
    alb = _albedo(s, tz, texture, rng)
    off, fall = _beam(P, params, pose)
    # pixel footprint: the beam integrated over a pixel (box of variance 1/12 px^2)
    off_img = off.reshape(H, W)
    gy, gx = np.gradient(off_img)
    sd = np.deg2rad(beam_deg)
    var = sd ** 2 + (gx ** 2 + gy ** 2).ravel() / 12.0
    beam = sd / np.sqrt(var) * np.exp(-0.5 * off ** 2 / var)
    if ghost > 0:
        goff = off - np.deg2rad(ghost_deg)
        sector = np.cos(np.arctan2(P[:, 1], P[:, 0]) - rng.uniform(-np.pi, np.pi)) > 0.7
        beam = beam + ghost * sector * sd / np.sqrt(var) * np.exp(-0.5 * goff ** 2 / var)
    base = (ambient * alb * seen).reshape(H, W)
    laser = (laser_power * alb * fall * beam * seen).reshape(H, W)
    lamps = 3.0 * _lamps((H, W), params, walls, int(n_lamps), rng)
    blur = (lambda a: gaussian_filter(a, psf_px)) if psf_px > 0 else (lambda a: a)
    kw = dict(full_well=full_well, read_noise=read_noise, bits=bits)
    image = _expose(blur(base + laser + lamps), rng, **kw)
    background = _expose(blur(base + lamps), rng, **kw) if with_background else None
    return image, RenderTruth(pixels=uv_true, points=pts, azimuth=az, background=background)
