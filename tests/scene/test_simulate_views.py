"""Simulated board views: visible boards, truth returned, the noise structure as asked."""

import numpy as np
import pytest

import bayescal as bc
from bayescal.sensor.board import project_board


def test_views_are_visible_and_noise_free_views_are_exact(rng):
    views, truth = bc.simulate_views(n_views=6, sigma=0.0, correlation=(0, 0), column_error=0,
                                     image_size=(1280, 1024), rng=rng)
    assert len(views) == 6 and truth["poses"].shape == (6, 6)
    for v, pose in zip(views, truth["poses"], strict=True):
        assert v.n_corners == 48 and v.image_size == (1280, 1024)
        assert np.all((v.pixels > 0) & (v.pixels < [1280, 1024]))
        np.testing.assert_allclose(v.pixels, project_board(truth["intrinsics"], pose, v.points)[0],
                                   atol=1e-9)


def test_noise_sd_and_neighbour_correlation(rng):
    """Pooled over 200 views of 48 corners: sd within 3 % and lag-1 correlation along the
    board's rows within 0.03 of 0.43 (standard errors ~1 % and ~0.01)."""
    views, truth = bc.simulate_views(n_views=200, sigma=0.3, correlation=(0.2, 0.43),
                                     column_error=0.0, rng=rng)
    e = np.stack([v.pixels - project_board(truth["intrinsics"], p, v.points)[0]
                  for v, p in zip(views, truth["poses"], strict=True)])   # (200, 48, 2)
    assert np.std(e) == pytest.approx(0.3, rel=0.03)
    g = e.reshape(200, 6, 8, 2)
    rho_y = np.corrcoef(g[:, :-1].ravel(), g[:, 1:].ravel())[0, 1]
    rho_x = np.corrcoef(g[:, :, :-1].ravel(), g[:, :, 1:].ravel())[0, 1]
    assert rho_y == pytest.approx(0.43, abs=0.03)
    assert rho_x == pytest.approx(0.2, abs=0.03)


def test_any_camera_size(rng):
    views, truth = bc.simulate_views({"xi": 0.9, "gamma_u": 150.0, "gamma_v": -150.0,
                                      "u0": 320.0, "v0": 240.0}, n_views=3,
                                     image_size=(640, 480), radius=(60, 140),
                                     distance=(300, 600), rng=rng)
    assert all(np.all(v.pixels < [640, 480]) for v in views)
