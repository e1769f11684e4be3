"""A fit the bad rows cannot take over (docs/robustness.md, sections 4b and 4c): a singular
information matrix does not stop the solver (fit.schur.safe_inv), and the high-breakdown
start (fit.em._robust_start, the path of every fit) flags the bad rows of a messy file."""

import numpy as np
import pytest

import bayescal as bc
from bayescal.fit import simultaneous as simul
from bayescal.fit.em import _fit_map
from bayescal.fit.schur import SINGULAR_FLOOR, safe_inv
from bayescal.likelihood.priors import Prior
from bayescal.sensor.parameters import to_identifiable
from bayescal.validation.corruption import corrupt, judge


def test_safe_inv_inverts_regular_matrices_and_gives_a_singular_one_a_huge_variance():
    rng = np.random.default_rng(0)
    X = rng.standard_normal((5, 3, 3))
    A = np.einsum("nij,nkj->nik", X, X) + 0.1 * np.eye(3)
    np.testing.assert_allclose(safe_inv(A), np.linalg.inv(A), rtol=1e-10, atol=1e-12)
    S = np.array([A[0], [[1.0, 1.0, 0.0], [1.0, 1.0, 0.0], [0.0, 0.0, 2.0]]])
    with pytest.raises(np.linalg.LinAlgError):
        np.linalg.inv(S[1])
    out = safe_inv(S)
    np.testing.assert_allclose(out[0], np.linalg.inv(A[0]), rtol=1e-10)
    # the null direction (1, -1, 0)/sqrt(2): variance 1 / (floor * largest eigenvalue 2)
    v = np.array([1.0, -1.0, 0.0]) / np.sqrt(2.0)
    assert v @ out[1] @ v == pytest.approx(1.0 / (2.0 * SINGULAR_FLOOR), rel=1e-6)
    assert out[1][2, 2] == pytest.approx(0.5, rel=1e-9)


@pytest.fixture(scope="module")
def room():
    return bc.simulate_room(range_mm=2500.0, n_points=300, n_walls=6, sigma_px=0.2,
                            approx_error=0.02, approx_model="gaussian", rng=1)


def test_the_robust_start_handles_a_messy_file_with_the_noise_inferred(room):
    """The messy file (a typo, a swapped pair, a spurious pixel, a z sign flip) from the
    high-breakdown start: every bad row flagged, the good points as good as the clean
    fit's, the noise near the simulated 0.2 px."""
    prior = Prior(None)
    clean = bc.calibrate_simultaneous(room.pixels, room.approx_points, sigma_px=None,
                                      sigma_scene=None)
    err = float(np.mean(np.linalg.norm(clean.points - room.points, axis=1)))
    c = corrupt(room, "mixed", rng=7)
    lik = simul.point_likelihood("aligned", c.pixels, c.approx_points, prior, sigma_px=None,
                                 sigma_scene=None, outliers=True)
    theta0 = to_identifiable(prior.mean().to_array())
    fit = _fit_map(lik, prior, theta0, lik.initial_q(theta0), 200)
    assert fit.robust
    assert np.all(fit.r[c.rows] > 0.5)
    assert np.sum(fit.r > 0.5) == len(c.rows)
    assert 0.15 < fit.sig < 0.27            # 0.21 px clean; 0.2 px simulated
    res = simul._checked(lik, prior, fit, True)[0]
    v = judge(res, c, room.points, err)
    assert v["verdict"] == "handled", v


def test_a_solver_crawling_along_a_flat_direction_stops_as_converged():
    """5000 mm, 1 % points by the paper's protocol, a block of 10 rows mis-paired, the
    pixel noise inferred: LM lowered the cost by 2e-6 per 20 steps until max_iter ended it
    'not converged'; the stall rule (schur.STALL_WINDOW, STALL_TOL) now ends the crawl."""
    ds = bc.simulate_room(range_mm=5000.0, n_points=300, n_walls=7, sigma_px=0.1,
                          approx_error=0.01, approx_model="fig9", rng=24)
    c = corrupt(ds, "block_mispaired", rng=902)
    res = bc.calibrate_simultaneous(c.pixels, c.approx_points, sigma_px=None,
                                    sigma_scene=ds.sigma_scene)
    assert res.converged and "stationary" in res.message
    assert np.all(res.outlier_prob[c.rows] > 0.5)
    assert np.sum(res.outlier_prob > 0.5) == len(c.rows)
