"""A board through a pose and eq. (1): Rodrigues, the Jacobians, OpenCV's omnidir model."""

import numpy as np
import pytest

from bayescal.image.views import board_points
from bayescal.sensor.board import (
    log_det_left_jacobian,
    project_board,
    project_board_local,
    rotation_from_vector,
    vector_from_rotation,
)

K = np.array([1.134, 317.8, -318.0, 642.5, 522.9])


def _pose(rng):
    """A board 300-900 mm from the focus, below the horizon, tilted at random."""
    w = rng.normal(size=3)
    w *= rng.uniform(0.2, 3.0) / np.linalg.norm(w)
    az = rng.uniform(-np.pi, np.pi)
    rho = rng.uniform(300.0, 900.0)
    return np.concatenate([w, [rho * np.cos(az), rho * np.sin(az), -rng.uniform(100, 600)]])


def test_rotation_vector_roundtrip_and_orthogonal(rng):
    for angle in (0.0, 1e-9, 0.3, 2.0, np.pi - 1e-3):
        w = rng.normal(size=3)
        w *= angle / np.linalg.norm(w)
        R = rotation_from_vector(w)
        np.testing.assert_allclose(R @ R.T, np.eye(3), atol=1e-14)
        assert np.linalg.det(R) == pytest.approx(1.0, abs=1e-13)
        np.testing.assert_allclose(vector_from_rotation(R), w, atol=1e-9)


def test_rotation_jacobian_matches_finite_differences(rng, numdiff):
    for w in (rng.normal(size=3), np.zeros(3), np.array([1e-10, 0, 0])):
        _, dR = rotation_from_vector(w, jacobian=True)
        num = numdiff(lambda x: rotation_from_vector(x).reshape(x.shape[:-1] + (9,)), w, 1e-6)
        np.testing.assert_allclose(dR.reshape(9, 3), num, atol=1e-8)


def test_project_board_jacobians_match_finite_differences(rng, numdiff):
    p = board_points((8, 6), 42.0)
    for _ in range(5):
        pose = _pose(rng)
        uv, valid, dk, dp = project_board(K, pose, p, jacobian=True)
        assert valid.all()
        nk = numdiff(lambda x, pose=pose: project_board(x, pose, p)[0].reshape(-1), K,
                     [1e-6, 1e-4, 1e-4, 1e-4, 1e-4])
        npo = numdiff(lambda x: project_board(K, x, p)[0].reshape(-1), pose,
                      [1e-7] * 3 + [1e-4] * 3)
        # central differences: truncation error ~ step^2 * third derivative, well below 1e-5
        np.testing.assert_allclose(dk.reshape(-1, 5), nk, rtol=1e-6, atol=1e-5)
        np.testing.assert_allclose(dp.reshape(-1, 6), npo, rtol=1e-6, atol=1e-4)


def test_rotation_without_jacobian_is_the_jacobian_paths_rotation(rng):
    """The entry-by-entry Rodrigues of the plain call equals the matrix form of the other."""
    w = rng.normal(size=(4, 3)) * np.array([[0.0], [1e-9], [0.5], [3.0]])
    np.testing.assert_allclose(rotation_from_vector(w), rotation_from_vector(w, jacobian=True)[0],
                               atol=1e-15)


def test_local_pose_derivative_is_the_rotation_vector_one_through_the_left_jacobian(rng, numdiff):
    """``d_pose = d_local @ diag(J_l(w), I)``, and ``log det J_l`` against finite differences
    of the left perturbation ``exp([d]_x) R(w) = R(w + dw)`` (central differences, error
    ~ step^2)."""
    p = board_points((8, 6), 42.0)
    for w_scale in (1e-9, 0.3, 2.5):
        pose = _pose(rng)
        pose[:3] *= w_scale / np.linalg.norm(pose[:3])
        uv, _, _, dp = project_board(K, pose, p, jacobian=True)
        uv_l, dl = project_board_local(K, pose, p)
        np.testing.assert_allclose(uv_l, uv, atol=1e-10)
        w = pose[:3]

        def local_of(x, w=w):
            """The left perturbation d with exp([d]_x) R(w) = R(x)."""
            return vector_from_rotation(rotation_from_vector(x) @ rotation_from_vector(w).T)

        Jl = numdiff(lambda x: np.array([local_of(v) for v in np.atleast_2d(x)]).reshape(
            np.shape(x)), w, 1e-6)
        T = np.eye(6)
        T[:3, :3] = Jl
        np.testing.assert_allclose((dl @ T).reshape(-1, 6), dp.reshape(-1, 6), rtol=1e-6,
                                   atol=1e-5)
        assert log_det_left_jacobian(w) == pytest.approx(np.linalg.slogdet(Jl)[1], abs=1e-8)


def test_project_board_broadcasts_over_walkers_and_views(rng):
    p = board_points((4, 3), 30.0)
    poses = np.stack([_pose(rng) for _ in range(3)])              # (3 views, 6)
    ks = K + np.array([[0.0] * 5, [0.01, 1, -1, 2, 3]])            # (2 walkers, 5)
    uv, _, dk, dp = project_board(ks[:, None], poses[None], p, jacobian=True)
    assert uv.shape == (2, 3, 12, 2) and dk.shape == (2, 3, 12, 2, 5) and dp.shape[-1] == 6
    for a in range(2):
        for b in range(3):
            np.testing.assert_allclose(uv[a, b], project_board(ks[a], poses[b], p)[0],
                                       atol=1e-10)


def test_project_board_matches_opencv_omnidir(rng):
    """Ours equals OpenCV's after z -> -z on both sides of the pose.

    OpenCV's frame has z along the optical axis (towards the mirror's vertex); ours
    has z up with the focus at the origin: ``P_cv = S P`` with ``S = diag(1, 1, -1)``.
    A planar board (z = 0) gives ``S R p = (S R S) p`` with ``S R S`` a rotation, so
    OpenCV's rotation is ``S R S`` and its translation ``S t``; ``fx = gamma_u``,
    ``fy = gamma_v``, ``cx = u0``, ``cy = v0``, zero skew and distortion, the same xi.
    """
    cv2 = pytest.importorskip("cv2")
    S = np.diag([1.0, 1.0, -1.0])
    p = board_points((8, 6), 42.0)
    for gv in (-318.0, 318.0):
        k = K.copy()
        k[2] = gv
        Kcv = np.array([[k[1], 0.0, k[3]], [0.0, k[2], k[4]], [0.0, 0.0, 1.0]])
        for _ in range(10):
            pose = _pose(rng)
            R = rotation_from_vector(pose[:3])
            rvec, _ = cv2.Rodrigues(S @ R @ S)
            ref, _ = cv2.omnidir.projectPoints(p.reshape(-1, 1, 3), rvec, S @ pose[3:], Kcv,
                                               float(k[0]), np.zeros((1, 4)))
            np.testing.assert_allclose(project_board(k, pose, p)[0], ref.reshape(-1, 2),
                                       atol=1e-8)
