"""``bayescal extract``: image files in, laser.csv and an overlay out; bad input writes nothing."""

import csv

import numpy as np
import pytest

import bayescal as bc
from tests.cli.test_cli import run

iio = pytest.importorskip("imageio.v3")


def _laser(path):
    """The numbers of extract's laser.csv (its '#' lines and header left out)."""
    with open(path) as f:
        return np.loadtxt([line for line in f if not line.startswith("#")][1:], delimiter=",")


@pytest.fixture(scope="module")
def images(tmp_path_factory):
    root = tmp_path_factory.mktemp("extract")
    img, truth = bc.render_image(bc.SensorParams.paper(), bc.room_walls(2500), rng=2,
                                 with_background=True, n_lamps=2, ghost=0.3, bits=16)
    rgb = np.stack([img, img // 3, img // 5], axis=-1).astype(np.uint16)
    iio.imwrite(root / "on.tif", rgb)
    iio.imwrite(root / "off.png", truth.background.astype(np.uint16))
    return root, truth


def test_extract_writes_csv_and_overlay(images):
    root, truth = images
    r = run("extract", "on.tif", "--background", "off.png", "--out", "ex", cwd=root)
    assert r.returncode == 0, r.stderr
    with open(root / "ex" / "laser.csv") as f:
        rows = [row for row in csv.reader(line for line in f if not line.startswith("#"))]
    assert rows[0] == ["u", "v", "cov_uu", "cov_uv", "cov_vv", "snr", "flagged"]
    a = np.array(rows[1:], dtype=float)
    assert len(a) > 200 and (root / "ex" / "overlay.png").stat().st_size > 1000
    # every unflagged pixel lies within 1 px of the true ring
    good = a[a[:, 6] == 0, :2]
    d = np.min(np.linalg.norm(good[:, None] - truth.pixels[None], axis=-1), axis=1)
    assert np.mean(d < 1.0) > 0.98
    # --along-sd sets the sd along the ring: the larger eigenvalue of each covariance
    r = run("extract", "on.tif", "--background", "off.png", "--along-sd", "1", "--out", "ex1",
            cwd=root)
    assert r.returncode == 0, r.stderr
    b = _laser(root / "ex1" / "laser.csv")
    cov = np.stack([np.stack([b[:, 2], b[:, 3]], -1), np.stack([b[:, 3], b[:, 4]], -1)], -2)
    big = np.linalg.eigvalsh(cov)[:, 1]
    np.testing.assert_allclose(np.sqrt(big[b[:, 6] == 0]), 1.0, rtol=0.05)


@pytest.mark.parametrize("args, match", [
    (("on.tif", "--along-sd", "0"), "--along-sd"),
    (("missing.png",), "no such file"),
    (("on.tif", "--background", "small.png"), "shape"),
    (("on.tif", "--center", "1", "nan"), "finite"),
    (("bad.png",), "cannot read"),
])
def test_bad_input_exit_2_nothing_written(images, args, match):
    root, _ = images
    iio.imwrite(root / "small.png", np.zeros((20, 20), np.uint8))
    (root / "bad.png").write_text("not an image")
    r = run("extract", *args, "--out", "bad_out", cwd=root)
    assert r.returncode == 2 and match in r.stderr
    assert not (root / "bad_out").exists()


@pytest.fixture(scope="module")
def simulated(tmp_path_factory):
    """`simulate --images` then `extract` with its laser-off image, once for the module."""
    root = tmp_path_factory.mktemp("sim_extract")
    r = run("simulate", "--images", "--range-mm", 2500, "--n-points", 60, "--seed", 3,
            "--out", "sim", cwd=root)
    assert r.returncode == 0, r.stderr
    r = run("extract", "sim/image.png", "--background", "sim/image_off.png", "--out", "ex",
            cwd=root)
    assert r.returncode == 0, r.stderr
    return root


def test_simulate_images_then_extract(simulated):
    tmp_path = simulated
    img = iio.imread(tmp_path / "sim" / "image.png")
    assert img.dtype == np.uint16 and img.shape == (600, 800)
    ring = np.loadtxt(tmp_path / "sim" / "ring.csv", delimiter=",", skiprows=3)
    got = _laser(tmp_path / "ex" / "laser.csv")
    good = got[got[:, 6] == 0, :2]
    d = np.min(np.linalg.norm(good[:, None] - ring[None, :, :2], axis=-1), axis=1)
    assert np.median(d) < 0.25


def _with_points(root, name, *, bad_row=None):
    """laser.csv of `extract` plus x, y, z (true points with 2 % error) -> NAME."""
    truth = bc.render_image(bc.SensorParams.paper(), bc.room_walls(2500), rng=2,
                            with_background=True, n_lamps=2, ghost=0.3, bits=16)[1]
    a = _laser(root / "ex" / "laser.csv")
    a = a[a[:, 6] == 0]
    k = np.argmin(np.sum((a[:, None, :2] - truth.pixels[None]) ** 2, -1), 1)
    pts = truth.points[k]
    sig = 0.02 * np.abs(pts) + 1.0
    pts = pts + np.random.default_rng(0).normal(size=pts.shape) * sig
    if bad_row is not None:
        a[bad_row, 4] = -1.0
    cols = np.column_stack([a[:, :2], pts, sig, a[:, 2:5]])
    head = "u,v,x,y,z,sigma_x,sigma_y,sigma_z,cov_uu,cov_uv,cov_vv"
    np.savetxt(root / name, cols, delimiter=",", header=head, comments="")


def test_calibrate_reads_pixel_covariances(images):
    root, _ = images
    if not (root / "ex").exists():
        assert run("extract", "on.tif", "--background", "off.png", "--out", "ex",
                   cwd=root).returncode == 0
    _with_points(root, "cov.csv")
    r = run("calibrate", "cov.csv", "--out", "cal", "--no-progress", cwd=root)
    assert r.returncode == 0, r.stderr
    assert "per-point covariances" in r.stdout + (root / "cal" / "report.md").read_text()
    res = bc.load_result(root / "cal" / "result.json")
    z = (res.params.to_identifiable() - bc.SensorParams.paper().to_identifiable()) / np.sqrt(
        np.diag(res.covariance_identifiable))
    assert np.all(np.abs(z) < 5)
    r = run("calibrate", "cov.csv", "--sigma-px", "infer", "--out", "cal2", cwd=root)
    assert r.returncode == 2 and "not supported" in r.stderr and not (root / "cal2").exists()
    _with_points(root, "badcov.csv", bad_row=3)
    r = run("calibrate", "badcov.csv", "--out", "cal3", cwd=root)
    assert r.returncode == 2 and "line 5" in r.stderr and "positive definite" in r.stderr
    assert not (root / "cal3").exists()


def test_calibrate_on_walls_with_pixel_covariances(simulated):
    """extract's laser.csv (cov_uu, cov_uv, cov_vv) with --walls: the least squares, with the
    noise given and with a scale on the covariances inferred, takes them."""
    tmp_path = simulated
    r = run("calibrate", "ex/laser.csv", "--walls", "sim/walls.csv", "--out", "cal",
            "--no-progress", cwd=tmp_path)
    assert r.returncode == 0, r.stderr
    assert "per-point covariances" in (tmp_path / "cal" / "report.md").read_text()
    assert "with --walls, pixel sds up to 5 px" in r.stderr          # extract's along-ring sd
    res = bc.load_result(tmp_path / "cal" / "result.json")
    truth = bc.SensorParams.paper()           # simulate --images renders the design sensor
    z = (res.params.to_identifiable() - truth.to_identifiable()) / np.sqrt(
        np.diag(res.covariance_identifiable))
    assert np.all(np.abs(z) < 5), z
    r = run("calibrate", "ex/laser.csv", "--walls", "sim/walls.csv", "--sigma-px", "infer",
            "--out", "cal2", "--no-progress", cwd=tmp_path)
    assert r.returncode == 0, r.stderr
    # the scale on the extractor's covariances, inferred: of order one (they are honest)
    scale = bc.load_result(tmp_path / "cal2" / "result.json").sigma_px_estimated
    assert 0.4 < scale < 2.5, scale


@pytest.mark.slow
def test_posterior_on_walls_with_pixel_covariances(simulated):
    """The posterior takes extract's covariances from the shell too (the library's sampler
    is tested with them in tests/mcmc/test_pixel_cov_posterior.py, in the default run)."""
    tmp_path = simulated
    r = run("calibrate", "ex/laser.csv", "--walls", "sim/walls.csv", "--method", "bayes",
            "--max-steps", 200, "--allow-unconverged", "--out", "post", "--no-progress",
            cwd=tmp_path)
    assert r.returncode == 0, r.stderr
    post = bc.load_posterior(tmp_path / "post" / "posterior.npz")
    assert np.all(np.isfinite(post.point_samples))
