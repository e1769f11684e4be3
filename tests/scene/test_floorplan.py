"""Floor-plan geometry: wall lines, corners, points on wall and cone, validation."""

import numpy as np
import pytest

import bayescal as bc
from bayescal.scene.floorplan import (
    FloorPlan,
    corner_azimuths,
    corner_points,
    plan_point,
    wall_range,
)
from bayescal.sensor.laser import cone_distance


def _plan(range_mm=1000.0, **kw):
    kw = {"distance_sd": 0.05 * range_mm, "angle_sd": 0.01} | kw
    return FloorPlan(bc.room_walls(range_mm), **kw)


def test_wall_lines_hold_their_segments():
    plan = _plan()
    n = np.stack([np.cos(plan.angles), np.sin(plan.angles)], -1)
    for end in (0, 1):
        np.testing.assert_allclose(np.einsum("ki,ki->k", n, plan.segments[:, end]),
                                   plan.distances, rtol=1e-12)
    assert np.all(plan.distances > 0)
    assert plan.param_names[:3] == ("d_0", "a_0", "d_1")
    np.testing.assert_allclose(plan.param_nominal[0::2], plan.distances)
    np.testing.assert_allclose(plan.param_sd[1::2], 0.01)


def test_from_lines_round_trip_and_corners_on_both_lines():
    plan = _plan()
    again = FloorPlan.from_lines(plan.distances, plan.angles, distance_sd=1.0, angle_sd=0.1)
    np.testing.assert_allclose(again.segments, plan.segments, atol=1e-9)
    c = corner_points(plan.distances, plan.angles)
    for k2 in (0, 1):
        d, a = np.roll(plan.distances, -k2), np.roll(plan.angles, -k2)
        np.testing.assert_allclose(c[:, 0] * np.cos(a) + c[:, 1] * np.sin(a), d, rtol=1e-12)
    np.testing.assert_allclose(corner_azimuths(plan.distances, plan.angles),
                               np.arctan2(plan.segments[:, 1, 1], plan.segments[:, 1, 0]),
                               atol=1e-12)


def test_point_is_on_wall_and_on_cone(sensor, rng):
    plan = _plan()
    theta = sensor.to_identifiable()
    k = rng.integers(0, plan.n_walls, 50)
    # azimuths inside each wall's span
    az0 = np.arctan2(plan.segments[k, 0, 1], plan.segments[k, 0, 0])
    span = (np.arctan2(plan.segments[k, 1, 1], plan.segments[k, 1, 0]) - az0) % (2 * np.pi)
    t = az0 + rng.uniform(0.05, 0.95, 50) * span
    P = plan_point(theta, t, plan.distances[k], plan.angles[k])
    on_wall = P[:, 0] * np.cos(plan.angles[k]) + P[:, 1] * np.sin(plan.angles[k])
    np.testing.assert_allclose(on_wall, plan.distances[k], rtol=1e-12)
    np.testing.assert_allclose(cone_distance(sensor.h, sensor.beta, P), 0.0, atol=1e-9)
    np.testing.assert_allclose(np.arctan2(P[:, 1], P[:, 0]), np.angle(np.exp(1j * t)),
                               atol=1e-12)


def test_plan_point_jacobians(sensor, rng, numdiff):
    theta = sensor.to_identifiable()
    t, d, a = 0.3, 900.0, 0.1
    _, dPt, dPth, dPw = plan_point(theta, np.array(t), np.array(d), np.array(a), jacobian=True)
    step_t = 1e-6
    np.testing.assert_allclose(
        dPt, numdiff(lambda x: plan_point(theta, x[0], d, a), [t], step_t)[:, 0], rtol=1e-6)
    np.testing.assert_allclose(
        dPth, numdiff(lambda x: plan_point(x, t, d, a), theta, 1e-6 * np.maximum(1, theta)),
        rtol=1e-6, atol=1e-6)
    np.testing.assert_allclose(
        dPw, numdiff(lambda x: plan_point(theta, t, x[0], x[1]), [d, a], [1e-4, 1e-7]),
        rtol=1e-6)
    rho, r_t, r_d, r_a = wall_range(t, d, a)
    assert rho == pytest.approx(d / np.cos(t - a))
    assert np.isnan(wall_range(a + 2.0, d, a)[0])       # behind the wall's line


@pytest.mark.parametrize("bad, match", [
    (np.zeros((3, 2)), "shape"),
    (np.zeros((2, 2, 2)), "shape"),
])
def test_rejects_bad_shapes(bad, match):
    with pytest.raises(ValueError, match=match):
        FloorPlan(bad, distance_sd=1.0, angle_sd=0.1)


def test_rejects_open_clockwise_or_outside_plans():
    w = bc.room_walls(1000.0)
    opened = w.copy()
    opened[2, 1] += 200.0
    with pytest.raises(ValueError, match="closed polygon; wall 2 ends"):
        FloorPlan(opened, distance_sd=1.0, angle_sd=0.1)
    clockwise = w[::-1, ::-1]
    with pytest.raises(ValueError, match="counterclockwise"):
        FloorPlan(clockwise, distance_sd=1.0, angle_sd=0.1)
    outside = w + np.array([3000.0, 0.0])
    with pytest.raises(ValueError, match="enclose the sensor"):
        FloorPlan(outside, distance_sd=1.0, angle_sd=0.1)
    with pytest.raises(ValueError, match="non-finite|finite"):
        FloorPlan(np.where(w == w[0, 0, 0], np.nan, w), distance_sd=1.0, angle_sd=0.1)


@pytest.mark.parametrize("kw, match", [
    ({"distance_sd": -1.0}, "distance_sd must be finite and positive.*-1.0"),
    ({"angle_sd": 0.0}, "angle_sd must be finite and positive"),
    ({"angle_sd": [0.1, 0.2]}, r"angle_sd must be a float or have shape \(7,\)"),
    ({"distance_sd": np.inf}, "distance_sd"),
])
def test_rejects_bad_sds(kw, match):
    with pytest.raises(ValueError, match=match):
        _plan(**kw)
    with pytest.raises(TypeError, match="distance_sd"):
        _plan(distance_sd="a lot")


def test_per_wall_sds_and_corner_tol():
    sd = np.linspace(10, 70, 7)
    plan = _plan(distance_sd=sd)
    np.testing.assert_allclose(plan.distance_sd, sd)
    w = bc.room_walls(1000.0)
    w[3, 1] += 10.0                                     # a 10 mm gap: rough but accepted
    FloorPlan(w, distance_sd=1.0, angle_sd=0.1)
    with pytest.raises(ValueError, match="corner_tol"):
        FloorPlan(w, distance_sd=1.0, angle_sd=0.1, corner_tol=1.0)
    assert "7 walls" in repr(plan)


def test_simulate_room_floor_plan_keeps_streams_and_matches_wall_errors():
    ds = bc.simulate_room(range_mm=1000, sigma_px=0.5, approx_error=0.05,
                          approx_model="wall", rng=3)
    # the pixel noise stream is the first spawned child, as before the plan existed
    ss = np.random.SeedSequence(np.random.default_rng(3).integers(2**63))
    rng_pix = np.random.default_rng(ss.spawn(3)[0])
    np.testing.assert_array_equal(
        ds.pixels, ds.pixels_true + rng_pix.normal(0.0, 0.5, ds.pixels.shape))
    plan, true = ds.floor_plan, FloorPlan(ds.walls, distance_sd=1.0, angle_sd=1.0)
    # "wall" model: the plan's distance errors are the approximate points' wall errors
    ratio = np.hypot(*ds.approx_points[:, :2].T) / np.hypot(*ds.points[:, :2].T)
    np.testing.assert_allclose(np.sort(np.unique(ratio.round(12))),
                               np.sort((plan.distances / true.distances).round(12)), rtol=1e-9)
    np.testing.assert_allclose(plan.distance_sd, 0.05 * true.distances)
    assert np.all(plan.angle_sd == 0.01)
    assert np.any(plan.angles != true.angles)
    again = bc.simulate_room(range_mm=1000, sigma_px=0.5, approx_error=0.05,
                             approx_model="wall", rng=3)
    np.testing.assert_array_equal(again.floor_plan.segments, plan.segments)


def test_walls_property_returns_the_segments_as_given():
    walls = bc.room_walls(1000)
    plan = bc.FloorPlan(walls, distance_sd=20.0, angle_sd=0.01)
    np.testing.assert_array_equal(plan.walls, walls)


POSE = np.array([0.02, -0.015, 4.0, -6.0])          # tilt_x, tilt_y (rad), offset (mm)


def test_plan_point_on_a_misaligned_cone_jacobians(sensor, numdiff):
    g = np.r_[sensor.to_identifiable(), POSE]
    t, d, a = np.array([0.3, -2.0]), np.array([900.0, 1500.0]), np.array([0.1, -2.2])
    P, dPt, dPth, dPw = plan_point(g, t, d, a, jacobian=True)
    assert dPth.shape == (2, 3, 11)
    # on the wall and on the tilted cone (the pose module's own cone equation)
    np.testing.assert_allclose(P[:, 0] * np.cos(a) + P[:, 1] * np.sin(a), d, rtol=1e-12)
    lit = bc.cone_point(sensor, P[:, :2], laser=bc.LaserPose.from_array(POSE))
    np.testing.assert_allclose(P, lit, atol=1e-9)
    for j in range(2):
        np.testing.assert_allclose(
            dPt[j], numdiff(lambda x, j=j: plan_point(g, x[0], d[j], a[j]), [t[j]], 1e-6)[:, 0],
            rtol=1e-6, atol=1e-6)
        np.testing.assert_allclose(
            dPth[j], numdiff(lambda x, j=j: plan_point(x, t[j], d[j], a[j]), g,
                             1e-6 * np.maximum(1, np.abs(g))), rtol=1e-5, atol=1e-5)
        np.testing.assert_allclose(
            dPw[j], numdiff(lambda x, j=j: plan_point(g, t[j], x[0], x[1]), [d[j], a[j]],
                            [1e-4, 1e-7]), rtol=1e-6, atol=1e-6)
    assert np.all(dPth[:, 2, 7:] != 0)                   # the pose moves the point's height


def test_plan_point_at_zero_pose_is_the_aligned_point(sensor, rng):
    theta = sensor.to_identifiable()
    t, d, a = rng.uniform(-0.6, 0.6, 20), rng.uniform(500, 3000, 20), np.zeros(20)
    out7 = plan_point(theta, t, d, a, jacobian=True)
    out11 = plan_point(np.r_[theta, np.zeros(4)], t, d, a, jacobian=True)
    for x7, x11 in zip(out7[:2] + out7[3:], out11[:2] + out11[3:], strict=True):
        np.testing.assert_allclose(x11, x7, rtol=1e-9, atol=1e-9)
    np.testing.assert_allclose(out11[2][..., :7], out7[2], rtol=1e-9, atol=1e-9)
    # walkers: theta (S, 1, 11) with azimuths (S, N)
    G = np.stack([np.r_[theta, POSE], np.r_[theta, np.zeros(4)]])
    P = plan_point(G[:, None, :], np.stack([t, t]), d, a)
    np.testing.assert_allclose(P[1], out7[0], rtol=1e-9)
    np.testing.assert_allclose(P[0], plan_point(G[0], t, d, a), rtol=1e-12)
