"""An extraction error correlated along the ring (bayescal.fit.floorplan.normal_sensitivity,
ring_error_cov; ``calibrate_simultaneous(..., ring_error_sd=, ring_error_deg=)``;
docs/floorplan.md, "Errors correlated along the ring")."""

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
    P, h = fp.normal_sensitivity(lik, sol)
    assert P.shape == (len(sol.g), lik.n) and h.shape == (lik.n, len(sol.g))
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


def test_ring_error_widens_the_intervals_and_leaves_the_fit(room):
    plain = bc.calibrate_simultaneous(room.pixels, room.floor_plan, sigma_px=0.2,
                                      outliers=False)
    wide = bc.calibrate_simultaneous(room.pixels, room.floor_plan, sigma_px=0.2,
                                     outliers=False, ring_error_sd=0.1, ring_error_deg=5.0)
    assert np.array_equal(plain.params.to_array(), wide.params.to_array())
    c0, c1 = plain.covariance_identifiable, wide.covariance_identifiable
    assert np.all(np.linalg.eigvalsh(c1 - c0) > -1e-12 * np.max(np.diag(c0)))
    assert c1[3, 3] > 1.1 * c0[3, 3] and c1[4, 4] > 1.1 * c0[4, 4]
    assert wide.extras["ring_error"] == (0.1, 5.0)
    # the same as P K P^T from the module's functions
    lik, _, sol = _fit(room.pixels, room.floor_plan)
    add = fp.ring_error_cov(lik, sol, 0.1, 5.0)
    assert np.allclose(np.diag(sol.cov + add)[3:5], np.diag(c1)[3:5], rtol=1e-6)


def test_a_short_scale_is_independent_noise_and_a_long_one_a_shared_shift(room):
    lik, _, sol = _fit(room.pixels, room.floor_plan)
    P, _ = fp.normal_sensitivity(lik, sol)
    assert np.allclose(fp.ring_error_cov(lik, sol, 0.1, 1e-3), 0.01 * P @ P.T, atol=1e-12)
    # a scale far beyond a turn: every point moved alike (the kernel 1 - O(pi / scale))
    one, bound = P.sum(axis=1), np.abs(P).sum(axis=1)
    err = fp.ring_error_cov(lik, sol, 0.1, 1e9) - 0.01 * np.outer(one, one)
    assert np.all(np.abs(err) <= 1e-5 * 0.01 * np.outer(bound, bound))


def test_ring_error_is_refused_without_a_plan_or_out_of_range(room):
    with pytest.raises(ValueError, match="ring_error_sd=0.05 needs a FloorPlan"):
        bc.calibrate_simultaneous(room.pixels, room.approx_points, sigma_px=0.2,
                                  sigma_scene=room.sigma_scene, ring_error_sd=0.05)
    with pytest.raises(ValueError, match="ring_error_sd must be a finite non-negative"):
        bc.calibrate_simultaneous(room.pixels, room.floor_plan, sigma_px=0.2,
                                  ring_error_sd=-1.0)
    with pytest.raises(ValueError, match="ring_error_deg must be a finite positive"):
        bc.calibrate_simultaneous(room.pixels, room.floor_plan, sigma_px=0.2,
                                  ring_error_deg=0.0)
