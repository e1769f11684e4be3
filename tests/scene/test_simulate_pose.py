"""simulate_room with a misaligned laser cone (tilt and offset)."""

import numpy as np
import pytest

import bayescal as bc


def test_zero_pose_is_todays_dataset():
    a = bc.simulate_room(range_mm=2500, n_points=120, sigma_px=0.2, approx_error=0.03, rng=7)
    b = bc.simulate_room(range_mm=2500, n_points=120, sigma_px=0.2, approx_error=0.03, rng=7,
                         tilt=(0.0, 0.0), offset=(0, 0))
    for name in ("pixels", "pixels_true", "points", "approx_points", "sigma_scene"):
        np.testing.assert_array_equal(getattr(a, name), getattr(b, name))
    np.testing.assert_array_equal(a.calibration.laser_pixels, b.calibration.laser_pixels)
    assert b.laser == bc.LaserPose()


def test_tilted_room_lies_on_the_tilted_cone_and_the_walls():
    tilt, offset = (np.radians(1.0), np.radians(0.5)), (5.0, -5.0)
    p = bc.SensorParams.paper()
    ds = bc.simulate_room(p, range_mm=2500, n_points=300, n_walls=6, sigma_px=0.0, rng=3,
                          tilt=tilt, offset=offset)
    assert ds.laser.to_array().tolist() == [*tilt, *offset]
    lp = bc.LaserPose(*tilt, *offset, h=p.h)
    Q = (ds.points - lp.apex) @ lp.rotation
    np.testing.assert_allclose(np.hypot(Q[:, 0], Q[:, 1]), Q[:, 2] * np.tan(p.beta), rtol=1e-10)
    # same horizontal positions (on the walls) as the aligned room, z moved by the tilt
    aligned = bc.simulate_room(p, range_mm=2500, n_points=300, n_walls=6, sigma_px=0.0, rng=3)
    np.testing.assert_array_equal(ds.points[:, :2], aligned.points[:, :2])
    dz = ds.points[:, 2] - aligned.points[:, 2]
    assert 10.0 < np.ptp(dz) < 200.0      # ~2 x 1.1 deg x ~2000 mm: tens of mm around the room
    # the pixels triangulate back with the true pose, not with the aligned cone
    np.testing.assert_allclose(bc.triangulate(p, ds.pixels, laser=ds.laser), ds.points,
                               rtol=1e-8)
    assert np.abs(bc.triangulate(p, ds.pixels) - ds.points).max() > 10.0
    # the calibration planes' laser curve lies on the same tilted cone
    Qc = (ds.calibration.laser_points_true - lp.apex) @ lp.rotation
    np.testing.assert_allclose(np.hypot(Qc[:, 0], Qc[:, 1]), Qc[:, 2] * np.tan(p.beta),
                               rtol=1e-10)


@pytest.mark.parametrize("kw, match", [
    ({"tilt": (0.1,)}, "tilt must be a finite pair"),
    ({"offset": (np.nan, 0.0)}, "offset must be a finite pair"),
    ({"tilt": (1.0, 0.0)}, "tilt must be below pi/4"),
    ({"tilt": ("a", 0.0)}, "tilt must be a pair of numbers"),
])
def test_bad_pose_arguments_are_refused(kw, match):
    with pytest.raises((ValueError, TypeError), match=match):
        bc.simulate_room(range_mm=1000, n_points=20, rng=1, **kw)
