"""CameraResult: project and reconstruct agree, covariances propagate, files round-trip."""

import numpy as np
import pytest

import bayescal as bc


@pytest.fixture(scope="module")
def cam():
    views, _ = bc.simulate_views(n_views=4, rng=5)
    return bc.calibrate_camera(views, noise="per-view"), views


def test_project_reconstruct_roundtrip(cam, numdiff):
    cam, _ = cam
    px = np.array([[700.0, 600.0], [500.0, 400.0], [642.0, 300.0]])
    rays, cov = cam.reconstruct(px)
    np.testing.assert_allclose(np.linalg.norm(rays, axis=-1), 1.0, atol=1e-12)
    np.testing.assert_allclose(cam.project(rays), px, atol=1e-8)
    uv, cuv = cam.project(rays * 500.0, return_cov=True)
    assert cuv.shape == (3, 2, 2) and cov.shape == (3, 3, 3)
    assert np.all(np.linalg.eigvalsh(cuv) > 0)


def test_save_load_roundtrip(cam, tmp_path):
    cam, _ = cam
    path = cam.save(tmp_path / "camera.json")
    back = bc.load_camera(path)
    assert back.intrinsics == cam.intrinsics
    np.testing.assert_array_equal(back.covariance(), cam.covariance())
    np.testing.assert_array_equal(back.poses, cam.poses)
    assert back.view_names == cam.view_names
    with pytest.raises(FileExistsError):
        cam.save(path)
    (tmp_path / "x.json").write_text("{}")
    with pytest.raises(ValueError, match="x.json"):
        bc.load_camera(tmp_path / "x.json")


def test_model_check_and_summary(cam):
    cam, _ = cam
    mc = cam.model_check()
    assert len(mc["views"]) == 4 and 0.1 < mc["rms"] < 0.5
    assert "gamma_u" in cam.summary() and "all used" in cam.summary()


def test_a_binary_file_is_named_not_decoded(tmp_path):
    (tmp_path / "img.png").write_bytes(b"\x89PNG\r\n\x1a\n\xff\xfe\x00\x01")
    with pytest.raises(bc.BayescalError, match=r"img\.png: not a text file; expected a camera"):
        bc.load_camera(tmp_path / "img.png")


def test_intrinsics_the_views_leave_open_are_flagged(cam):
    cam, _ = cam
    assert cam.unidentified() == []
    assert "NOT IDENTIFIED" not in cam.summary()
    cov = cam.covariance().copy()
    cov[0, 0] = 4.0 * cam.intrinsics["xi"] ** 2          # sd twice the value
    cov[3, 3] = -1.0                                     # no sd at all
    open_ = bc.CameraResult(cam.k, cov, cam.poses, cam.residuals, cam.view_names,
                            noise=cam.noise, sigma=cam.sigma, tau=cam.tau,
                            image_size=cam.image_size)
    assert open_.unidentified() == ["xi", "u0"]
    text = open_.summary()
    assert text.count("NOT IDENTIFIED (sd >= |value|)") == 2
    assert "the views do not determine xi, u0" in text


def test_calibrate_camera_warns_when_the_views_leave_the_camera_open():
    # every other row of each view taken for the next (a board option smaller than the
    # board): the fit leaves xi and gamma_v with an sd above their value (seed 0)
    views, _ = bc.simulate_views(n_views=4, rng=0)
    parts = [bc.BoardView(v.pixels.reshape(6, 8, 2)[[0, 2, 4]].reshape(-1, 2),
                          bc.board_points((8, 3), 42.0), name=v.name) for v in views]
    with pytest.warns(bc.BayescalWarning, match=r"the views do not determine the camera: xi ="):
        res = bc.calibrate_camera(parts)
    assert res.unidentified() == ["xi", "gamma_v"]
