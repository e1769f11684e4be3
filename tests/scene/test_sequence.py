"""Rendered frames of a moving sensor (bc.render_sequence)."""

import numpy as np
import pytest

import bayescal as bc
from bayescal.errors import InvalidValueError
from bayescal.scene.sequence import sensor_path

P = bc.SensorParams(**{**bc.SensorParams.paper().as_dict(), "alpha_u": 30.0,
                       "alpha_v": -30.0, "u0": 80.0, "v0": 60.0})


def test_frames_move_smoothly_and_keep_their_texture():
    out = list(bc.render_sequence(P, bc.room_walls(2500), 3, shape=(120, 160), rng=2))
    assert len(out) == 3
    (a, ta), (b, tb), _ = out
    assert a.shape == (120, 160) and a.dtype == np.uint8
    # the true ring moves by a fraction of a pixel per frame at the default speed
    step = np.median(np.hypot(*(tb.pixels - ta.pixels).T))
    assert 0.01 < step < 2.0
    # a still sensor: the same scene, the noise drawn anew
    still = (np.zeros((2, 2)), np.zeros(2), np.zeros((2, 4)))
    (c, _), (d, _) = bc.render_sequence(P, bc.room_walls(2500), 2, shape=(120, 160), rng=3,
                                        path=still)
    diff = c.astype(float) - d.astype(float)
    assert np.any(diff != 0) and abs(diff.mean()) < 0.2


def test_same_seed_same_frames():
    kw = dict(shape=(60, 80), rng=5)
    a = [im for im, _ in bc.render_sequence(P, bc.room_walls(2500), 2, **kw)]
    b = [im for im, _ in bc.render_sequence(P, bc.room_walls(2500), 2, **kw)]
    np.testing.assert_array_equal(a, b)


def test_sensor_path_is_smooth():
    pos, heading, laser = sensor_path(50, speed_mm=10.0, rng=0)
    assert pos.shape == (50, 2) and heading.shape == (50,) and laser.shape == (50, 4)
    np.testing.assert_array_equal(pos[0], 0.0)
    assert np.max(np.hypot(*np.diff(pos, axis=0).T)) < 20.0
    assert np.max(np.abs(np.degrees(laser[:, :2]))) <= 0.5 + 1e-12


@pytest.mark.parametrize("kw, match", [(dict(with_background=True), "laser-off"),
                                       (dict(bits=12), "bits")])
def test_bad_options(kw, match):
    with pytest.raises(InvalidValueError, match=match):
        next(bc.render_sequence(P, bc.room_walls(2500), 2, shape=(60, 80), **kw))
