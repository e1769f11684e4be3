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
