"""The misaligned laser cone: pose, ray/cone intersection and its Jacobians."""

import numpy as np
import pytest

import bayescal as bc
from bayescal.sensor.parameters import to_identifiable
from bayescal.sensor.pose import pose_rotation, triangulate_pose_theta

POSES = [(0.0, 0.0, 0.0, 0.0), (0.02, -0.01, 5.0, -3.0), (0.035, 0.017, 10.0, 0.0),
         (-0.004, 0.0, 0.0, -8.0)]


def _ring_pixels(sensor, rng, n=200, hi=1500.0):
    """Pixels of points on the aligned cone within hi mm (they stay on a cone tilted by
    <= 2 deg: far rays graze the cone and may pass above a tilted one)."""
    az = rng.uniform(0, 2 * np.pi, n)
    rho = rng.uniform(300, hi, n)
    pts = bc.cone_point(sensor, rho[:, None] * np.column_stack([np.cos(az), np.sin(az)]))
    return bc.project(sensor, pts), pts


def _brute_force(sensor, pose, pixel):
    """First sign change of the signed cone function along the ray, then bisection."""
    d = bc.backproject(sensor, pixel)
    R = pose_rotation(np.asarray(pose))
    A = np.array([pose[2], pose[3], -sensor.h])

    def f(t):
        Q = (t[:, None] * d - A) @ R
        return np.hypot(Q[:, 0], Q[:, 1]) - Q[:, 2] * np.tan(sensor.beta)

    t = np.linspace(1e-6, 1e4, 200_001)
    k = np.flatnonzero(np.diff(np.sign(f(t))) != 0)[0]
    lo, hi = t[k], t[k + 1]
    for _ in range(80):
        mid = 0.5 * (lo + hi)
        if np.sign(f(np.array([mid])))[0] == np.sign(f(np.array([lo])))[0]:
            lo = mid
        else:
            hi = mid
    return 0.5 * (lo + hi) * d


def test_zero_pose_is_the_paper_model(sensor, rng):
    pix, pts = _ring_pixels(sensor, rng)
    aligned = bc.triangulate(sensor, pix)
    np.testing.assert_array_equal(bc.triangulate(sensor, pix, laser=bc.LaserPose()), aligned)
    # the general quadratic agrees with the aligned closed form to rounding
    general, valid = triangulate_pose_theta(to_identifiable(sensor.to_array()), np.zeros(4),
                                            pix)
    assert valid.all()
    np.testing.assert_allclose(general, aligned, rtol=1e-12)


@pytest.mark.parametrize("pose", POSES[1:])
def test_intersection_lies_on_the_lit_nappe(sensor, rng, pose):
    pix, _ = _ring_pixels(sensor, rng)
    pts, valid = bc.triangulate(sensor, pix, laser=bc.LaserPose(*pose), return_valid=True)
    assert valid.all()
    lp = bc.LaserPose(*pose, h=sensor.h)
    Q = (pts - lp.apex) @ lp.rotation
    assert (Q[:, 2] > 0).all()
    np.testing.assert_allclose(np.hypot(Q[:, 0], Q[:, 1]), Q[:, 2] * np.tan(sensor.beta),
                               rtol=1e-10)
    # on the ray of the pixel
    np.testing.assert_allclose(bc.project(sensor, pts), pix, atol=1e-8)


@pytest.mark.parametrize("pose", POSES[1:3])
def test_root_matches_brute_force(sensor, rng, pose):
    """The closed-form root is the first crossing of the cone along the ray."""
    pix, _ = _ring_pixels(sensor, rng, n=3)
    # a steep downward ray too (it leaves the cone near the apex)
    pix = np.vstack([pix, [sensor.u0 + 5.0, sensor.v0 - 3.0]])
    pts = bc.triangulate(sensor, pix, laser=pose)
    for p, x in zip(pix, pts, strict=True):
        # grid step 0.05 mm then bisection: the crossing to 1e-6 mm
        np.testing.assert_allclose(x, _brute_force(sensor, pose, p), atol=1e-5)


def test_axis_and_apex_convention():
    lp = bc.LaserPose(tilt_x=0.1, tilt_y=0.2, offset_x=3.0, offset_y=-4.0, h=150.0)
    tx, ty = 0.1, 0.2
    np.testing.assert_allclose(lp.axis, [np.cos(tx) * np.sin(ty), -np.sin(tx),
                                         np.cos(tx) * np.cos(ty)], rtol=1e-15)
    np.testing.assert_allclose(np.linalg.norm(lp.axis), 1.0, rtol=1e-15)
    np.testing.assert_array_equal(lp.apex, [3.0, -4.0, -150.0])
    np.testing.assert_array_equal(bc.LaserPose.from_array(lp.to_array()).to_array(),
                                  lp.to_array())
    assert bc.LaserPose().is_aligned and not lp.is_aligned


def test_bad_pose_is_refused():
    sensor = bc.SensorParams.paper()
    with pytest.raises(ValueError, match="apex needs h"):
        _ = bc.LaserPose(0.1).apex
    with pytest.raises(ValueError, match="tilt_x must be finite"):
        bc.LaserPose(np.inf)
    with pytest.raises(TypeError, match="offset_y must be a real number"):
        bc.LaserPose(0, 0, 0, "1")
    with pytest.raises(ValueError, match=r"laser must have shape \(\.\.\., 4\)"):
        bc.triangulate(sensor, [[400.0, 380.0]], laser=[0.1, 0.2])


@pytest.mark.parametrize("pose", POSES)
def test_jacobians_match_finite_differences(sensor, rng, pose):
    pix, _ = _ring_pixels(sensor, rng, n=50)
    th = to_identifiable(sensor.to_array())
    pose = np.asarray(pose, dtype=float)
    _, valid, dpix, dth, dpose = triangulate_pose_theta(th, pose, pix, jacobian=True)
    assert valid.all()

    def fd(fun, x, k, eps):
        e = np.zeros_like(x)
        e[..., k] = eps
        return (fun(x + e) - fun(x - e)) / (2 * eps)

    # central differences: truncation ~eps^2 * third derivative, rounding ~1e-16 |P| / eps
    for k in range(4):
        num = fd(lambda q: triangulate_pose_theta(th, q, pix)[0], pose, k, 1e-6)
        np.testing.assert_allclose(dpose[..., k], num, rtol=1e-5, atol=1e-6 * np.abs(num).max())
    for k in range(7):
        eps = 1e-6 * max(1.0, abs(th[k]))
        num = fd(lambda t: triangulate_pose_theta(t, pose, pix)[0], th, k, eps)
        np.testing.assert_allclose(dth[..., k], num, rtol=1e-5, atol=1e-6 * np.abs(num).max())
    for k in range(2):
        num = fd(lambda p: triangulate_pose_theta(th, pose, p)[0], pix, k, 1e-5)
        np.testing.assert_allclose(dpix[..., k], num, rtol=1e-5, atol=1e-6 * np.abs(num).max())


def test_broadcasts_over_walkers_and_points(sensor, rng):
    pix, _ = _ring_pixels(sensor, rng, n=30)
    th = to_identifiable(sensor.to_array())
    thetas = th + np.zeros((5, 1, 7))
    poses = np.array(POSES[1:] + [POSES[1]] + [POSES[0]], dtype=float)[:, None, :]
    pts, valid = triangulate_pose_theta(thetas, poses, pix)
    assert pts.shape == (5, 30, 3) and valid.all()
    for w in range(5):
        np.testing.assert_array_equal(pts[w], triangulate_pose_theta(th, poses[w, 0], pix)[0])


@pytest.mark.parametrize("pose", POSES)
def test_cone_point_is_on_the_tilted_cone(sensor, rng, pose):
    from bayescal.sensor.pose import cone_point_pose_theta

    az = rng.uniform(0, 2 * np.pi, 100)
    xy = rng.uniform(300, 3000, 100)[:, None] * np.column_stack([np.cos(az), np.sin(az)])
    th = to_identifiable(sensor.to_array())
    pose = np.asarray(pose, dtype=float)
    pts, dxy, dth, dpose = cone_point_pose_theta(th, pose, xy, jacobian=True)
    np.testing.assert_array_equal(pts[:, :2], xy)
    np.testing.assert_allclose(bc.cone_point(sensor, xy, laser=pose), pts, rtol=1e-12, atol=1e-9)
    if not pose.any():
        np.testing.assert_allclose(pts, bc.cone_point(sensor, xy), rtol=1e-12, atol=1e-9)
    lp = bc.LaserPose(*pose, h=sensor.h)
    Q = (pts - lp.apex) @ lp.rotation
    assert (Q[:, 2] > 0).all()
    np.testing.assert_allclose(np.hypot(Q[:, 0], Q[:, 1]), Q[:, 2] * np.tan(sensor.beta),
                               rtol=1e-10)
    # the pixel of a tilted-cone point triangulates back onto it
    pix = bc.project(sensor, pts)
    np.testing.assert_allclose(bc.triangulate(sensor, pix, laser=pose), pts, rtol=1e-8)

    def fd(fun, x, k, eps):
        e = np.zeros_like(x)
        e[..., k] = eps
        return (fun(x + e) - fun(x - e)) / (2 * eps)

    for k in range(4):
        num = fd(lambda q: cone_point_pose_theta(th, q, xy), pose, k, 1e-6)
        np.testing.assert_allclose(dpose[..., k], num, rtol=1e-5, atol=1e-6 * np.abs(num).max())
    for k in (5, 6):
        num = fd(lambda t: cone_point_pose_theta(t, pose, xy), th, k, 1e-6 * max(1, th[k]))
        np.testing.assert_allclose(dth[..., k], num, rtol=1e-5, atol=1e-6 * np.abs(num).max())
    for k in range(2):
        num = fd(lambda q: cone_point_pose_theta(th, pose, q), xy, k, 1e-4)
        np.testing.assert_allclose(dxy[..., k], num, rtol=1e-5, atol=1e-7)


def test_cone_distance_pose_is_the_aligned_distance_at_zero_pose_and_has_exact_jacobians():
    from bayescal.sensor.laser import cone_distance
    from bayescal.sensor.pose import cone_distance_pose

    rng = np.random.default_rng(0)
    P = rng.normal(0, 1000, (30, 3))
    np.testing.assert_allclose(cone_distance_pose([200.0, 1.0, 0, 0, 0, 0], P),
                               cone_distance(200.0, 1.0, P), atol=1e-9)
    x = np.array([200.0, 1.0, 0.02, -0.01, 4.0, -3.0])
    _, J, dP = cone_distance_pose(x, P, jacobian=True)
    for k in range(6):
        e = np.zeros(6)
        e[k] = 1e-6 * max(1.0, abs(x[k]))
        num = (cone_distance_pose(x + e, P) - cone_distance_pose(x - e, P)) / (2 * e[k])
        np.testing.assert_allclose(J[:, k], num, rtol=1e-5, atol=1e-6 * np.abs(num).max())
    for k in range(3):
        E = np.zeros(3)
        E[k] = 1e-4
        num = (cone_distance_pose(x, P + E) - cone_distance_pose(x, P - E)) / 2e-4
        np.testing.assert_allclose(dP[:, k], num, atol=1e-7)
    pose = bc.LaserPose(*x[2:], h=200.0)
    on = bc.cone_point(bc.SensorParams.paper().replace(beta=1.0), P[:, :2], laser=pose)
    ok = np.isfinite(on[:, 2])
    np.testing.assert_allclose(cone_distance_pose(x, on[ok]), 0.0, atol=1e-9)
