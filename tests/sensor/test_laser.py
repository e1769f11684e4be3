"""Laser cone (eq. 3), image azimuth (eqs. 4-5), triangulation and the plane case (eq. 2)."""

import numpy as np
import pytest

import bayescal as bc
from bayescal.sensor.laser import cone_distance, cone_point_theta, triangulate_theta
from bayescal.sensor.parameters import to_identifiable


def _cone_xy(rng, n, lo=300.0, hi=6000.0):
    az = rng.uniform(0, 2 * np.pi, n)
    rho = rng.uniform(lo, hi, n)
    return rho[:, None] * np.column_stack([np.cos(az), np.sin(az)])


def test_cone_point_is_on_the_cone(sensor, rng):
    xy = _cone_xy(rng, 100)
    pts = bc.cone_point(sensor, xy)
    np.testing.assert_array_equal(pts[:, :2], xy)
    np.testing.assert_allclose(cone_distance(sensor.h, sensor.beta, pts), 0.0, atol=1e-9)
    # eq. (3): x = (z + h) tan(beta) cos(alpha), y = (z + h) tan(beta) sin(alpha)
    az = np.arctan2(xy[:, 1], xy[:, 0])
    rho = (pts[:, 2] + sensor.h) * np.tan(sensor.beta)
    np.testing.assert_allclose(pts[:, :2], rho[:, None] * np.column_stack(
        [np.cos(az), np.sin(az)]), rtol=1e-12)


def test_project_triangulate_round_trip(sensor, rng):
    pts = bc.cone_point(sensor, _cone_xy(rng, 300))
    pix, valid = bc.project(sensor, pts, return_valid=True)
    assert valid.all()
    back, valid = bc.triangulate(sensor, pix, return_valid=True)
    assert valid.all()
    np.testing.assert_allclose(back, pts, rtol=1e-9)


def test_pixel_azimuth_is_the_cone_azimuth(sensor, rng):
    """Eqs. (4)-(5): the pixel's azimuth about (u0, v0), scaled by alpha, is the point's."""
    xy = _cone_xy(rng, 100)
    pix = bc.project(sensor, bc.cone_point(sensor, xy))
    az = bc.pixel_azimuth(sensor, pix)
    diff = np.angle(np.exp(1j * (az - np.arctan2(xy[:, 1], xy[:, 0]))))
    np.testing.assert_allclose(diff, 0.0, atol=1e-12)


def test_triangulate_ray_that_misses_the_cone(sensor):
    """Rays upward within beta of the vertical never meet the cone: NaN and invalid."""
    checked = 0
    for angle in (0.3 * sensor.beta, 0.95 * sensor.beta):
        if np.cos(angle) >= sensor.xi:       # not even projectable for this xi
            continue
        checked += 1
        direction = [np.sin(angle), 0.0, np.cos(angle)]
        pix = bc.project(sensor, 1000.0 * np.array(direction))
        pts, valid = bc.triangulate(sensor, pix, return_valid=True)
        assert not valid and np.isnan(pts).all()
    assert checked >= 1
    # just outside: 1.05 beta from the vertical meets it far away
    angle = min(1.05 * sensor.beta, 0.5 * (sensor.beta + np.pi / 2))
    pix = bc.project(sensor, [np.sin(angle), 0.0, np.cos(angle)])
    pts, valid = bc.triangulate(sensor, pix, return_valid=True)
    assert valid and np.isfinite(pts).all()


def test_triangulate_principal_point_is_invalid(sensor):
    """The principal point looks straight down, (0, 0, -1); that ray meets the cone only at
    its apex (0, 0, -h), which is not on the lit nappe (z > -h): NaN and invalid."""
    pts, valid = bc.triangulate(sensor, [sensor.u0, sensor.v0], return_valid=True)
    assert not bool(valid)
    assert np.isnan(pts).all()


# ---------------------------------------------------------------- Jacobians

THETA_STEP = np.array([1e-6, 1e-4, 1e-4, 1e-4, 1e-4, 1e-4, 1e-7])


@pytest.mark.parametrize("lo, hi", [(300.0, 1200.0), (1200.0, 6000.0)])
def test_triangulate_theta_jacobians(sensor, rng, numdiff, lo, hi):
    theta = sensor.to_identifiable()
    pix = bc.project(sensor, bc.cone_point(sensor, _cone_xy(rng, 30, lo, hi)))
    pts, valid, dpix, dth = triangulate_theta(theta, pix, jacobian=True)
    assert valid.all() and dpix.shape == (30, 3, 2) and dth.shape == (30, 3, 7)
    dpix_fd = numdiff(lambda x: triangulate_theta(theta, x)[0], pix, 1e-6)
    dth_fd = numdiff(lambda t: triangulate_theta(t, pix)[0], theta, 0.01 * THETA_STEP)
    np.testing.assert_allclose(dpix, dpix_fd, rtol=1e-5, atol=1e-6 * np.abs(dpix_fd).max())
    np.testing.assert_allclose(dth, dth_fd, rtol=1e-5, atol=1e-6 * np.abs(dth_fd).max())


def test_cone_point_theta_jacobians(sensor, rng, numdiff):
    theta = sensor.to_identifiable()
    xy = _cone_xy(rng, 30)
    pts, dxy, dth = cone_point_theta(theta, xy, jacobian=True)
    assert dxy.shape == (30, 3, 2) and dth.shape == (30, 3, 7)
    dxy_fd = numdiff(lambda q: cone_point_theta(theta, q), xy, 1e-3)
    dth_fd = numdiff(lambda t: cone_point_theta(t, xy), theta, THETA_STEP)
    np.testing.assert_allclose(dxy, dxy_fd, rtol=1e-7, atol=1e-9)
    np.testing.assert_allclose(dth, dth_fd, rtol=1e-7, atol=1e-7 * np.abs(dth_fd).max())


# ---------------------------------------------------------------- broadcasting

def test_triangulate_broadcasts_over_walkers(rng):
    p = bc.SensorParams.paper()
    a = np.tile(p.to_array(), (5, 1))
    a[:, 6] += rng.normal(0.0, 5.0, 5)
    a[:, 7] += rng.normal(0.0, 0.01, 5)
    pix = bc.project(p, bc.cone_point(p, _cone_xy(rng, 11)))
    pts, valid = bc.triangulate(a[:, None, :], pix, return_valid=True)
    assert pts.shape == (5, 11, 3) and valid.shape == (5, 11)
    for w in range(5):
        np.testing.assert_allclose(pts[w], bc.triangulate(a[w], pix), rtol=1e-15)
    out = triangulate_theta(to_identifiable(a)[:, None, :], pix, jacobian=True)
    assert [o.shape for o in out] == [(5, 11, 3), (5, 11), (5, 11, 3, 2), (5, 11, 3, 7)]
    assert bc.cone_point(a[:, None, :], _cone_xy(rng, 11)).shape == (5, 11, 3)
    assert bc.triangulate(p, pix[0]).shape == (3,)
    assert bc.pixel_azimuth(a[:, None, :], pix).shape == (5, 11)


# ---------------------------------------------------------------- plane (eq. 2)

def test_triangulate_plane(sensor, rng):
    # the wall x = 1500 mm: plane (1, 0, 0, -1500)
    yz = rng.uniform(-1000.0, 1000.0, (20, 2))
    wall = np.column_stack([np.full(20, 1500.0), yz])
    pix = bc.project(sensor, wall)
    pts, valid = bc.triangulate_plane(sensor, pix, [1.0, 0.0, 0.0, -1500.0], return_valid=True)
    assert valid.all()
    np.testing.assert_allclose(pts, wall, rtol=1e-9)
    # the same pixels meet the wall x = -1500 behind the focus: NaN
    pts, valid = bc.triangulate_plane(sensor, pix, [1.0, 0.0, 0.0, 1500.0], return_valid=True)
    assert not valid.any() and np.isnan(pts).all()


def test_triangulate_plane_parallel_ray_gives_nan():
    p = bc.SensorParams.paper()
    # principal point: ray (0, 0, -1) exactly, parallel to the wall x = 1000
    pts, valid = bc.triangulate_plane(p, [p.u0, p.v0], [1.0, 0.0, 0.0, -1000.0],
                                      return_valid=True)
    assert not valid and np.isnan(pts).all()
    # (1000, 0, 0) images on a horizontal ray (1, 0, 0) for xi = 1: parallel to the floor
    pix = bc.project(p, [1000.0, 0.0, 0.0])
    np.testing.assert_array_equal(bc.backproject(p, pix), [1.0, 0.0, 0.0])
    pts, valid = bc.triangulate_plane(p, pix, [0.0, 0.0, 1.0, 500.0], return_valid=True)
    assert not valid and np.isnan(pts).all()


# ---------------------------------------------------------------- bad input

def test_laser_bad_input_names_the_argument():
    p = bc.SensorParams.paper()
    with pytest.raises(ValueError, match=r"pixels must have shape \(\.\.\., 2\), got shape \(3,\)"):
        bc.triangulate(p, [1.0, 2.0, 3.0])
    with pytest.raises(ValueError, match=r"pixels must contain only finite values"):
        bc.triangulate(p, [[np.inf, 2.0]])
    with pytest.raises(ValueError, match=r"xy must have shape \(\.\.\., 2\), got shape \(2, 3\)"):
        bc.cone_point(p, np.zeros((2, 3)))
    with pytest.raises(ValueError, match=r"plane must have shape \(\.\.\., 4\), got shape \(3,\)"):
        bc.triangulate_plane(p, [400.0, 300.0], [1.0, 0.0, 0.0])
    with pytest.raises(ValueError, match=r"plane normal \(a, b, c\) must be non-zero"):
        bc.triangulate_plane(p, [400.0, 300.0], [0.0, 0.0, 0.0, 1.0])
    with pytest.raises(ValueError, match=r"points must have shape \(\.\.\., 3\)"):
        cone_distance(200.0, 1.0, np.zeros((4, 2)))
