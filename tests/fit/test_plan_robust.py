"""The floor-plan least squares' high-breakdown start (bayescal.fit.plan_robust,
docs/robustness.md section 4b): the same retry conditions as the per-point fit's, a
least-trimmed start that lands where the plain EM does on data it handles, and a
detector that names a noise a few rows set."""

import numpy as np
import pytest

import bayescal as bc
from bayescal.fit import floorplan as fp
from bayescal.validation.corruption import corrupt, judge


@pytest.fixture(scope="module")
def room():
    return bc.simulate_room(range_mm=1500.0, n_points=200, n_walls=5, sigma_px=0.2,
                            approx_error=0.02, approx_model="gaussian", rng=3)


def _fit(pixels, plan, **kw):
    return fp._fit(pixels, plan, sigma_px=kw.pop("sigma_px", None), prior=None, init=None,
                   max_iter=200, **kw)


def test_the_detector_passes_a_clean_fit_and_names_a_noise_gross_pixels_set(room):
    """Clean: no problem (the trimmed ratio of a correct fit is ~1). 5 % of the pixels
    5-30 px off fitted without the mixture: the inferred sigma_px is several times its
    estimate from the best 80 % of the points, and the residuals' robust scale says so."""
    lik, prior, sol = _fit(room.pixels, room.floor_plan)
    assert fp.RETRY.problems(lik, prior, sol) == []
    assert not sol.robust
    c = corrupt(room, "random_gross", rng=5)
    lik, prior, sol = _fit(c.pixels, room.floor_plan, outliers=False)
    problems = fp.RETRY.problems(lik, prior, sol)
    assert any("best-fitting 80%" in p for p in problems), problems
    assert any("robust scale" in p for p in problems), problems
    assert sol.sigma_px > 2 * 0.2


@pytest.mark.parametrize("model", ["aligned", "misaligned"])
def test_an_untrusted_plan_fit_is_retried_from_the_robust_start(room, model, monkeypatch):
    """The retry's wiring: when the plain solution is reported untrustworthy, the robust
    start's is taken if it passes; on a 5 % pixel mix (a streak, a ghost arc, spurious
    pixels; noise inferred) it is as good as the plain one: >= 90 % of the bad rows and
    <= 1 % of the good ones flagged, the good points' error <= 1.25x the clean fit's."""
    clean = bc.calibrate_simultaneous(room.pixels, room.floor_plan, sigma_px=None, model=model)
    err = float(np.mean(np.linalg.norm(clean.points - room.points, axis=1)))
    real, calls = fp.RETRY.problems, []

    def first_untrusted(lik, prior, sol):
        calls.append(sol)
        return ["forced"] if len(calls) == 1 else real(lik, prior, sol)

    monkeypatch.setattr(fp.RETRY, "problems", first_untrusted)
    c = corrupt(room, "pixels_5pct", rng=11)
    assert len(c.rows) == 10
    res = bc.calibrate_simultaneous(c.pixels, room.floor_plan, sigma_px=None, model=model)
    assert len(calls) == 2 and res.extras["robust_start"]
    v = judge(res, c, room.points, err)
    assert v["verdict"] == "handled", v
    assert 0.15 < res.extras["noise"]["sigma_px"] < 0.25           # 0.2 px simulated
