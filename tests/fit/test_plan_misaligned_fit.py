"""model="misaligned" with a floor plan: the least squares on a tilted, offset laser cone."""

import numpy as np
import pytest
from scipy import stats

import bayescal as bc
from bayescal.sensor.pose import POSE_NAMES

TILT = tuple(np.radians([1.0, 0.5]))
OFFSET = (5.0, -5.0)
TRUE_POSE = np.r_[TILT, OFFSET]


def _room(seed, *, approx_error=0.03, n_points=300, sigma_px=0.2):
    return bc.simulate_room(range_mm=2500, n_points=n_points, n_walls=6, sigma_px=sigma_px,
                            approx_error=approx_error, approx_model="wall", rng=seed,
                            tilt=TILT, offset=OFFSET)


def _fits(ds):
    return {m: bc.calibrate_simultaneous(ds.pixels, ds.floor_plan, sigma_px=0.2, model=m)
            for m in ("aligned", "misaligned")}


@pytest.fixture(scope="module")
def tilted():
    ds = _room(0)
    return ds, _fits(ds)


def _z(ds, res):
    g = res.extras["theta"]
    truth = np.r_[ds.params.to_identifiable(), TRUE_POSE][:len(g)]
    return (g - truth) / np.sqrt(np.diag(res.covariance(identifiable=True)))


def test_misaligned_plan_fit_takes_the_tilt_off_the_principal_point(tilted):
    ds, fits = tilted
    # the aligned model absorbs the 1 degree tilt into u0, v0 (measured 13.5 and 29 sd)
    assert np.max(np.abs(_z(ds, fits["aligned"])[3:5])) > 10
    # one replication of a correct model: |z| < 4 fails with probability ~ 6e-5 per value
    z = _z(ds, fits["misaligned"])
    assert z.shape == (11,) and np.all(np.abs(z) < 4), z
    np.testing.assert_allclose(fits["misaligned"].laser.to_array(),
                               fits["misaligned"].extras["theta"][7:])


def test_a_tight_plan_shows_the_misaligned_points_are_better():
    # with the room's scale known to 0.5 % the cone's tilt dominates the points' error
    # (measured 20 vs 55 mm; with a 3 % plan, as in the plan benchmark of
    # docs/performance.md, both are ~80 mm: the plan's scale dominates)
    ds = _room(0, approx_error=0.005)
    fits = _fits(ds)
    err = {m: np.mean(np.linalg.norm(r.points - ds.points, axis=1)) for m, r in fits.items()}
    assert err["misaligned"] < 0.6 * err["aligned"], err
    assert np.all(np.abs(_z(ds, fits["misaligned"])) < 4)


def test_plan_result_carries_the_pose(tilted, tmp_path):
    _, fits = tilted
    al, mis = fits["aligned"], fits["misaligned"]
    assert al.model == "aligned" and mis.model == "misaligned"
    assert mis.covariance(identifiable=True).shape == (11, 11)
    assert mis.covariance().shape == (8, 8)
    assert mis.extras["identifiable_names"][7:] == POSE_NAMES
    assert mis.identifiability.names[-4:] == POSE_NAMES
    assert mis.extras["walls"].shape == (6, 2) and mis.extras["point_covariance"].shape == (
        300, 3, 3)
    # the 3D points lie on the fitted tilted cone
    lit = bc.cone_point(mis.params, mis.points[:, :2], laser=mis.laser)
    np.testing.assert_allclose(mis.points, lit, atol=1e-6)
    back = bc.load_result(mis.save(tmp_path / "r.json"))
    assert back.model == "misaligned"
    np.testing.assert_array_equal(back.laser.to_array(), mis.laser.to_array())


def test_a_pose_pinned_at_zero_gives_the_aligned_fit():
    ds = _room(1, n_points=120)
    pinned = bc.Prior({n: stats.norm(0.0, 1e-9) for n in POSE_NAMES})
    kw = dict(sigma_px=0.2, prior=pinned)
    al = bc.calibrate_simultaneous(ds.pixels, ds.floor_plan, model="aligned", **kw)
    mis = bc.calibrate_simultaneous(ds.pixels, ds.floor_plan, model="misaligned", **kw)
    np.testing.assert_allclose(mis.laser.to_array(), 0.0, atol=1e-8)
    np.testing.assert_allclose(mis.params.to_identifiable(), al.params.to_identifiable(),
                               rtol=1e-6, atol=1e-6)
    np.testing.assert_allclose(mis.covariance(identifiable=True)[:7, :7],
                               al.covariance(identifiable=True), rtol=1e-4, atol=1e-12)
    np.testing.assert_allclose(mis.points, al.points, atol=1e-4)
