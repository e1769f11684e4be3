"""Point clouds out: the PLY read back by a reader we did not write (meshio), and NPZ."""

import numpy as np
import pytest

import bayescal as bc
from bayescal.io.pointcloud import COVARIANCE_FIELDS, write_ply


@pytest.fixture(scope="module")
def rec():
    ds = bc.simulate_room(range_mm=1000, n_points=60, sigma_px=0.3, approx_error=0.02,
                          approx_model="gaussian", rng=2)
    res = bc.calibrate_simultaneous(ds.pixels, ds.approx_points, sigma_px=0.3,
                                    sigma_scene=ds.sigma_scene)
    rec = res.reconstruct(ds.pixels)
    rec.outlier_prob = res.outlier_prob
    return rec


def test_ply_read_back_by_meshio(rec, tmp_path):
    meshio = pytest.importorskip("meshio")
    path = rec.save(tmp_path / "cloud.ply")
    assert path.read_bytes().startswith(b"ply\nformat binary_little_endian 1.0\n")
    mesh = meshio.read(path)
    np.testing.assert_array_equal(mesh.points, rec.mean)
    iu = np.triu_indices(3)
    for name, (i, j) in zip(COVARIANCE_FIELDS, zip(*iu, strict=True), strict=True):
        np.testing.assert_array_equal(mesh.point_data[name], rec.covariance[:, i, j])
    np.testing.assert_array_equal(mesh.point_data["u"], rec.pixels[:, 0])
    np.testing.assert_array_equal(mesh.point_data["outlier_prob"], rec.outlier_prob)


def test_npz_and_refusals(rec, tmp_path):
    path = rec.save(tmp_path / "cloud.npz")
    with np.load(path) as f:
        np.testing.assert_array_equal(f["covariance"], rec.covariance)
        np.testing.assert_array_equal(f["pixels"], rec.pixels)
    with pytest.raises(FileExistsError, match="overwrite=True"):
        rec.save(path)
    rec.save(path, overwrite=True)
    with pytest.raises(ValueError, match=r"\.ply or \.npz"):
        rec.save(tmp_path / "cloud.xyz")
    with pytest.raises(ValueError, match=r"covariance must have shape \(M, 3, 3\)"):
        write_ply(tmp_path / "bad.ply", rec.mean, rec.covariance[:3])
    assert not list(tmp_path.glob("*.tmp"))
