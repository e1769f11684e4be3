"""Pixel errors correlated along the ring (bayescal.fit.floorplan.normal_sensitivity,
ring_corr_cov; ``calibrate_simultaneous(..., ring_corr_deg=)``; docs/floorplan.md, "Errors
correlated along the ring")."""

import copy

import numpy as np
import pytest

import bayescal as bc
from bayescal.fit import floorplan as fp


@pytest.fixture(scope="module")
def room():
    return bc.simulate_room(range_mm=1500.0, n_points=120, n_walls=5, sigma_px=0.2,
                            approx_error=0.02, approx_model="gaussian", rng=5)


def _fit(pixels, plan):
    return fp._fit(pixels, plan, sigma_px=0.2, prior=None, init=None, max_iter=200,
                   outliers=False)


def test_normal_sensitivity_matches_a_refit_of_moved_pixels(room):
    lik, prior, sol = _fit(room.pixels, room.floor_plan)
    P, sd = fp.normal_sensitivity(lik, sol)
    assert P.shape == (len(sol.g), lik.n) and sd.shape == (lik.n,)
    assert np.allclose(sd, 0.2, rtol=1e-9)                     # isotropic 0.2 px noise
    rad = room.pixels - sol.g[3:5]
    rad /= np.linalg.norm(rad, axis=1, keepdims=True)
    delta = 0.01 * (np.cos(3 * sol.t) + 0.5)          # px along the normal, smooth in azimuth
    moved = copy.copy(lik)
    moved.pixels = lik.pixels + delta[:, None] * rad
    new = fp._solve(moved, prior, sol.g, sol.t, sol.sigma_px)    # the same walls' pairs
    sd = np.sqrt(np.diag(sol.cov))[:8]
    dg, pred = (new.g - sol.g)[:8] / sd, (P @ delta)[:8] / sd
    # first order with the Gauss-Newton S (the cost's r . r'' terms left out: measured
    # 5-10 % of the change at 0.002-0.02 px, the same at both, so not the O(delta^2) part)
    assert np.max(np.abs(dg - pred)) < 0.15 * np.max(np.abs(pred))
    assert np.max(np.abs(pred)) > 0.01               # the move matters: the check is not empty


def test_ring_corr_widens_the_intervals_and_leaves_the_fit(room):
    plain = bc.calibrate_simultaneous(room.pixels, room.floor_plan, sigma_px=0.2,
                                      outliers=False)
    wide = bc.calibrate_simultaneous(room.pixels, room.floor_plan, sigma_px=0.2,
                                     outliers=False, ring_corr_deg=2.0)
    assert np.array_equal(plain.params.to_array(), wide.params.to_array())
    c0, c1 = plain.covariance_identifiable, wide.covariance_identifiable
    assert np.all(np.linalg.eigvalsh(c1 - c0) > -1e-9 * np.max(np.diag(c0)))
    # 120 points 3 degrees apart, neighbours correlated exp(-3/2) = 0.22: u0's and v0's
    # data share of their variance (31 % and 18 % here; the rest the plan's) grows
    assert c1[3, 3] > 1.05 * c0[3, 3] and c1[4, 4] > 1.05 * c0[4, 4]
    assert wide.extras["ring_corr_deg"] == 2.0
    lik, _, sol = _fit(room.pixels, room.floor_plan)
    add = fp.ring_corr_cov(lik, sol, 2.0)
    assert np.allclose(np.diag(sol.cov + add)[3:5], np.diag(c1)[3:5], rtol=1e-6)
    grow = [fp.ring_corr_cov(lik, sol, d)[3, 3] for d in (1.0, 2.0, 5.0)]
    assert 0 < grow[0] < grow[1] < grow[2]                    # longer correlation, wider


def test_ring_corr_is_saved_with_the_result(room, tmp_path):
    wide = bc.calibrate_simultaneous(room.pixels, room.floor_plan, sigma_px=0.2,
                                     outliers=False, ring_corr_deg=2.0)
    wide.save(tmp_path / "result.json")
    back = bc.load_result(tmp_path / "result.json")
    assert back.extras["ring_corr_deg"] == 2.0
    assert np.allclose(back.covariance_identifiable, wide.covariance_identifiable)


def test_the_term_is_none_at_a_tiny_scale_and_a_shared_shift_at_a_huge_one(room):
    lik, _, sol = _fit(room.pixels, room.floor_plan)
    P, sd = fp.normal_sensitivity(lik, sol)
    assert np.allclose(fp.ring_corr_cov(lik, sol, 1e-3), 0.0, atol=1e-15)
    # a scale far beyond a turn: every error the same draw, P sd summed, less the diagonal
    Q = P * sd
    one, bound = Q.sum(axis=1), np.abs(Q).sum(axis=1)
    err = fp.ring_corr_cov(lik, sol, 1e9) - (np.outer(one, one) - Q @ Q.T)
    assert np.all(np.abs(err) <= 1e-5 * np.outer(bound, bound))


def test_ring_corr_is_refused_without_a_plan_or_negative(room):
    with pytest.raises(ValueError, match="ring_corr_deg=1.0 needs a FloorPlan"):
        bc.calibrate_simultaneous(room.pixels, room.approx_points, sigma_px=0.2,
                                  sigma_scene=room.sigma_scene, ring_corr_deg=1.0)
    with pytest.raises(ValueError, match="ring_corr_deg must be a finite non-negative"):
        bc.calibrate_simultaneous(room.pixels, room.floor_plan, sigma_px=0.2,
                                  ring_corr_deg=-1.0)
