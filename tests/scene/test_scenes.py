"""Synthetic rooms: reproducibility, noise-free data, approximation models, calibration."""

import numpy as np
import pytest

import bayescal as bc
from bayescal.scene.simulate import rotation_matrix
from bayescal.sensor.laser import cone_distance

CALIB_NORMALS_W = np.array([[1.0, 0, 0], [0, 1.0, 0], [-1.0, 0, 0], [0, -1.0, 0]])


def _arrays(ds):
    c = ds.calibration
    return [ds.pixels, ds.pixels_true, ds.points, ds.approx_points, ds.sigma_scene, ds.walls,
            c.grid_points, c.grid_pixels, c.laser_pixels]


def test_same_seed_same_dataset_different_seed_differs():
    kw = dict(range_mm=3000, n_points=120, sigma_px=0.3, approx_error=0.05, sigma_3d=2.0)
    a = bc.simulate_room(rng=7, **kw)
    b = bc.simulate_room(rng=np.random.default_rng(7), **kw)
    c = bc.simulate_room(rng=8, **kw)
    for x, y in zip(_arrays(a), _arrays(b), strict=True):
        np.testing.assert_array_equal(x, y)
    for i in (0, 3, 7, 8):                            # the noisy arrays
        assert not np.allclose(_arrays(a)[i], _arrays(c)[i])
    np.testing.assert_array_equal(a.points, c.points)  # the scene itself is fixed


@pytest.mark.parametrize("range_mm", [1000.0, 5000.0])
def test_noise_free_pixels_are_projections(sensor, range_mm):
    ds = bc.simulate_room(sensor, range_mm=range_mm, n_points=200, sigma_px=0.0, rng=0)
    assert ds.n_points == 200 and ds.pixels.shape == (200, 2)
    np.testing.assert_allclose(ds.pixels, bc.project(sensor, ds.points), rtol=1e-14)
    np.testing.assert_array_equal(ds.pixels, ds.pixels_true)
    np.testing.assert_allclose(cone_distance(sensor.h, sensor.beta, ds.points), 0.0, atol=1e-9)


def test_noisy_pixels_have_the_stated_noise():
    sigma = 0.4
    ds = bc.simulate_room(range_mm=2000, n_points=2000, sigma_px=sigma, rng=3)
    r = (ds.pixels - ds.pixels_true).ravel() / sigma
    # sample sd of n = 4000 N(0, 1) draws: sd(s) ~ 1/sqrt(2n) = 0.0112; 5 sd -> 0.056
    # (two-sided false-failure rate 6e-7); the mean: sd 1/sqrt(n) = 0.0158, 5 sd -> 0.079
    assert abs(r.std(ddof=1) - 1.0) < 5 / np.sqrt(2 * r.size)
    assert abs(r.mean()) < 5 / np.sqrt(r.size)


def test_laser_points_lie_on_the_walls():
    ds = bc.simulate_room(range_mm=4000, n_points=300, rng=0)
    a, b = ds.walls[:, 0], ds.walls[:, 1]              # (W, 2)
    q = ds.points[:, None, :2]                         # (N, 1, 2)
    e = b - a
    s = np.clip(np.sum((q - a) * e, axis=-1) / np.sum(e * e, axis=-1), 0.0, 1.0)
    dist = np.linalg.norm(q - (a + s[..., None] * e), axis=-1).min(axis=1)
    np.testing.assert_allclose(dist, 0.0, atol=1e-9)
    rho = np.hypot(ds.points[:, 0], ds.points[:, 1])
    assert rho.min() > 0.6 * 4000 and rho.max() <= 4000.0


@pytest.mark.parametrize("model", ["fig9", "wall", "gaussian"])
def test_exact_approximation_gives_the_true_points(model):
    p = bc.SensorParams.paper().replace(h=230.0, beta=1.0)
    ds = bc.simulate_room(p, range_mm=2500, n_points=150, approx_error=0.0, sigma_3d=0.0,
                          approx_model=model, nominal=p, rng=1)
    np.testing.assert_allclose(ds.approx_points, ds.points, rtol=1e-12, atol=1e-9)
    # the default nominal sensor is the paper's: exact for the paper's sensor too
    ds = bc.simulate_room(range_mm=2500, n_points=150, approx_model=model, rng=1)
    np.testing.assert_allclose(ds.approx_points, ds.points, rtol=1e-12, atol=1e-9)


def test_gaussian_approximation_has_the_stated_spread():
    err = 0.05
    ds = bc.simulate_room(range_mm=5000, n_points=580, approx_error=err, approx_model="gaussian",
                          rng=11)
    np.testing.assert_allclose(ds.sigma_scene, err * np.abs(ds.points), rtol=1e-15)
    ok = np.abs(ds.points) > 1e-6                       # skip exact zeros (0/0)
    r = (ds.approx_points - ds.points)[ok] / (err * np.abs(ds.points[ok]))
    # n ~ 1740 standardised errors ~ N(0, 1): sd of the sample sd ~ 1/sqrt(2n) = 0.017;
    # 5 sd gives a two-sided false-failure rate of 6e-7. Same for the mean (sd 1/sqrt(n)).
    assert r.size > 1700
    assert abs(r.std(ddof=1) - 1.0) < 5 / np.sqrt(2 * r.size)
    assert abs(r.mean()) < 5 / np.sqrt(r.size)


def test_fig9_approximation_puts_z_on_the_nominal_cone():
    err = 0.05
    nominal = bc.SensorParams.paper()
    truth = nominal.replace(h=215.0, beta=1.02)
    ds = bc.simulate_room(truth, range_mm=5000, approx_error=err, rng=2)
    np.testing.assert_allclose(cone_distance(nominal.h, nominal.beta, ds.approx_points), 0.0,
                               atol=1e-9)
    assert np.isinf(ds.sigma_scene[:, 2]).all()
    r = (ds.approx_points[:, :2] - ds.points[:, :2]) / (err * np.abs(ds.points[:, :2]))
    # 1160 N(0, 1) draws; 5-sd bound on the sample sd, false-failure rate 6e-7
    assert abs(r.std(ddof=1) - 1.0) < 5 / np.sqrt(2 * r.size)


def test_calibration_grid_pixels_are_projections(sensor):
    ds = bc.simulate_room(sensor, range_mm=1000, sigma_px=0.0, rng=4)
    c = ds.calibration
    R = rotation_matrix(c.angles)
    np.testing.assert_allclose(R @ R.T, np.eye(3), atol=1e-15)
    grid_c = c.grid_points_true @ R.T + c.translation
    np.testing.assert_allclose(c.grid_pixels, bc.project(sensor, grid_c), rtol=1e-13)
    # grid points lie on their planes n . P_W = d (d = 0.8 * range by default)
    np.testing.assert_allclose(np.sum(c.grid_points_true * CALIB_NORMALS_W[c.grid_plane], axis=1),
                               800.0, rtol=1e-14)
    # zero approx_error and sigma_3d: the pattern is measured exactly
    np.testing.assert_array_equal(c.grid_points, c.grid_points_true)


def test_calibration_laser_points_lie_on_the_cone(sensor):
    ds = bc.simulate_room(sensor, range_mm=1000, sigma_px=0.0, rng=4)
    c = ds.calibration
    np.testing.assert_allclose(cone_distance(sensor.h, sensor.beta, c.laser_points_true), 0.0,
                               atol=1e-9)
    np.testing.assert_allclose(c.laser_pixels, bc.project(sensor, c.laser_points_true),
                               rtol=1e-13)


def test_calibration_laser_points_lie_on_their_planes():
    ds = bc.simulate_room(range_mm=1000, sigma_px=0.0, rng=4)
    c = ds.calibration
    R = rotation_matrix(c.angles)
    p_w = (c.laser_points_true - c.translation) @ R          # R^T (P_C - t), row-wise
    on_plane = np.sum(p_w * CALIB_NORMALS_W[c.laser_plane], axis=1)
    np.testing.assert_allclose(on_plane, 800.0, rtol=0, atol=1e-9)


def test_room_walls_closed_polygon():
    w = bc.room_walls(1000.0, 7)
    assert w.shape == (7, 2, 2)
    np.testing.assert_array_equal(w[:, 1], np.roll(w[:, 0], -1, axis=0))
    r = np.linalg.norm(w[:, 0], axis=-1)
    assert r.min() >= 700.0 and r.max() <= 1000.0


@pytest.mark.parametrize("kwargs, exc, match", [
    ({"n_points": 0}, ValueError, r"n_points must be a positive integer, got 0"),
    ({"n_points": -5}, ValueError, r"n_points must be a positive integer, got -5"),
    ({"n_points": 2.5}, ValueError, r"n_points must be a positive integer, got 2.5"),
    ({"n_points": True}, ValueError, r"n_points must be a positive integer, got True"),
    ({"range_mm": -1.0}, ValueError, r"range_mm must be a finite positive number, got -1.0"),
    ({"range_mm": np.inf}, ValueError, r"range_mm must be a finite positive number, got inf"),
    ({"range_mm": "far"}, TypeError, r"range_mm must be a number, got 'far'"),
    ({"sigma_px": -0.1}, ValueError, r"sigma_px must be a finite non-negative number"),
    ({"approx_error": -0.05}, ValueError, r"approx_error must be a finite non-negative"),
    ({"sigma_3d": np.nan}, ValueError, r"sigma_3d must be a finite non-negative number"),
    ({"approx_model": "fig8"}, ValueError, r"approx_model must be one of \('fig9', 'wall', "
                                           r"'gaussian'\), got 'fig8'"),
    ({"n_walls": 2}, ValueError, r"n_walls must be an integer >= 3, got 2"),
    ({"rng": "seed"}, TypeError, r"rng must be a numpy.random.Generator.*got str"),
    ({"rng": -1}, ValueError, r"rng seed must be non-negative, got -1"),
    ({"colour": "red"}, TypeError, r"unexpected keyword argument 'colour'"),
])
def test_simulate_room_bad_input(kwargs, exc, match):
    kw = {"range_mm": 1000.0, "n_points": 20, **kwargs}
    with pytest.raises(exc, match=match):
        bc.simulate_room(**kw)


def test_simulate_room_params_must_be_sensor_params():
    with pytest.raises(TypeError, match=r"params must be a SensorParams, got ndarray"):
        bc.simulate_room(bc.SensorParams.paper().to_array(), range_mm=1000.0)
    with pytest.raises(TypeError, match=r"missing 1 required keyword-only argument: 'range_mm'"):
        bc.simulate_room()
