"""Eq. (1): projection, closed-form back-projection, their Jacobians, domain and input checks."""

import numpy as np
import pytest

import bayescal as bc
from bayescal.sensor.camera import backproject_theta, project_theta
from bayescal.sensor.parameters import to_identifiable


def _random_sensor(rng):
    """A random sensor with xi in (0.3, 1.5), phi != 0 and a random sign of alpha_v."""
    xi = rng.uniform(0.3, 1.5)
    return bc.SensorParams(
        xi=xi, phi=rng.uniform(max(-0.2, 0.1 - xi), 0.8),
        alpha_u=rng.uniform(30.0, 300.0), alpha_v=rng.choice([-1.0, 1.0]) * rng.uniform(30, 300),
        u0=rng.uniform(200.0, 800.0), v0=rng.uniform(150.0, 600.0),
        h=rng.uniform(100.0, 300.0), beta=rng.uniform(0.5, 1.4))


def _domain_points(rng, xi, n, *, margin=0.05):
    """Points in the projection domain: xi * r - z > margin * r, ranges 100..8000 mm."""
    out = np.empty((0, 3))
    while len(out) < n:
        d = rng.normal(size=(4 * n, 3))
        d /= np.linalg.norm(d, axis=-1, keepdims=True)
        d = d[xi - d[:, 2] > margin]
        out = np.concatenate([out, d * rng.uniform(100.0, 8000.0, (len(d), 1))])
    return out[:n]


def test_project_matches_opencv_omnidir(rng):
    """Independent implementation: OpenCV's Mei model after z -> -z, fx = gamma_u, fy = gamma_v.

    cv2.omnidir.projectPoints takes a negative fy as it is (it multiplies, it
    does not check the sign), so no flip of v about v0 is needed; the random
    sensors include both signs of alpha_v.
    """
    cv2 = pytest.importorskip("cv2")
    n_sets = 25
    n_xi_not_1 = n_phi_not_0 = 0
    for _ in range(n_sets):
        p = _random_sensor(rng)
        n_xi_not_1 += p.xi != 1.0
        n_phi_not_0 += p.phi != 0.0
        pts = _domain_points(rng, p.xi, 200)
        s = p.xi + p.phi
        K = np.array([[p.alpha_u * s, 0.0, p.u0], [0.0, p.alpha_v * s, p.v0], [0.0, 0.0, 1.0]])
        obj = (pts * [1.0, 1.0, -1.0]).reshape(-1, 1, 3)
        cv, _ = cv2.omnidir.projectPoints(obj, np.zeros((3, 1)), np.zeros((3, 1)), K, p.xi,
                                          np.zeros((1, 4)))
        cv = cv.reshape(-1, 2)
        uv, valid = bc.project(p, pts, return_valid=True)
        assert valid.all()
        # relative to the pixel's distance from the principal point (the part eq. (1) computes)
        scale = np.linalg.norm(uv - [p.u0, p.v0], axis=-1, keepdims=True)
        np.testing.assert_array_less(np.abs(uv - cv), np.broadcast_to(1e-9 * scale, uv.shape))
    assert n_xi_not_1 >= 20 and n_phi_not_0 >= 20


def test_project_known_value():
    p = bc.SensorParams.paper()
    # xi = 1, z = 0: u = 55 * x / r + 400; straight down: the principal point
    np.testing.assert_allclose(bc.project(p, [1000.0, 0.0, 0.0]), [455.0, 300.0], rtol=1e-15)
    np.testing.assert_allclose(bc.project(p, [0.0, 1000.0, 0.0]), [400.0, 245.0], rtol=1e-15)
    np.testing.assert_allclose(bc.project(p, [0.0, 0.0, -10.0]), [400.0, 300.0], rtol=1e-15)


def test_backproject_unit_rays_project_back(sensor, rng):
    xi = sensor.xi
    pts = _domain_points(rng, xi, 300)
    pix = bc.project(sensor, pts)
    rays, valid = bc.backproject(sensor, pix, return_valid=True)
    assert valid.all()
    np.testing.assert_allclose(np.linalg.norm(rays, axis=-1), 1.0, rtol=0, atol=1e-13)
    # for xi <= 1 the ray is the direction of the original point
    np.testing.assert_allclose(rays, pts / np.linalg.norm(pts, axis=-1, keepdims=True),
                               rtol=0, atol=1e-11)
    for scale in (1.0, 3000.0):
        np.testing.assert_allclose(bc.project(sensor, scale * rays), pix, rtol=1e-12)


def test_principal_point_looks_straight_down(sensor):
    ray = bc.backproject(sensor, [sensor.u0, sensor.v0])
    np.testing.assert_allclose(ray, [0.0, 0.0, -1.0], rtol=0, atol=1e-15)


@pytest.mark.parametrize("xi", [1.0, 0.5, 0.9])
def test_project_outside_domain_gives_nan(xi):
    """xi * r - z <= 0: for xi = 1 the half-axis straight up, for xi < 1 a cone around +z."""
    p = bc.SensorParams.paper().replace(xi=xi)
    half_angle = np.arccos(xi)                       # the invalid cone around +z
    inside = [[0.0, 0.0, 500.0], [0.0, 0.0, 0.0]]    # straight up; the focus itself
    if xi < 1:
        a = 0.5 * half_angle
        inside.append([np.sin(a) * 700, 0.0, np.cos(a) * 700])
    a = half_angle + 0.1                              # just outside the invalid cone
    ok = [[np.sin(a) * 700, 0.0, np.cos(a) * 700], [300.0, -200.0, -900.0]]
    uv, valid = bc.project(p, np.array(inside + ok), return_valid=True)
    np.testing.assert_array_equal(valid, [False] * len(inside) + [True] * len(ok))
    assert np.isnan(uv[~valid]).all() and np.isfinite(uv[valid]).all()


def test_backproject_outside_image_of_sphere_gives_nan():
    """For xi > 1 pixels with 1 + (1 - xi^2) |m|^2 < 0 have no ray."""
    p = bc.SensorParams.paper().replace(xi=1.5)
    gu = p.alpha_u * (p.xi + p.phi)
    m_edge = 1.0 / np.sqrt(p.xi**2 - 1.0)
    pix = [[p.u0 + 0.9 * m_edge * gu, p.v0], [p.u0 + 1.1 * m_edge * gu, p.v0]]
    rays, valid = bc.backproject(p, pix, return_valid=True)
    np.testing.assert_array_equal(valid, [True, False])
    assert np.isfinite(rays[0]).all() and np.isnan(rays[1]).all()


# ---------------------------------------------------------------- Jacobians

THETA_STEP = np.array([1e-6, 1e-4, 1e-4, 1e-4, 1e-4, 1e-4, 1e-7])


def test_project_theta_jacobians(sensor, rng, numdiff):
    theta = sensor.to_identifiable()
    pts = _domain_points(rng, sensor.xi, 40, margin=0.1)
    uv, valid, dP, dth = project_theta(theta, pts, jacobian=True)
    assert valid.all() and dP.shape == (40, 2, 3) and dth.shape == (40, 2, 7)
    dP_fd = numdiff(lambda x: project_theta(theta, x)[0], pts, 1e-3)
    dth_fd = numdiff(lambda t: project_theta(t, pts)[0], theta, THETA_STEP)
    for J, Jfd in ((dP, dP_fd), (dth, dth_fd)):
        np.testing.assert_allclose(J, Jfd, rtol=1e-6, atol=1e-7 * np.abs(Jfd).max())


def test_backproject_theta_jacobians(sensor, rng, numdiff):
    theta = sensor.to_identifiable()
    pix = bc.project(sensor, _domain_points(rng, sensor.xi, 40, margin=0.1))
    rays, valid, dpix, dth = backproject_theta(theta, pix, jacobian=True)
    assert valid.all() and dpix.shape == (40, 3, 2) and dth.shape == (40, 3, 7)
    dpix_fd = numdiff(lambda x: backproject_theta(theta, x)[0], pix, 1e-4)
    dth_fd = numdiff(lambda t: backproject_theta(t, pix)[0], theta, THETA_STEP)
    for J, Jfd in ((dpix, dpix_fd), (dth, dth_fd)):
        np.testing.assert_allclose(J, Jfd, rtol=1e-6, atol=1e-7 * np.abs(Jfd).max())


def test_backproject_theta_jacobian_for_xi_above_one(rng, numdiff):
    p = bc.SensorParams.paper().replace(xi=1.3, phi=0.2)
    theta = p.to_identifiable()
    gu = abs(p.alpha_u * (p.xi + p.phi))
    r = rng.uniform(0.0, 0.8 / np.sqrt(p.xi**2 - 1), 30) * gu      # inside the image of the sphere
    a = rng.uniform(0, 2 * np.pi, 30)
    pix = np.column_stack([p.u0 + r * np.cos(a), p.v0 + r * np.sin(a)])
    _, valid, dpix, dth = backproject_theta(theta, pix, jacobian=True)
    assert valid.all()
    dth_fd = numdiff(lambda t: backproject_theta(t, pix)[0], theta, THETA_STEP)
    dpix_fd = numdiff(lambda x: backproject_theta(theta, x)[0], pix, 1e-4)
    np.testing.assert_allclose(dth, dth_fd, rtol=1e-6, atol=1e-7 * np.abs(dth_fd).max())
    np.testing.assert_allclose(dpix, dpix_fd, rtol=1e-6, atol=1e-7 * np.abs(dpix_fd).max())


# ---------------------------------------------------------------- broadcasting

def _walker_params(rng, n_walkers):
    a = np.tile(bc.SensorParams.paper().to_array(), (n_walkers, 1))
    a[:, 0] = rng.uniform(0.8, 1.0, n_walkers)
    a[:, 2:6] += rng.normal(0.0, 1.0, (n_walkers, 4))
    a[:, 6] += rng.normal(0.0, 10.0, n_walkers)
    return a


def test_broadcast_walkers_against_points(rng):
    a = _walker_params(rng, 6)
    pts = _domain_points(rng, 0.8, 9, margin=0.05)
    uv = bc.project(a[:, None, :], pts)
    assert uv.shape == (6, 9, 2)
    for w in range(6):
        np.testing.assert_allclose(uv[w], bc.project(bc.SensorParams.from_array(a[w]), pts),
                                   rtol=1e-15)
    pts_w = pts + rng.normal(0.0, 10.0, (6, 9, 3))                 # (W, N, 3) points
    uv_w, valid = bc.project(a[:, None, :], pts_w, return_valid=True)
    assert uv_w.shape == (6, 9, 2) and valid.shape == (6, 9)
    for w in range(6):
        np.testing.assert_allclose(uv_w[w], bc.project(a[w], pts_w[w]), rtol=1e-15)
    rays = bc.backproject(a[:, None, :], uv)
    assert rays.shape == (6, 9, 3)
    np.testing.assert_allclose(rays[2], bc.backproject(a[2], uv[2]), rtol=1e-15)


def test_broadcast_single_point_and_jacobian_shapes(rng):
    p = bc.SensorParams.paper()
    uv = bc.project(p, [500.0, 200.0, -100.0])
    assert uv.shape == (2,)
    uv, valid = bc.project(p, np.array([500.0, 200.0, -100.0]), return_valid=True)
    assert valid.shape == () and bool(valid)
    assert bc.backproject(p, uv).shape == (3,)
    theta = to_identifiable(_walker_params(rng, 5))[:, None, :]
    out = project_theta(theta, _domain_points(rng, 0.8, 7), jacobian=True)
    assert [o.shape for o in out] == [(5, 7, 2), (5, 7), (5, 7, 2, 3), (5, 7, 2, 7)]
    out = backproject_theta(theta, out[0], jacobian=True)
    assert [o.shape for o in out] == [(5, 7, 3), (5, 7), (5, 7, 3, 2), (5, 7, 3, 7)]


# ---------------------------------------------------------------- bad input

_S3, _S2 = r"must have shape \(\.\.\., 3\)", r"must have shape \(\.\.\., 2\)"


@pytest.mark.parametrize("func, arg, exc, match", [
    ("project", np.zeros((4, 2)), ValueError, "points " + _S3 + r", got shape \(4, 2\)"),
    ("project", 5.0, ValueError, "points " + _S3 + r", got shape \(\)"),
    ("project", [[0.0, np.nan, 1.0]], ValueError, r"points must contain only finite values"),
    ("project", [[0.0, np.inf, 1.0]], ValueError, r"points must contain .*finite.*index \(0, 1\)"),
    ("project", "abc", TypeError, r"points must be a numeric array, got str"),
    ("backproject", np.zeros((4, 3)), ValueError, "pixels " + _S2 + r", got shape \(4, 3\)"),
    ("backproject", [[np.nan, 1.0]], ValueError, r"pixels must contain only finite values"),
    ("backproject", ["a", 1.0], TypeError, r"pixels must be a numeric array"),
])
def test_bad_input_names_the_argument(func, arg, exc, match):
    with pytest.raises(exc, match=match):
        getattr(bc, func)(bc.SensorParams.paper(), arg)


def test_bad_params_name_the_argument():
    with pytest.raises(ValueError, match=r"params must be a SensorParams or an array of shape "
                                         r"\(\.\.\., 8\), got shape \(3, 7\)"):
        bc.project(np.zeros((3, 7)), [1.0, 0.0, 0.0])
    with pytest.raises(TypeError, match=r"params must be a SensorParams.*got dict"):
        bc.backproject({"xi": 1.0}, [1.0, 0.0])
