"""SensorParams, the identifiable coordinates and the exact degeneracy (fact 1 of
docs/model.md, "Measured facts": only xi, gamma_u, gamma_v, u0, v0, h, beta are seen)."""

import numpy as np
import pytest

import bayescal as bc
from bayescal.sensor.parameters import (
    as_param_array,
    from_identifiable,
    identifiable_jacobian,
    to_identifiable,
)


def test_paper_values():
    p = bc.SensorParams.paper()
    np.testing.assert_array_equal(
        p.to_array(), [1.0, 0.0, 55.0, -55.0, 400.0, 300.0, 200.0, np.pi / 3])
    assert bc.PARAM_NAMES == ("xi", "phi", "alpha_u", "alpha_v", "u0", "v0", "h", "beta")
    assert list(p.as_dict()) == list(bc.PARAM_NAMES)


def test_array_round_trip(sensor):
    assert bc.SensorParams.from_array(sensor.to_array()) == sensor
    assert sensor.replace(h=333.0).h == 333.0
    assert sensor.replace(h=333.0).beta == sensor.beta


def test_identifiable_round_trip(sensor):
    theta = sensor.to_identifiable()
    assert theta.shape == (7,)
    s = sensor.xi + sensor.phi
    np.testing.assert_allclose(theta[1:3], [sensor.alpha_u * s, sensor.alpha_v * s], rtol=1e-15)
    back = bc.SensorParams.from_identifiable(theta, phi=sensor.phi)
    np.testing.assert_allclose(back.to_array(), sensor.to_array(), rtol=1e-14, atol=1e-14)


def test_identifiable_round_trip_vectorized(rng):
    a = np.tile(bc.SensorParams.paper().to_array(), (5, 3, 1))
    a[..., 0] = rng.uniform(0.3, 1.5, (5, 3))
    a[..., 1] = rng.uniform(-0.2, 0.8, (5, 3))
    a[..., 2:4] *= rng.uniform(0.5, 2.0, (5, 3, 2))
    theta = to_identifiable(a)
    assert theta.shape == (5, 3, 7)
    np.testing.assert_allclose(from_identifiable(theta, a[..., 1]), a, rtol=1e-14, atol=1e-14)


def test_identifiable_jacobian_matches_finite_differences(sensor, numdiff):
    x = np.append(sensor.to_identifiable(), sensor.phi)           # (theta, phi), shape (8,)
    J = identifiable_jacobian(x[:7], x[7])
    Jfd = numdiff(lambda z: from_identifiable(z[..., :7], z[..., 7]), x, 1e-6)
    np.testing.assert_allclose(J, Jfd, rtol=1e-7, atol=1e-7 * np.abs(Jfd).max())


@pytest.mark.parametrize("k", [0.5, 1.7, 3.0])
def test_degeneracy_changes_no_pixel_and_no_point(sensor, k, rng):
    """Fact 1 (docs/model.md, "Measured facts"): alpha -> k alpha,
    phi -> (xi + phi) / k - xi is invisible in the data."""
    other = sensor.replace(alpha_u=k * sensor.alpha_u, alpha_v=k * sensor.alpha_v,
                           phi=(sensor.xi + sensor.phi) / k - sensor.xi)
    assert not np.allclose(other.to_array(), sensor.to_array())
    np.testing.assert_allclose(other.to_identifiable(), sensor.to_identifiable(), rtol=1e-14)
    az = rng.uniform(0, 2 * np.pi, 50)
    rho = rng.uniform(500, 6000, 50)
    pts = bc.cone_point(sensor, rho[:, None] * np.column_stack([np.cos(az), np.sin(az)]))
    pix = bc.project(sensor, pts)
    np.testing.assert_allclose(bc.project(other, pts), pix, rtol=1e-12)
    np.testing.assert_allclose(bc.triangulate(other, pix), bc.triangulate(sensor, pix),
                               rtol=1e-12)
    np.testing.assert_allclose(bc.pixel_azimuth(other, pix), bc.pixel_azimuth(sensor, pix),
                               rtol=1e-12, atol=1e-12)


def test_as_param_array_accepts_both_forms():
    p = bc.SensorParams.paper()
    np.testing.assert_array_equal(as_param_array(p), p.to_array())
    a = np.tile(p.to_array(), (4, 1, 1))
    assert as_param_array(a).shape == (4, 1, 8)


@pytest.mark.parametrize("changes, exc, match", [
    ({"h": 0.0}, ValueError, r"h must be positive \(mm\), got 0.0"),
    ({"h": -5.0}, ValueError, r"h must be positive \(mm\), got -5.0"),
    ({"beta": 0.0}, ValueError, r"beta must lie in \(0, pi/2\) radians, got 0.0"),
    ({"beta": np.pi / 2}, ValueError, r"beta must lie in \(0, pi/2\) radians"),
    ({"beta": -0.3}, ValueError, r"beta must lie in \(0, pi/2\) radians, got -0.3"),
    ({"xi": "one"}, TypeError, r"SensorParams.xi must be a number, got 'one'"),
    ({"u0": None}, TypeError, r"SensorParams.u0 must be a number, got None"),
    ({"v0": np.nan}, ValueError, r"SensorParams.v0 must be finite, got nan"),
    ({"alpha_u": 0.0}, ValueError, r"alpha_u and alpha_v must be non-zero"),
    ({"xi": -0.1, "phi": 0.5}, ValueError, r"xi must be non-negative, got -0.1"),
    ({"phi": -1.0}, ValueError, r"xi \+ phi must be positive, got xi=1.0, phi=-1.0"),
])
def test_sensor_params_rejects_bad_values(changes, exc, match):
    with pytest.raises(exc, match=match):
        bc.SensorParams.paper().replace(**changes)


def test_sensor_params_bad_arrays_and_names():
    p = bc.SensorParams.paper()
    with pytest.raises(ValueError, match=r"a must have shape \(8,\).*got \(7,\)"):
        bc.SensorParams.from_array(np.zeros(7))
    with pytest.raises(ValueError, match=r"theta must have shape \(7,\).*got \(8,\)"):
        bc.SensorParams.from_identifiable(p.to_array())
    with pytest.raises(TypeError, match=r"unknown parameter name\(s\) \['gamma'\]"):
        p.replace(gamma=1.0)
    with pytest.raises(ValueError, match=r"params must be a SensorParams or an array of shape "
                                         r"\(\.\.\., 8\), got shape \(7,\)"):
        as_param_array(np.zeros(7))
    with pytest.raises(TypeError, match=r"params must be a SensorParams.*got str"):
        as_param_array("paper")
