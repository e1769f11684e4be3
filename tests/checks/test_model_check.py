"""result.model_check(): the predictive check on every result type, from Python."""

import numpy as np
import pytest

import bayescal as bc
from bayescal.checks import model as model_mod


@pytest.fixture(scope="module")
def room():
    return bc.simulate_room(range_mm=1000, n_points=150, sigma_px=0.5, approx_error=0.01,
                            approx_model="gaussian", rng=2)


def _lsq(ds, **kw):
    kw.setdefault("sigma_px", 0.5)
    kw.setdefault("sigma_scene", ds.sigma_scene)
    return bc.calibrate_simultaneous(ds.pixels, ds.approx_points, **kw)


def test_least_squares_fits_its_own_model(room):
    chk = _lsq(room).model_check()
    assert isinstance(chk, model_mod.ModelCheck) and chk.fits, chk.message
    assert set(chk.p_values) >= {"chi2", "tail"}
    assert chk.point_chi2.shape == chk.azimuth.shape == (150,)
    assert str(chk) == chk.message and chk["fits"] is chk.fits


def test_wrong_noise_level_does_not_fit(room):
    """The pixels carry 0.5 px; a fit told 0.2 px must be refused by the check; told
    0.1 px (residuals > 2x the noise given, pixel and scene rows together), the fit
    itself is not called converged."""
    with pytest.raises(bc.ConvergenceError, match="times the noise given"):
        _lsq(room, sigma_px=0.1)
    res = _lsq(room, sigma_px=0.1, raise_on_failure=False)
    assert not res.converged and "too small" in res.message
    chk = _lsq(room, sigma_px=0.2).model_check()
    assert not chk.fits and chk.message.startswith("MODEL DOES NOT FIT")
    assert chk.p_values["chi2"] < 0.01


def test_inferred_noise_and_a_floor_plan_and_a_posterior(room):
    assert _lsq(room, sigma_px=None, sigma_scene=None).model_check().fits
    plan = bc.FloorPlan(room.floor_plan.walls, distance_sd=20.0, angle_sd=0.01)
    assert bc.calibrate_simultaneous(room.pixels, plan, sigma_px=0.5).model_check().fits
    post = bc.sample_posterior(room.pixels, room.approx_points, sigma_px=0.5,
                               sigma_scene=room.sigma_scene, rng=1, min_ess=200,
                               n_samples=200, progress=False)
    chk = post.model_check()
    assert chk.fits, chk.message


def test_saved_result_keeps_what_its_check_needs(room, tmp_path):
    res = _lsq(room)
    back = bc.load_result(res.save(tmp_path / "r.json"))
    a, b = res.model_check(), back.model_check()
    assert a.p_values == pytest.approx(b.p_values)


def test_targeted_statistics_plug_in(room, monkeypatch):
    """A model variant adds its statistic to STATISTICS; a failing one fails the check."""
    def always_bad(result, check):
        return {"name": "harmonic", "p_value": 1e-5, "observed": 3.0, "expected": 1.0,
                "message": "a structure in azimuth: try the other model"}

    monkeypatch.setattr(model_mod, "STATISTICS", [always_bad])
    chk = _lsq(room).model_check()
    assert not chk.fits and "harmonic" in chk.p_values
    assert chk.message == "MODEL DOES NOT FIT; a structure in azimuth: try the other model"


def test_sequential_and_old_files_say_what_to_do(room, tmp_path):
    with pytest.raises(ValueError, match="sequential_residuals"):
        bc.calibrate_sequential(room).model_check()
    res = _lsq(room)
    del res.extras["pixels"]
    with pytest.raises(ValueError, match="pass pixels"):
        res.model_check()
    assert res.model_check(pixels=room.pixels, approx_points=room.approx_points).fits
    np.testing.assert_array_equal(res.points.shape, (150, 3))
