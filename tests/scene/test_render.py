"""The renderer: its centre line is the model's, its laser is where the truth says."""

import numpy as np
import pytest

import bayescal as bc


def test_truth_is_the_model_projection_of_the_cone_on_the_walls():
    p = bc.SensorParams.paper()
    img, truth = bc.render_image(p, bc.room_walls(2500), rng=0, n_truth=360)
    assert img.shape == (600, 800) and img.dtype == np.uint8
    # the truth points lie on the laser cone and on the walls, and project to truth.pixels
    rho = np.hypot(truth.points[:, 0], truth.points[:, 1])
    np.testing.assert_allclose(truth.points[:, 2], rho / np.tan(p.beta) - p.h, atol=1e-9)
    np.testing.assert_allclose(bc.project(p, truth.points), truth.pixels, atol=1e-9)
    np.testing.assert_allclose(bc.pixel_azimuth(p, truth.pixels), truth.azimuth, atol=1e-9)


def test_the_ring_is_the_brightest_line_along_each_radius():
    # noise-free, plain walls: on a radial line through a truth pixel, the brightest
    # pixel is within one pixel of it (beam sd 0.18 px in the image, PSF 0.8 px)
    p = bc.SensorParams.paper()
    img, truth = bc.render_image(p, bc.room_walls(1000), rng=0, texture=0.0, full_well=1e9,
                                 read_noise=0.0, bits=16, n_truth=72, laser_power=1.0)
    c = np.array([p.u0, p.v0])
    for uv in truth.pixels:
        d = (uv - c) / np.linalg.norm(uv - c)
        r = np.linalg.norm(uv - c) + np.arange(-6, 7)
        q = np.rint(c + r[:, None] * d).astype(int)
        k = np.argmax(img[q[:, 1], q[:, 0]])
        assert abs(r[k] - np.linalg.norm(uv - c)) <= 1.0


def test_seeded_16_bit_and_laser_off():
    p = bc.SensorParams.paper()
    a, ta = bc.render_image(p, bc.room_walls(2000), rng=3, bits=16, with_background=True,
                            n_lamps=2, ghost=0.3)
    b, _ = bc.render_image(p, bc.room_walls(2000), rng=3, bits=16, with_background=True,
                           n_lamps=2, ghost=0.3)
    assert a.dtype == np.uint16 and np.array_equal(a, b)
    # the laser adds light: on the truth pixels the laser-on image is brighter
    q = np.rint(ta.pixels).astype(int)
    assert np.median(a[q[:, 1], q[:, 0]].astype(float) - ta.background[q[:, 1], q[:, 0]]) > 0


@pytest.mark.parametrize("kw, match", [(dict(bits=12), "bits"), (dict(shape=(4, 4)), "shape"),
                                       (dict(beam_deg=-1), "beam_deg")])
def test_bad_arguments(kw, match):
    with pytest.raises(ValueError, match=match):
        bc.render_image(bc.SensorParams.paper(), bc.room_walls(1000), **kw)


def test_bad_room():
    with pytest.raises(ValueError, match="room"):
        bc.render_image(bc.SensorParams.paper(), np.zeros((3, 2)))


def test_render_a_tilted_cone():
    """laser=: the ring is drawn on the tilted, offset cone (its true centre line, and the
    extracted stripe, on that cone, about 1.6 px off the aligned one here)."""
    p = bc.SensorParams.paper()
    pose = bc.LaserPose(np.radians(1.0), np.radians(0.5), 5.0, -5.0, h=p.h)
    img0, t0 = bc.render_image(p, bc.room_walls(2500), rng=0)
    img1, t1 = bc.render_image(p, bc.room_walls(2500), rng=0, laser=pose)
    np.testing.assert_allclose(t1.points, bc.cone_point(p, t1.points[:, :2], laser=pose))
    lp = bc.extract_laser(img1)
    good = lp.pixels[~lp.flagged]

    def to(truth):
        return np.median(np.min(np.linalg.norm(good[:, None] - truth.pixels[None], axis=-1), 1))
    assert to(t1) < 0.3 < 1.0 < to(t0)
    img_zero, _ = bc.render_image(p, bc.room_walls(2500), rng=0, laser=np.zeros(4))
    np.testing.assert_array_equal(img_zero, img0)
