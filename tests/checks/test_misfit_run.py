"""The model check's run statistic (``misfit_run``): a run of neighbouring points holding
much of the misfit fails the least squares' own check (docs/robustness.md, 4c)."""

import dataclasses
import warnings

import numpy as np
import pytest

import bayescal as bc
from bayescal.checks.misfit import MISFIT_ALPHA, misfit_run_p
from bayescal.validation.corruption import corrupt


def _ring(n, rng):
    """Misfits of independent points (chi-square, 3 dof) and the ranges of a square room's
    walls seen in azimuth order (1000 mm to each wall)."""
    phi = np.sort(rng.uniform(-np.pi, np.pi, n))
    rho = 1000.0 / np.maximum(np.abs(np.cos(phi)), np.abs(np.sin(phi)))
    return rng.chisquare(3, n), rho


@pytest.mark.parametrize("seed", range(5))
def test_independent_misfits_are_not_a_run(seed):
    m, rho = _ring(300, np.random.default_rng(seed))
    p, rows = misfit_run_p(m, rho)
    assert p > 1e-3
    assert len(rows) in (8, 16, 32)


def test_a_noise_scale_that_changes_with_range_is_not_a_run():
    # isotropic errors fitted as relative ones in a long room (walls 1000 and 3000 mm from
    # the axis): the near walls' points misfit up to 9x the far ones'; divided by its trend
    # in range that is no run; taken as it is it looks like one (p 1e-4 to 9e-3 over seeds
    # 0-4 of this test)
    rng = np.random.default_rng(7)
    phi = np.sort(rng.uniform(-np.pi, np.pi, 300))
    rho = 1.0 / np.maximum(np.abs(np.cos(phi)) / 3000.0, np.abs(np.sin(phi)) / 1000.0)
    m = rng.chisquare(3, 300) * (3000.0 / rho) ** 2
    assert misfit_run_p(m, rho)[0] > 1e-3
    assert misfit_run_p(m, np.full(300, 1000.0))[0] < 0.01


def test_a_run_of_raised_misfit_is_found():
    rng = np.random.default_rng(3)
    m, rho = _ring(300, rng)
    m[140:155] *= 5.0                                   # 15 rows each ~2-4 sds off
    p, rows = misfit_run_p(m, rho)
    assert p < MISFIT_ALPHA
    assert np.isin(np.arange(140, 155), rows).mean() >= 0.5
    m[100] = np.nan                                     # a point left out
    assert misfit_run_p(m, rho)[0] < MISFIT_ALPHA
    assert misfit_run_p(m[:20], rho[:20]) == (1.0, pytest.approx(np.zeros(0)))   # too few
    with pytest.raises(bc.errors.InvalidValueError, match="shape"):
        misfit_run_p(m, rho[:-1])


def _streak_room():
    """The harness's silent wrong answer (studies/robust_rooms.py, room 11 of ``simulate``):
    a 3-px streak of 15 rows at 1000 mm, isotropic 16-mm points, the noise inferred."""
    g = np.random.default_rng([0, 11])
    params = bc.SensorParams.from_array(bc.Prior().sample(rng=g))
    range_mm, walls = float(g.choice([1000.0, 1500.0, 2500.0, 4000.0])), int(g.integers(5, 8))
    ds = bc.simulate_room(params, range_mm=range_mm, n_points=300, n_walls=walls,
                          sigma_px=0.2, approx_error=0.02, approx_model="gaussian", rng=11)
    sd = 0.016 * range_mm
    apx = ds.points + g.normal(0.0, sd, ds.points.shape)
    ds = dataclasses.replace(ds, approx_points=apx, sigma_scene=np.full_like(apx, sd))
    return ds, range_mm, corrupt(ds, "streak", rng=18)


def test_a_streak_that_bends_the_fit_is_not_a_plain_success():
    # without the run statistic: exit 0, 2 of 15 rows flagged, the good points 1.55x the
    # clean fit's error, neighbour correlation p = 0.007
    ds, range_mm, c = _streak_room()
    assert range_mm == 1000.0 and len(c.rows) == 15
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        res = bc.calibrate_simultaneous(c.pixels, c.approx_points, sigma_px=None,
                                        sigma_scene=None)
    assert res.extras["model_misfit"] == ["misfit_run"]
    msg = [str(w.message) for w in caught if issubclass(w.category, bc.ModelMisfitWarning)]
    assert len(msg) == 1 and "a run of neighbouring points" in msg[0]
    assert np.isin(c.rows, res.extras["failed_rows"]).mean() >= 0.5
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        clean = bc.calibrate_simultaneous(ds.pixels, ds.approx_points, sigma_px=None,
                                          sigma_scene=None)
    assert "model_misfit" not in clean.extras
    assert clean.extras["model_check"]["misfit_run"] > 1e-3
