"""Rendered frames of a moving sensor: :func:`render_sequence`.

The sensor moves through one room: each frame is :func:`~bayescal.scene.render.render_image`
of the room's walls in the sensor's frame at that time (the room translated and turned),
with the laser cone's pose drifting (a mount that vibrates). The wall texture is attached to
the walls, so it moves with them; the shot and read noise is drawn anew for every frame.
"""

from __future__ import annotations

import numpy as np

from .._validation import check_positive, resolve_rng
from ..errors import InvalidValueError
from ..sensor.pose import LaserPose
from .render import _expose, render_image

__all__ = ["render_sequence", "sensor_path"]


def sensor_path(n_frames, *, speed_mm=15.0, turn_deg=0.3, wobble_mm=20.0, tilt_deg=0.5,
                offset_mm=2.0, rng=None):
    """A smooth path of the sensor through a room: position, heading and laser pose per
    frame.

    The sensor moves along a curve at ``speed_mm`` per frame, turning by ``turn_deg`` per
    frame, with a slow sideways wobble of amplitude ``wobble_mm``; the laser cone tilts by up
    to ``tilt_deg`` and shifts by up to ``offset_mm`` about the camera's axis, slowly, each
    with a random phase.

    Parameters
    ----------
    n_frames : int
    speed_mm, turn_deg, wobble_mm, tilt_deg, offset_mm : float, optional
    rng : numpy.random.Generator, int or None, optional
        The phases.

    Returns
    -------
    position : ndarray, shape (n_frames, 2)
        The sensor's axis in the room, mm.
    heading : ndarray, shape (n_frames,)
        The turn of the sensor's frame against the room's, rad.
    laser : ndarray, shape (n_frames, 4)
        The laser cone's pose per frame (tilt_x, tilt_y rad; offset_x, offset_y mm).
    """
    n = int(n_frames)
    if n != n_frames or n < 1:
        raise InvalidValueError(f"n_frames must be a positive integer, got {n_frames!r}")
    rng = resolve_rng(rng)
    t = np.arange(n, dtype=float)
    ph = rng.uniform(0, 2 * np.pi, 5)
    heading = np.radians(turn_deg) * t
    along = speed_mm * t
    side = wobble_mm * np.sin(2 * np.pi * t / 40.0 + ph[0])
    position = np.stack([along * np.cos(0.5 * heading) - side * np.sin(0.5 * heading),
                         along * np.sin(0.5 * heading) + side * np.cos(0.5 * heading)], -1)
    tilt = np.radians(tilt_deg) * np.stack([np.sin(2 * np.pi * t / 25.0 + ph[1]),
                                           np.sin(2 * np.pi * t / 31.0 + ph[2])], -1)
    offset = offset_mm * np.stack([np.sin(2 * np.pi * t / 37.0 + ph[3]),
                                   np.sin(2 * np.pi * t / 29.0 + ph[4])], -1)
    return position - position[0], heading, np.concatenate([tilt, offset], axis=1)


def render_sequence(params, room, n_frames, *, shape=(600, 800), full_well=20000.0,
                    read_noise=10.0, bits=8, rng=None, path=None, **options):
    """Render the frames of a sensor moving through a room.

    Parameters
    ----------
    params : SensorParams or ndarray, shape (8,)
        The true sensor (the camera stays the same; the laser's pose drifts).
    room : ndarray, shape (W, 2, 2)
        The room's walls at the first frame, mm (e.g. :func:`bayescal.room_walls`).
    n_frames : int
    shape : tuple of int, optional
        ``(height, width)`` px.
    full_well, read_noise, bits : optional
        The sensor's noise and depth (as :func:`~bayescal.scene.render.render_image`).
    rng : numpy.random.Generator, int or None, optional
        The room's texture, the path's phases and every frame's noise.
    path : tuple, optional
        ``(position (n, 2) mm, heading (n,) rad, laser (n, 4))`` as :func:`sensor_path`
        returns; default ``sensor_path(n_frames, rng=rng)``.
    **options
        More options of :func:`~bayescal.scene.render.render_image` (``texture``,
        ``n_lamps``, ``ghost``, ``laser_power``, ``psf_px``, ...); not ``with_background``.

    Yields
    ------
    image : ndarray of uint8 or uint16, shape (H, W)
    truth : RenderTruth
        The frame's true centre line (``truth.points`` in the sensor's frame at that time).

    Examples
    --------
    >>> import bayescal as bc
    >>> frames = list(bc.render_sequence(bc.SensorParams.paper(), bc.room_walls(2500), 2,
    ...                                  shape=(120, 160), rng=0))
    >>> len(frames), frames[0][0].shape
    (2, (120, 160))
    """
    if options.get("with_background"):
        raise InvalidValueError("render_sequence renders no laser-off frames "
                                "(with_background must be False)")
    options.pop("with_background", None)
    check_positive(full_well, "full_well")
    check_positive(read_noise, "read_noise", allow_zero=True)
    if bits not in (8, 16):
        raise InvalidValueError(f"bits must be 8 or 16, got {bits!r}")
    rng = resolve_rng(rng)
    texture_seed = int(rng.integers(2 ** 31))
    position, heading, laser = sensor_path(n_frames, rng=rng) if path is None else path
    walls = np.asarray(room, dtype=float)
    for t in range(len(position)):
        c, s = np.cos(heading[t]), np.sin(heading[t])
        turn = np.array([[c, s], [-s, c]])          # room -> the sensor's frame at t
        walls_t = (walls - position[t]) @ turn.T
        # noise-free (a well of 2^40 electrons, 16 bit), then this frame's own noise: the
        # same seed renders the same texture on the walls in every frame
        clean, truth = render_image(params, walls_t, shape=shape, full_well=2.0 ** 40,
                                    read_noise=0.0, bits=16, rng=texture_seed,
                                    laser=LaserPose.from_array(laser[t]), **options)
        signal = clean.astype(float) / 65535.0
        yield _expose(signal, rng, full_well=full_well, read_noise=read_noise, bits=bits), truth
