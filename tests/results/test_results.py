"""Result type: identifiability report, 8x8 covariance from the identifiable one, properties."""

import numpy as np
import pytest

import bayescal as bc
import bayescal.sensor.parameters as parameters
from bayescal.results.calibration import (
    covariance_8_from_identifiable,
    identifiable_to_paper_jacobian,
)
from bayescal.sensor.camera import project_theta
from bayescal.sensor.parameters import PARAM_NAMES, from_identifiable


def test_report_finds_an_exact_linear_dependence(rng):
    J = rng.normal(size=(50, 4))
    J[:, 3] = 2.0 * J[:, 0] - 0.5 * J[:, 2]
    rep = bc.identifiability_report(J, ["a", "b", "c", "d"])
    assert len(rep.null_directions) == 1 and rep.condition_number > 1e12
    comps = rep.null_directions[0]["components"]
    assert set(comps) == {"a", "c", "d"}                  # b is not involved
    # the null vector in scaled coordinates: w_j ~ v_j * |J_j|
    v = np.array([2.0, 0.0, -0.5, -1.0]) * np.linalg.norm(J, axis=0)
    v /= np.linalg.norm(v) * np.sign(v[np.argmax(np.abs(v))])
    np.testing.assert_allclose([comps[n] for n in "acd"], v[[0, 2, 3]], rtol=1e-8)
    assert np.all(np.diff(rep.singular_values) <= 0)
    text = str(rep)
    assert "near-null direction 1" in text
    undetermined = text.split("not determined by the data: ")[1].split(", ")
    assert sorted(undetermined) == ["a", "c", "d"]


def test_report_full_rank_and_zero_column(rng):
    J = rng.normal(size=(30, 3))
    rep = bc.identifiability_report(J, ["a", "b", "c"])
    assert rep.null_directions == [] and "no near-null direction" in str(rep)
    assert np.isfinite(rep.condition_number)
    J[:, 1] = 0.0
    rep = bc.identifiability_report(J, ["a", "b", "c"])
    assert rep.null_directions[0]["components"] == {"b": 1.0}
    assert rep.condition_number == np.inf


def test_report_scale_makes_units_irrelevant(rng):
    J = rng.normal(size=(40, 3))
    J[:, 2] = J[:, 0] + 1e-4 * rng.normal(size=40)        # nearly dependent
    a = bc.identifiability_report(J, "xyz", rtol=1e-2)
    # the same problem with column 1 expressed in units 1e6 times smaller
    J2 = J * np.array([1.0, 1e6, 1.0])
    b = bc.identifiability_report(J2, "xyz", rtol=1e-2)
    np.testing.assert_allclose(a.singular_values, b.singular_values, rtol=1e-10)
    # an explicit scale equal to the column norms is the default
    c = bc.identifiability_report(J2, "xyz", rtol=1e-2, scale=np.linalg.norm(J2, axis=0))
    np.testing.assert_allclose(c.singular_values, b.singular_values, rtol=1e-12)
    assert set(a.null_directions[0]["components"]) == {"x", "z"}


def test_report_fewer_residuals_than_columns():
    rep = bc.identifiability_report(np.array([[1.0, 1.0, 0.0]]), "abc")
    assert len(rep.singular_values) == 3 and len(rep.null_directions) == 2


def test_report_bad_input():
    with pytest.raises(ValueError, match=r"names must have one entry per jacobian column \(2\)"):
        bc.identifiability_report(np.eye(2), ["a"])
    with pytest.raises(ValueError, match=r"jacobian must have shape \(n_residuals, n_params\)"):
        bc.identifiability_report(np.ones(3), ["a"])
    with pytest.raises(ValueError, match=r"rtol must lie in \(0, 1\)"):
        bc.identifiability_report(np.eye(2), "ab", rtol=2.0)
    with pytest.raises(ValueError, match=r"scale must have shape \(2,\)"):
        bc.identifiability_report(np.eye(2), "ab", scale=[1.0])
    with pytest.raises(ValueError, match=r"jacobian must contain only finite"):
        bc.identifiability_report([[np.nan, 1.0]], "ab")


def test_report_on_8_parameter_jacobian_names_phi_alpha(sensor, rng):
    pts = rng.uniform(-1000, 1000, (60, 3))
    pts[:, 2] = np.hypot(pts[:, 0], pts[:, 1]) / np.tan(sensor.beta) - sensor.h
    _, _, _, dth = project_theta(sensor.to_identifiable(), pts, jacobian=True)
    J7 = dth.reshape(-1, 7)[:, :5]                        # pixels see the camera only
    J8 = J7 @ identifiable_to_paper_jacobian(sensor)[:5, :6]
    rep = bc.identifiability_report(J8, PARAM_NAMES[:6])
    assert len(rep.null_directions) == 1
    assert set(rep.null_directions[0]["components"]) == {"phi", "alpha_u", "alpha_v"}
    for name in ("phi", "alpha_u", "alpha_v"):
        assert name in str(rep)


def test_identifiable_to_paper_jacobian_matches_finite_differences(sensor, numdiff):
    fd = numdiff(lambda a: parameters.to_identifiable(a), sensor.to_array(), 1e-6)
    np.testing.assert_allclose(identifiable_to_paper_jacobian(sensor), fd, rtol=1e-8, atol=1e-8)


def test_covariance_8_matches_finite_difference_propagation(sensor, rng, numdiff):
    theta = sensor.to_identifiable()
    A = rng.normal(size=(7, 7)) * np.r_[1e-3, 0.3, 0.3, 0.2, 0.2, 5.0, 1e-2]
    cov7 = A @ A.T
    var_phi = 0.01
    got = covariance_8_from_identifiable(theta, sensor.phi, cov7, var_phi)
    J = numdiff(lambda x: from_identifiable(x[:7], x[7]), np.r_[theta, sensor.phi], 1e-6)
    C = np.zeros((8, 8))
    C[:7, :7], C[7, 7] = cov7, var_phi
    np.testing.assert_allclose(got, J @ C @ J.T, rtol=1e-6, atol=1e-12)
    # phi fixed: no variance for phi, alpha keeps the gamma / (xi + phi) uncertainty only
    fixed = covariance_8_from_identifiable(theta, sensor.phi, cov7, 0.0)
    assert fixed[1, 1] == 0.0 and np.all(fixed[1] == 0.0)
    np.testing.assert_allclose(np.delete(np.delete(fixed, [1, 2, 3], 0), [1, 2, 3], 1),
                               np.delete(np.delete(cov7, [1, 2], 0), [1, 2], 1), rtol=1e-12)


def test_covariance_8_keeps_nan_confined_and_checks_input():
    theta = bc.SensorParams.paper().to_identifiable()
    cov7 = np.full((7, 7), np.nan)
    cov7[:5, :5] = np.eye(5)
    out = covariance_8_from_identifiable(theta, 0.0, cov7, 0.0)
    assert np.isnan(out[6:]).all() and np.isnan(out[:, 6:]).all()
    assert np.isfinite(out[:6, :6]).all()
    with pytest.raises(ValueError, match=r"cov7 must have shape \(7, 7\)"):
        covariance_8_from_identifiable(theta, 0.0, np.eye(6), 0.0)
    with pytest.raises(ValueError, match=r"var_phi must be a non-negative variance"):
        covariance_8_from_identifiable(theta, 0.0, np.eye(7), -1.0)


def _result(cov8, converged=True):
    p = bc.SensorParams.paper()
    rep = bc.identifiability_report(np.eye(2), "ab")
    return bc.CalibrationResult(
        method="sequential", params=p, points=None, covariance=cov8,
        covariance_identifiable=np.eye(7), residual_rms={"pixel_px": 0.5},
        sigma_px_estimated=0.51, n_residuals=100, n_unknowns=11, converged=converged,
        message="ok", nfev=7, identifiability=rep)


def test_result_std_correlation_summary():
    sd = np.array([0.1, 0.0, 2.0, 2.0, 1.0, 1.0, 3.0, 0.01])
    corr = np.eye(8)
    corr[2, 3] = corr[3, 2] = -0.5
    res = _result(corr * np.outer(sd, sd))
    np.testing.assert_allclose(res.std, sd, rtol=1e-15)
    c = res.correlation
    assert np.isnan(c[1]).all() and np.isnan(c[:, 1]).all()
    keep = [0, 2, 3, 4, 5, 6, 7]
    np.testing.assert_allclose(c[np.ix_(keep, keep)], corr[np.ix_(keep, keep)], rtol=1e-12)
    text = res.summary()
    for name in PARAM_NAMES:
        assert name in text
    assert "fixed" in text and "converged" in text and "0.51" in text
    assert res.extras == {}


def test_convergence_error_carries_result():
    res = _result(np.eye(8), converged=False)
    err = bc.ConvergenceError("did not converge", res)
    assert isinstance(err, RuntimeError) and err.result is res
    assert "NOT CONVERGED" in res.summary()


# -- the shared vocabulary ---------------------------------------------------------------

def _simultaneous_result():
    import bayescal as bc

    ds = bc.simulate_room(range_mm=1000, n_points=60, sigma_px=0.2, approx_error=0.01, rng=2)
    return ds, bc.calibrate_simultaneous(ds.pixels, ds.approx_points, sigma_px=0.2,
                                         sigma_scene=np.maximum(ds.sigma_scene, 1.0))


def test_calibration_result_vocabulary_and_round_trip(tmp_path):
    import bayescal as bc

    ds, res = _simultaneous_result()
    assert res.covariance().shape == (8, 8) and res.covariance(identifiable=True).shape == (7, 7)
    assert res.points.shape == (60, 3) and res.point_covariance().shape == (60, 3, 3)
    mean, cov = res.reconstruct(ds.pixels[:4], sigma_px=0.0)
    np.testing.assert_allclose(mean, bc.triangulate(res.params, ds.pixels[:4]), rtol=1e-12)
    assert cov.shape == (4, 3, 3) and isinstance(res.summary(), str)
    d = res.to_dict()
    assert d["format"] == "bayescal-result" and d["version"] == 1
    back = bc.load_result(res.save(tmp_path / "r.json"))
    np.testing.assert_array_equal(back.covariance(), res.covariance())
    np.testing.assert_array_equal(back.points, res.points)
    np.testing.assert_array_equal(back.point_covariance(), res.point_covariance())
    assert back.params == res.params and back.summary() == res.summary()
    with pytest.raises(FileExistsError, match="overwrite=True"):
        res.save(tmp_path / "r.json")


@pytest.mark.parametrize("text, match", [
    ("{not json", "not valid JSON"),
    ('{"format": "other"}', "not a bayescal result file"),
    ('{"format": "bayescal-result", "version": 99}', "format version 99"),
    ('{"format": "bayescal-result", "version": 1, "method": "x"}', "damaged"),
])
def test_load_result_refuses_foreign_files(tmp_path, text, match):
    import bayescal as bc

    (tmp_path / "r.json").write_text(text)
    with pytest.raises(ValueError, match=match):
        bc.load_result(tmp_path / "r.json")


def test_posterior_speaks_the_same_vocabulary():
    import bayescal as bc

    assert isinstance(bc.Posterior.params, property) and isinstance(bc.Posterior.points, property)
    for name in ("covariance", "point_covariance", "reconstruct", "summary", "to_dict", "save"):
        assert callable(getattr(bc.Posterior, name)) and callable(getattr(bc.CalibrationResult,
                                                                           name))


@pytest.mark.parametrize("module", ["arviz", "arviz_base"])
def test_to_inference_data(module):
    """ArviZ 0.x (``from_dict(posterior=...)``) and the >= 1.0 interface of arviz_base
    (``from_dict({"posterior": ...})``, what ArviZ 1.x re-exports), both in the test extra."""
    import importlib
    import warnings

    from bayescal.results.export import to_inference_data

    with warnings.catch_warnings():
        warnings.simplefilter("ignore", FutureWarning)
        mod = importlib.import_module(module)
    ds = bc.simulate_room(range_mm=1000, n_points=20, sigma_px=0.5, approx_error=0.01, rng=1)
    post = bc.sample_posterior(ds.pixels, ds.approx_points, sigma_px=0.5,
                               sigma_scene=np.maximum(ds.sigma_scene, 1.0), rng=1, max_steps=400,
                               progress=False)
    idata = to_inference_data(post, module=mod)
    assert idata.posterior["h"].shape == (1, post.n_samples)
    assert idata.posterior["points"].shape == (1, post.n_samples, 20, 3)
    np.testing.assert_array_equal(np.asarray(idata.posterior["h"])[0], post.param_samples[:, 6])
    if module == "arviz":
        assert post.to_inference_data().posterior["h"].shape == (1, post.n_samples)
