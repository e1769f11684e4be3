"""Sequential calibration (paper sec. II): Jacobians, noise-free recovery, plane fit,
covariance against Monte-Carlo re-fits, noise estimate, identifiability, bad input."""

import dataclasses

import numpy as np
import pytest
from scipy import stats

import bayescal as bc
import bayescal.fit.sequential as sequential
from bayescal.fit.sequential import fit_plane
from bayescal.fit.sequential_stages import laser_points, rotation_and_jacobian, stage1_residuals
from bayescal.scene.simulate import rotation_matrix
from bayescal.sensor.parameters import IDENTIFIABLE_NAMES

CALIB_NORMALS_W = np.array([[1.0, 0, 0], [0, 1.0, 0], [-1.0, 0, 0], [0, -1.0, 0]])


def _calib_distance(c):
    return float(np.abs(np.sum(c.grid_points_true * CALIB_NORMALS_W[c.grid_plane], axis=1))[0])


def _room(range_mm=1000.0, sigma_px=0.0, rng=0, **kw):
    return bc.simulate_room(range_mm=range_mm, sigma_px=sigma_px, rng=rng, **kw)


def _true_pose(c):
    return np.concatenate([c.angles, c.translation])


# ----------------------------------------------------------------------------- Jacobians
def test_rotation_matches_scenes_and_its_jacobian(numdiff):
    angles = np.array([0.3, -0.2, 1.1])
    R, dR = rotation_and_jacobian(angles)
    np.testing.assert_allclose(R, rotation_matrix(angles), rtol=0, atol=1e-15)
    fd = numdiff(lambda a: rotation_matrix(a).ravel(), angles, 1e-6)      # (9, 3)
    np.testing.assert_allclose(np.moveaxis(dR, 0, -1).reshape(9, 3), fd, rtol=0, atol=1e-9)


def test_stage1_jacobian_matches_finite_differences(numdiff):
    ds = _room(sigma_px=0.3)
    c = ds.calibration
    p1 = np.concatenate([ds.params.to_identifiable()[:5] * 1.01, _true_pose(c) + 0.01])
    J = stage1_residuals(p1, c.grid_points, c.grid_pixels, jacobian=True)
    fd = numdiff(lambda x: stage1_residuals(x, c.grid_points, c.grid_pixels), p1,
                 np.r_[1e-6, 1e-4, 1e-4, 1e-4, 1e-4, 1e-7, 1e-7, 1e-7, 1e-4, 1e-4, 1e-4])
    np.testing.assert_allclose(J, fd, rtol=1e-6, atol=1e-6)


def test_laser_point_jacobians_match_finite_differences(numdiff):
    ds = _room(sigma_px=0.3)
    c = ds.calibration
    p1 = np.concatenate([ds.params.to_identifiable()[:5] * 0.99, _true_pose(c) - 0.01])
    planes = np.array([fit_plane(c.grid_points[c.grid_plane == j])[0] for j in range(4)])
    pix, idx = c.laser_pixels[:15], c.laser_plane[:15]
    P, valid, dpix, dp1 = laser_points(p1, planes, pix, idx, jacobian=True)
    assert valid.all()
    fd1 = numdiff(lambda x: laser_points(x, planes, pix, idx)[0], p1,
                  np.r_[1e-6, 1e-4, 1e-4, 1e-4, 1e-4, 1e-7, 1e-7, 1e-7, 1e-4, 1e-4, 1e-4])
    np.testing.assert_allclose(dp1, fd1, rtol=1e-5, atol=1e-5)
    fdp = np.stack([numdiff(lambda q, k=k: laser_points(p1, planes, q[None], idx[k:k + 1])[0][0],
                            pix[k], 1e-4) for k in range(len(pix))])
    np.testing.assert_allclose(dpix, fdp, rtol=1e-5, atol=1e-5)


# ----------------------------------------------------------------------------- recovery
@pytest.mark.parametrize("range_mm", [1000.0, 5000.0])
def test_noise_free_recovery_from_random_starts(range_mm, rng):
    ds = _room(range_mm=range_mm)
    truth = ds.params.to_identifiable()
    pose = _true_pose(ds.calibration)
    n_ok = 0
    for _ in range(20):
        init = bc.SensorParams.from_array(ds.params.to_array() * (1 + rng.uniform(-0.1, 0.1, 8)))
        res = bc.calibrate_sequential(ds, init=init)
        ok = (np.allclose(res.params.to_identifiable(), truth, rtol=1e-6, atol=0)
              and np.allclose(res.extras["pose"], pose, rtol=1e-6, atol=0))
        n_ok += ok
        assert res.converged and res.method == "sequential"
    # Every start within +-10 % lies in the basin of the single (convex near the truth)
    # minimum: require all 20; a failure means the solver, not luck.
    assert n_ok == 20
    # the room is reconstructed exactly with the recovered sensor
    np.testing.assert_allclose(bc.reconstruction_error(res.points, ds.points), 0.0,
                               atol=1e-6 * range_mm)


def test_fix_phi_changes_alpha_only():
    ds = _room()
    r0 = bc.calibrate_sequential(ds)
    r1 = bc.calibrate_sequential(ds, fix_phi=0.5)
    assert r1.params.phi == 0.5
    np.testing.assert_allclose(r1.params.to_identifiable(), r0.params.to_identifiable(),
                               rtol=1e-10)
    np.testing.assert_allclose(r1.params.alpha_u, r0.params.alpha_u / 1.5, rtol=1e-10)
    np.testing.assert_allclose(r1.points, r0.points, rtol=1e-10)
    assert r1.covariance()[1, 1] == 0.0 and np.isnan(r1.correlation[1]).all()


def test_trf_and_restarts_agree_with_lm():
    ds = _room(sigma_px=0.5, rng=3)
    a = bc.calibrate_sequential(ds)
    b = bc.calibrate_sequential(ds, method="trf", restarts=2, rng=1)
    np.testing.assert_allclose(b.params.to_identifiable(), a.params.to_identifiable(),
                               rtol=1e-7)


def test_calibration_data_alone_gives_no_points():
    ds = _room()
    res = bc.calibrate_sequential(ds.calibration)
    assert res.points is None
    np.testing.assert_allclose(res.params.to_identifiable(), ds.params.to_identifiable(),
                               rtol=1e-6)


# ----------------------------------------------------------------------------- plane fit
def _laser_on_known_plane(ds, m, e, n_per_wall=12):
    """Calibration data whose laser lies on the plane m . P = e (frame C)."""
    c = ds.calibration
    R = rotation_matrix(c.angles)
    d = _calib_distance(c)
    pts, idx = [], []
    for j, n_w in enumerate(CALIB_NORMALS_W):
        n_c = R @ n_w
        o = d + n_c @ c.translation
        p0 = np.linalg.lstsq(np.stack([n_c, m]), np.array([o, e]), rcond=None)[0]
        u = np.cross(n_c, m)
        u /= np.linalg.norm(u)
        s = np.linspace(-0.7 * d, 0.7 * d, n_per_wall)
        pts.append(p0 + s[:, None] * u)
        idx.append(np.full(n_per_wall, j))
    pts = np.concatenate(pts)
    c2 = dataclasses.replace(c, laser_points_true=pts, laser_plane=np.concatenate(idx),
                             laser_pixels=bc.project(ds.params, pts))
    return c2


def test_plane_fit_recovers_a_known_laser_plane():
    ds = _room()
    m = np.array([0.04, -0.03, 1.0])
    m /= np.linalg.norm(m)
    calib = _laser_on_known_plane(ds, m, -150.0)
    plane_true = np.append(m, 150.0)                      # m . P + 150 = 0, d >= 0
    room = dataclasses.replace(ds, calibration=calib)
    res = bc.calibrate_sequential(room, fit="plane")
    np.testing.assert_allclose(res.extras["laser_plane"], plane_true, rtol=0, atol=1e-8)
    assert res.extras["laser_model"] == "plane" and res.residual_rms["plane_mm"] < 1e-8
    # h and beta are not estimated: copied from init, NaN in the covariance
    assert res.params.h == bc.SensorParams.paper().h
    assert np.isnan(res.covariance()[6:, :]).all() and np.isfinite(res.covariance()[:6, :6]).all()
    expected = bc.triangulate_plane(ds.params, ds.pixels, plane_true)
    np.testing.assert_allclose(res.points, expected, rtol=1e-8, atol=1e-6)


def test_cone_fit_of_a_plane_raises_with_flagged_result():
    ds = _room()
    calib = _laser_on_known_plane(ds, np.array([0.0, 0.0, 1.0]), -150.0)
    with pytest.raises(bc.ConvergenceError, match=r"beta >= pi/2.*fit='plane'") as info:
        bc.calibrate_sequential(calib)
    res = info.value.result
    assert not res.converged and res.extras["theta_raw"][6] >= np.pi / 2
    # the stage-1 camera is still reported, h and beta fall back to init (not estimated)
    np.testing.assert_allclose(res.params.to_identifiable()[:5],
                               ds.params.to_identifiable()[:5], rtol=1e-6)
    assert res.params.beta == bc.SensorParams.paper().beta and np.isnan(res.std[7])


def test_fit_plane_on_noisy_points_and_bad_input(rng):
    xy = rng.uniform(-500, 500, (200, 2))
    z = 0.1 * xy[:, 0] - 0.2 * xy[:, 1] - 300.0
    n = np.array([0.1, -0.2, -1.0])
    n /= -np.linalg.norm(n)                                # orientation with d >= 0
    pts = np.column_stack([xy, z]) + n * rng.normal(0, 2.0, 200)[:, None]
    plane, rms = fit_plane(pts)
    np.testing.assert_allclose(plane[:3], n, atol=5e-3)
    np.testing.assert_allclose(plane[3], 300.0 / np.linalg.norm([0.1, -0.2, -1.0]), rtol=0.02)
    # rms of N(0, 2) normal offsets from 200 points: 2 +- 0.1 (sd); 5 sd below/above
    assert 1.5 < rms < 2.5
    with pytest.raises(ValueError, match="on a line"):
        fit_plane(np.outer(np.arange(5.0), [1.0, 2.0, 3.0]))
    with pytest.raises(ValueError, match=r"K >= 3"):
        fit_plane(np.zeros((2, 3)))


# ----------------------------------------------------------------------------- covariance
def _refit_spread(n_fits, range_mm=1000.0, sigma_px=0.5, seed=11):
    """Re-fit on fresh pixel noise; return estimates, predicted sds and noise estimates."""
    seeds = np.random.SeedSequence(seed).spawn(n_fits)
    est, sd, sig = [], [], []
    for s in seeds:
        ds = _room(range_mm=range_mm, sigma_px=sigma_px, rng=np.random.default_rng(s),
                   n_points=20)
        res = bc.calibrate_sequential(ds)
        est.append(np.r_[res.params.to_identifiable(), res.extras["pose"]])
        sd.append(np.sqrt(np.r_[np.diag(res.covariance_identifiable),
                                np.diag(res.extras["pose_covariance"])]))
        sig.append(res.sigma_px_estimated)
    return np.array(est), np.array(sd), np.array(sig)


def _check_spread(est, sd, lo, hi):
    observed = est.std(axis=0, ddof=1)
    predicted = np.sqrt(np.mean(sd**2, axis=0))
    ratio = observed / predicted
    names = IDENTIFIABLE_NAMES + sequential.POSE_NAMES
    bad = {n: round(float(r), 3) for n, r in zip(names, ratio, strict=True)
           if not lo < r < hi}
    assert not bad, f"observed/predicted sd outside ({lo:.3f}, {hi:.3f}): {bad}"


def test_covariance_matches_refit_spread_large_room_fast():
    n = 40
    est, sd, sig = _refit_spread(n, range_mm=5000.0)
    # For Gaussian estimates, (n-1) s^2 / sigma^2 ~ chi2(n-1). Two-sided bounds at 1e-4 per
    # quantity; 13 quantities (Bonferroni): false failure < 1.3e-3 per run.
    lo = np.sqrt(stats.chi2.ppf(0.5e-4, n - 1) / (n - 1))
    hi = np.sqrt(stats.chi2.ppf(1 - 0.5e-4, n - 1) / (n - 1))
    _check_spread(est, sd, lo, hi)
    # sigma estimate: each has relative sd ~ 1/sqrt(2 * 269) = 4.3 %; the mean of 40 has
    # 0.7 %, so 10 % is > 14 sd: a failure means a biased estimator, not bad luck.
    np.testing.assert_allclose(sig.mean(), 0.5, rtol=0.10)


def test_covariance_matches_refit_spread_200():
    # ~15 s on one core: run by default (the large-room check above is the quick one)
    est, sd, sig = _refit_spread(200, seed=12)
    # 20 % of the predicted sd: with 199 dof, s/sigma < 0.8 has p ~ 1e-6 and > 1.2 has
    # p ~ 5e-5 per quantity; 13 quantities: false failure < 1e-3 per run.
    _check_spread(est, sd, 0.8, 1.2)
    np.testing.assert_allclose(sig.mean(), 0.5, rtol=0.10)
    # every single estimate within 10 % as well (p(|z| > 2.3) ~ 2 % each would fail too
    # often), so only the fraction outside is checked: binomial(200, 0.021) <= 12 at 1 - 1e-3
    assert np.mean(np.abs(sig / 0.5 - 1) > 0.10) <= 12 / 200


def test_single_noise_estimate_and_fields():
    ds = _room(sigma_px=0.5, rng=5)
    res = bc.calibrate_sequential(ds)
    m = ds.calibration.grid_pixels.size
    assert res.extras["stage1"]["n_residuals"] == m and res.extras["stage1"]["n_unknowns"] == 11
    rms = res.residual_rms["pixel_px"]
    np.testing.assert_allclose(res.sigma_px_estimated, rms / np.sqrt(1 - 11 / m), rtol=1e-12)
    # relative sd of the estimate ~ 1/sqrt(2 * 269) = 4.3 %; 25 % is 5.8 sd
    np.testing.assert_allclose(res.sigma_px_estimated, 0.5, rtol=0.25)
    # stage 2 fits within pixel noise and stage-1 uncertainty: chi2(78) / 78; two-sided
    # bounds at 1e-4 each (false failure 2e-4)
    dof = res.extras["stage2"]["n_residuals"] - 2
    lo, hi = stats.chi2.ppf([1e-4, 1 - 1e-4], dof) / dof
    assert lo < res.extras["stage2"]["chi2_per_dof"] < hi
    # the covariance with a given sigma_px scales as sigma_px^2 in stage 1
    r2 = bc.calibrate_sequential(ds, sigma_px=1.0)
    np.testing.assert_allclose(r2.extras["stage1_covariance"],
                               res.extras["stage1_covariance"] / res.sigma_px_estimated**2,
                               rtol=1e-8)
    cov = res.covariance()
    np.testing.assert_allclose(cov, cov.T, rtol=0, atol=1e-12 * np.abs(cov).max())
    assert np.all(np.linalg.eigvalsh(res.covariance_identifiable) > 0)
    assert res.covariance()[1, 1] == 0.0                    # phi fixed
    assert "xi" in res.summary() and "fixed" in res.summary()


def test_identifiability_report_names_phi_alpha_ridge():
    res = bc.calibrate_sequential(_room(sigma_px=0.5, rng=6))
    rep = res.identifiability
    assert len(rep.null_directions) == 1
    comps = rep.null_directions[0]["components"]
    assert set(comps) == {"phi", "alpha_u", "alpha_v"}
    assert "phi" in str(rep) and "alpha_u" in str(rep)


def test_reconstruction_improves_with_less_noise():
    big = bc.calibrate_sequential(_room(sigma_px=1.0, rng=9, n_points=100))
    small = bc.calibrate_sequential(_room(sigma_px=0.01, rng=9, n_points=100))
    ds_small = _room(sigma_px=0.01, rng=9, n_points=100)
    ds_big = _room(sigma_px=1.0, rng=9, n_points=100)
    e_big = bc.reconstruction_error(big.points, ds_big.points)
    e_small = bc.reconstruction_error(small.points, ds_small.points)
    # errors scale ~ linearly with pixel noise (fact 2 of docs/model.md,
    # "Measured facts": ~41 mm mean error per px of noise at 1000 mm)
    assert e_small < 0.05 * e_big and 5.0 < e_big < 150.0


def test_approximate_patterns_are_used_as_given_and_hurt():
    # the paper's Fig. 9 point: the sequential method trusts the measured pattern points
    exact = _room(range_mm=5000.0, sigma_px=0.1, rng=1, n_points=100)
    approx = _room(range_mm=5000.0, sigma_px=0.1, rng=1, n_points=100, approx_error=0.05)
    r0, r5 = bc.calibrate_sequential(exact), bc.calibrate_sequential(approx)
    e0 = bc.reconstruction_error(r0.points, exact.points)
    e5 = bc.reconstruction_error(r5.points, approx.points)
    # over seeds 0-3 the ratio was 5.7-11 (e0 ~ 94-111 mm at 0.1 px): 3 leaves margin
    assert e5 > 3 * e0
    # the 3D errors of the patterns show up as excess pixel residuals in stage 1
    assert r5.sigma_px_estimated > 10 * r0.sigma_px_estimated


# ----------------------------------------------------------------------------- bad input
def test_bad_input_errors():
    ds = _room()
    c = ds.calibration
    gp = c.grid_pixels.copy()
    gp[3, 1] = np.nan
    with pytest.raises(ValueError, match=r"grid_pixels must contain only finite"):
        bc.calibrate_sequential(dataclasses.replace(c, grid_pixels=gp))
    with pytest.raises(ValueError, match=r"matching lengths"):
        bc.calibrate_sequential(dataclasses.replace(c, grid_pixels=c.grid_pixels[:-1]))
    with pytest.raises(ValueError, match=r"laser_pixels .* matching lengths"):
        bc.calibrate_sequential(dataclasses.replace(c, laser_plane=c.laser_plane[:-1]))
    few = dataclasses.replace(c, grid_points=c.grid_points[:5], grid_pixels=c.grid_pixels[:5],
                              grid_plane=c.grid_plane[:5])
    with pytest.raises(ValueError, match=r"too few grid points: .* has 5"):
        bc.calibrate_sequential(few)
    with pytest.raises(ValueError, match=r"dataset has no calibration data"):
        bc.calibrate_sequential(dataclasses.replace(ds, calibration=None))
    with pytest.raises(TypeError, match=r"dataset must be a bayescal.Dataset"):
        bc.calibrate_sequential({"grid_points": c.grid_points})
    px = ds.pixels.copy()
    px[0] = np.nan
    with pytest.raises(ValueError, match=r"dataset.pixels must contain only finite"):
        bc.calibrate_sequential(dataclasses.replace(ds, pixels=px))
    with pytest.raises(ValueError, match=r"fit must be one of"):
        bc.calibrate_sequential(c, fit="quadric")
    with pytest.raises(ValueError, match=r"sigma_px must be a finite positive"):
        bc.calibrate_sequential(c, sigma_px=-1.0)
    with pytest.raises(ValueError, match=r"init_pose must have shape \(6,\)"):
        bc.calibrate_sequential(c, init_pose=[0.0, 0.0])
    with pytest.raises(TypeError, match=r"init must be a SensorParams"):
        bc.calibrate_sequential(c, init=[1.0] * 8)
    with pytest.raises(ValueError, match=r"max_nfev must be an integer >= 1, got 0"):
        bc.calibrate_sequential(c, max_nfev=0)
    with pytest.raises(ValueError, match=r"restarts must be an integer >= 0, got 1.5"):
        bc.calibrate_sequential(c, restarts=1.5)
    with pytest.raises(ValueError, match=r"fix_phi must be finite with xi \+ fix_phi > 0"):
        bc.calibrate_sequential(c, fix_phi=-1.0)
    with pytest.raises(ValueError, match=r"method must be one of"):
        bc.calibrate_sequential(c, method="dogbox")
    sparse = dataclasses.replace(c, grid_plane=np.where(c.grid_plane == 2, 1, c.grid_plane))
    with pytest.raises(ValueError, match=r"calibration plane 2 carries laser pixels"):
        bc.calibrate_sequential(sparse)


def test_no_convergence_raises_with_flagged_result():
    ds = _room(sigma_px=0.5)
    init = bc.SensorParams.paper().replace(xi=0.9, u0=380.0)
    with pytest.raises(bc.ConvergenceError, match=r"stage 1 .* did not converge") as info:
        bc.calibrate_sequential(ds, init=init, max_nfev=2)
    res = info.value.result
    assert isinstance(res, bc.CalibrationResult) and not res.converged
    assert "NOT CONVERGED" in res.summary()


# ----------------------------------------------------------------------------- residuals
def _mean_squares(fit, seeds, sigma_px=0.5):
    g, laser = [], []
    for seed in seeds:
        ds = _room(sigma_px=sigma_px, rng=seed, n_points=20)
        if fit == "plane":
            m = np.array([0.04, -0.03, 1.0]) / np.linalg.norm([0.04, -0.03, 1.0])
            calib = _laser_on_known_plane(ds, m, -150.0)
            noise = np.random.default_rng(seed).normal(0.0, sigma_px, calib.laser_pixels.shape)
            calib = dataclasses.replace(calib, laser_pixels=calib.laser_pixels + noise)
            ds = dataclasses.replace(ds, calibration=calib)
        s = bc.sequential_residuals(bc.calibrate_sequential(ds, sigma_px=sigma_px, fit=fit))
        assert s.grid_z.shape == s.grid_px.shape and s.laser_z.shape == s.laser_mm.shape
        g.append(np.mean(s.grid_z**2))
        laser.append(np.mean(s.laser_z**2))
    return np.mean(g), np.mean(laser)


@pytest.mark.parametrize("fit", ["cone", "plane"])
def test_standardized_residuals_have_unit_variance(fit):
    """Exact pattern points, the true pixel noise given: each standardized residual is N(0, 1)
    to first order, so the mean square over 10 datasets is 1 within sampling error. Grid: 280
    residuals a dataset, sd of one mean square sqrt(2/280) = 0.085; stage 2: 80 residuals
    correlated through the shared stage-1 error, measured sd 0.18 over 30 datasets (0.158 if
    independent). Over 10 datasets the bounds below are ~4 sd: FFR ~1e-4 per check."""
    g, laser = _mean_squares(fit, range(100, 110))
    assert abs(g - 1.0) < 4 * 0.085 / np.sqrt(10)
    assert abs(laser - 1.0) < 4 * 0.2 / np.sqrt(10)


def test_residuals_show_pattern_errors_the_method_does_not_model():
    """5 % errors on the measured pattern points (~40 mm at 800 mm, i.e. pixels off by ~1 px
    against 0.1 px of noise): the standardized residuals are far wider than N(0, 1), as the
    residual plot must show (measured mean squares ~500 and ~80)."""
    s = bc.sequential_residuals(bc.calibrate_sequential(
        _room(sigma_px=0.1, rng=1, n_points=20, approx_error=0.05), sigma_px=0.1))
    assert np.mean(s.grid_z**2) > 10 and np.mean(s.laser_z**2) > 10


def test_residuals_survive_save_and_load(tmp_path):
    res = bc.calibrate_sequential(_room(sigma_px=0.5, rng=3, n_points=20))
    loaded = bc.load_result(res.save(tmp_path / "seq.json"))
    for a, b in zip(bc.sequential_residuals(res), bc.sequential_residuals(loaded), strict=True):
        np.testing.assert_array_equal(a, b)
    assert loaded.extras["sigma_px_used"] == res.extras["sigma_px_used"]


def test_sequential_residuals_refuses_other_results():
    ds = _room(sigma_px=0.5, rng=3, n_points=20)
    sim = bc.calibrate_simultaneous(ds.pixels, ds.approx_points, sigma_px=0.5,
                                    sigma_scene=np.maximum(ds.sigma_scene, 1.0))
    with pytest.raises(ValueError, match="calibrate_sequential"):
        bc.sequential_residuals(sim)
    with pytest.raises(TypeError, match="CalibrationResult"):
        bc.sequential_residuals({"method": "sequential"})
    seq = bc.calibrate_sequential(ds)
    seq.extras.pop("stage2_residuals_std")
    with pytest.raises(ValueError, match="stage2_residuals_std"):
        bc.sequential_residuals(seq)
