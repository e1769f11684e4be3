"""calibrate_camera on simulated boards: truth recovered, every view used, any camera size,
a view that cannot be fitted named, the noise model's covariance."""

import numpy as np
import pytest

import bayescal as bc
from bayescal.errors import DegenerateInputError


@pytest.fixture(scope="module")
def white():
    """Eight views of the real camera with white noise (0.2 px)."""
    views, truth = bc.simulate_views(n_views=8, sigma=0.2, correlation=(0, 0), column_error=0,
                                     rng=11)
    return views, truth


def test_recovers_truth_with_white_noise(white):
    """Each intrinsic within 4.5 sd of the truth (false failure < 1e-4 for all five), the
    noise within 15 % (REML; sd ~ 1 / sqrt(2 * 8 * 90) = 2.6 %)."""
    views, truth = white
    cam = bc.calibrate_camera(views, noise="plain")
    z = (cam.k - truth["intrinsics"]) / np.sqrt(np.diag(cam.covariance()))
    assert np.all(np.abs(z) < 4.5), z
    assert cam.sigma[0] == pytest.approx(0.2, rel=0.15)
    assert cam.covariance().shape == (5, 5) and len(cam.poses) == 8
    assert list(cam.intrinsics) == ["xi", "gamma_u", "gamma_v", "u0", "v0"]
    assert cam.converged


def test_systematic_model_on_white_noise_stays_near_plain(white):
    """With no systematic error the inferred tau is small and the standard errors stay
    within 1.5x of plain least squares."""
    views, _ = white
    plain = bc.calibrate_camera(views, noise="plain")
    cam = bc.calibrate_camera(views)
    assert cam.noise == "view-systematic" and cam.tau < 0.1
    ratio = np.sqrt(np.diag(cam.covariance()) / np.diag(plain.covariance()))
    assert np.all(ratio < 1.5), ratio
    full = cam.covariance(noise=True)
    assert full.shape == (5 + 8 + 1, 5 + 8 + 1)
    assert cam.noise_names[-1] == "tau" and len(cam.noise_names) == 9


def test_small_board_near_the_centre_is_kept(rng):
    """A board seen small near the centre (the kind OpenCV's start drops) is fitted too."""
    views, truth = bc.simulate_views(n_views=4, sigma=0.2, correlation=(0, 0), column_error=0,
                                     rng=rng)
    small, _ = bc.simulate_views(n_views=1, sigma=0.2, correlation=(0, 0), column_error=0,
                                 radius=(60.0, 80.0), distance=(900.0, 1000.0), rng=rng)
    cam = bc.calibrate_camera(views + small, noise="per-view")
    assert len(cam.residuals) == 5
    assert np.sqrt(np.mean(cam.residuals[-1] ** 2)) < 0.4


def test_other_camera_size(rng):
    """A 640x480 camera with |gamma| 150 and xi 0.9: no design value from the real one."""
    k = {"xi": 0.9, "gamma_u": 150.0, "gamma_v": -152.0, "u0": 330.0, "v0": 235.0}
    views, truth = bc.simulate_views(k, n_views=6, image_size=(640, 480), radius=(60, 140),
                                     distance=(300, 600), sigma=0.1, correlation=(0, 0),
                                     column_error=0, rng=rng)
    cam = bc.calibrate_camera(views, noise="plain")
    z = (cam.k - truth["intrinsics"]) / np.sqrt(np.diag(cam.covariance()))
    assert np.all(np.abs(z) < 4.5), z


def test_garbage_view_is_named_not_dropped(rng):
    views, _ = bc.simulate_views(n_views=3, rng=rng)
    bad = bc.BoardView(views[0].pixels[rng.permutation(48)], views[0].points, name="shuffled")
    cam = bc.calibrate_camera(views + [bad], noise="plain")
    assert "shuffled" in cam.model_check()["suspect"]
    assert "SUSPECT" in cam.summary()


def test_bad_arguments_are_named():
    with pytest.raises(TypeError, match="views"):
        bc.calibrate_camera([np.zeros((4, 2))])
    views, _ = bc.simulate_views(n_views=2, rng=0)
    with pytest.raises(ValueError, match="noise"):
        bc.calibrate_camera(views, noise="white")
    with pytest.raises(ValueError, match="init"):
        bc.calibrate_camera(views, init=[1.0, 2.0])
    with pytest.raises(ValueError, match="init"):
        bc.calibrate_camera(views, init={"xi": 1.0})
    assert DegenerateInputError  # raised by the start when no pose fits (named views)


def test_sandwich_covariance_matches_dense_algebra(rng):
    """The per-view Schur form of the sandwich equals (H^-1 M H^-1)[:5, :5] built densely."""
    from bayescal.fit.camera import sandwich_covariance
    from bayescal.likelihood.boards import BoardLikelihood

    views, truth = bc.simulate_views(n_views=3, rng=rng)
    lik = BoardLikelihood(views)
    k, poses = truth["intrinsics"], truth["poses"]
    s2w, s2, t2 = np.array([0.05, 0.08, 0.03]), np.array([0.04, 0.06, 0.02]), 0.03
    _, Jk, Jp = lik.residuals(k, poses, jacobian=True)
    n = 5 + 6 * 3
    H, M = np.zeros((n, n)), np.zeros((n, n))
    for j in range(3):
        G = np.zeros((lik.n_obs[j], n))
        G[:, :5], G[:, 5 + 6 * j:11 + 6 * j] = Jk[j], Jp[j]
        S = s2[j] * np.eye(lik.n_obs[j]) + t2 * lik.B[j] @ lik.B[j].T
        H += G.T @ G / s2w[j]
        M += G.T @ S @ G / s2w[j] ** 2
    Hi = np.linalg.inv(H)
    np.testing.assert_allclose(sandwich_covariance(lik, k, poses, s2w, s2, t2),
                               (Hi @ M @ Hi)[:5, :5], rtol=1e-8)


def test_splits_are_generated_lazily():
    from bayescal.validation.camera_cv import all_splits

    splits = all_splits(5)
    assert len(splits) == 10 and all(len(a) + len(b) == 5 for a, b in splits)
    assert len(all_splits(4)) == 3 and all(0 in a for a, _ in all_splits(4))
    # 30 views have ~1.5e8 splits: the first ten without building them all
    assert all_splits(30, max_splits=10)[0][0] == list(range(15))
