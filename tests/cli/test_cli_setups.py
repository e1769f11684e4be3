"""Files that do not describe the same camera or scene are refused, naming both sides:
pixels, images, camera files, --image-size and a run of different image sizes; a --truth
of extracted pixels; plain pixels on a run calibrated with pixel covariances."""

import json

import numpy as np
import pytest

import bayescal as bc
from bayescal.cli.main import main


def _main(args, capsys):
    rc = main([str(a) for a in args])
    return rc, capsys.readouterr()


def _csv(path, columns, rows, size=None):
    head = "" if size is None else f"# image_size: {size[0]}x{size[1]}\n"
    body = "\n".join(",".join(repr(float(v)) for v in r) for r in rows)
    path.write_text(head + ",".join(columns) + "\n" + body + "\n")
    return path


@pytest.fixture(scope="module")
def room(tmp_path_factory):
    """An 80-point room (800x600) with per-pixel covariances, and a least-squares run of it
    (its result.json and run.json as ``bayescal calibrate`` writes them, without the report,
    to keep this fast)."""
    root = tmp_path_factory.mktemp("setups")
    ds = bc.simulate_room(range_mm=1000, n_points=80, sigma_px=0.2, approx_error=0.02,
                          approx_model="gaussian", rng=3)
    # extractor-like covariances: sd 0.2 px across the ring (radial), 2 px along it
    d = ds.pixels - [400.0, 300.0]
    n = d / np.linalg.norm(d, axis=1, keepdims=True)
    t = np.column_stack([-n[:, 1], n[:, 0]])
    cov = 0.04 * np.einsum("mi,mj->mij", n, n) + 4.0 * np.einsum("mi,mj->mij", t, t)
    sig = np.maximum(ds.sigma_scene, 1.0)
    rows = np.column_stack([ds.pixels, ds.approx_points, sig, cov[:, 0, 0], cov[:, 0, 1],
                            cov[:, 1, 1]])
    data = _csv(root / "laser.csv", ["u", "v", "x", "y", "z", "sigma_x", "sigma_y", "sigma_z",
                                     "cov_uu", "cov_uv", "cov_vv"], rows, (800, 600))
    res = bc.calibrate_simultaneous(ds.pixels, ds.approx_points, sigma_px=1.0,
                                    sigma_scene=sig, pixel_cov=cov)
    res.extras["sigma_px"] = 1.0                      # what calibrate records
    (root / "cal").mkdir()
    res.save(root / "cal" / "result.json")
    (root / "cal" / "run.json").write_text(json.dumps({
        "format": "bayescal-run", "version": 1, "method": "simultaneous",
        "inputs": {"data": str(data)}, "sigma_px": 1.0, "image_size": [800, 600],
        "sigma_px_how": "1 x the file's per-point covariances (cov_uu, cov_uv, cov_vv)"}))
    return root, ds, cov, res


def test_pixels_of_another_image_size_are_refused(room, capsys):
    root, ds, _, _ = room
    big = _csv(root / "big.csv", ["u", "v"], ds.pixels * 1.6, (1280, 1024))
    rc, cap = _main(["reconstruct", big, "--run", root / "cal", "--out", root / "r1"], capsys)
    assert rc == 2 and not (root / "r1").exists()
    assert "big.csv (image_size line): pixels of a 1280x1024 image, but the run" in cap.err
    assert "was calibrated on 800x600 images" in cap.err


@pytest.mark.parametrize("command", ["calibrate", "reconstruct"])
def test_an_image_size_option_against_the_file_is_refused(room, capsys, command):
    root, _, _, _ = room
    args = (["calibrate", root / "laser.csv"] if command == "calibrate" else
            ["reconstruct", root / "laser.csv", "--run", root / "cal"])
    rc, cap = _main([*args, "--image-size", "640x480", "--out", root / "o2"], capsys)
    assert rc == 2 and not (root / "o2").exists()
    assert "640x480" in cap.err and "800x600" in cap.err and "--image-size" in cap.err


def _camera(path, image_size=(1280, 1024), sizes=True):
    views, _ = bc.simulate_views(n_views=3, rng=2, image_size=image_size)
    if not sizes:
        views = [bc.BoardView(v.pixels, v.points, name=v.name) for v in views]
    bc.calibrate_camera(views, noise="plain").save(path)
    return path


def test_a_camera_of_another_image_size_is_refused(room, capsys):
    root, _, _, _ = room
    cam = _camera(root / "camera.json")
    rc, cap = _main(["calibrate", root / "laser.csv", "--camera", cam, "--out", root / "o3"],
                    capsys)
    assert rc == 2 and not (root / "o3").exists()
    assert f"--camera {cam} is 1280x1024 px but" in cap.err and "is 800x600 px" in cap.err


def test_a_camera_size_guessed_from_its_corners_is_no_size(tmp_path):
    from bayescal.cli.lasermodel import read_camera

    cam, size = read_camera(_camera(tmp_path / "c.json", sizes=False))
    assert size is None and cam.info["image_size_from"] == "corners"
    assert read_camera(_camera(tmp_path / "d.json"))[1] == (1280, 1024)


def test_an_image_frame_of_another_size_is_refused_and_pgm_is_an_image(room, capsys):
    import imageio.v3 as iio

    root, _, _, _ = room
    iio.imwrite(root / "big.png", np.zeros((1024, 1280), np.uint8))
    rc, cap = _main(["reconstruct", root / "big.png", "--run", root / "cal", "--out",
                     root / "o4"], capsys)
    assert rc == 2 and not (root / "o4").exists()
    assert "big.png is a 1280x1024 image but the run" in cap.err and "800x600 px" in cap.err
    iio.imwrite(root / "dark.pgm", np.full((600, 800), 20, np.uint8))
    rc, cap = _main(["reconstruct", root / "dark.pgm", "--run", root / "cal", "--out",
                     root / "o4"], capsys)
    assert rc == 2 and "dark.pgm: cannot extract laser pixels" in cap.err    # read as an image


def test_plain_pixels_on_a_covariance_run_get_its_typical_noise(room, capsys, monkeypatch):
    import matplotlib.pyplot as plt

    import bayescal.plotting

    root, ds, cov, res = room
    monkeypatch.setattr(bayescal.plotting, "plot_reconstruction_ellipses",    # (speed only)
                        lambda *a, **k: plt.figure(figsize=(1, 1)))
    plain = _csv(root / "plain.csv", ["u", "v"], ds.pixels, (800, 600))
    rc, cap = _main(["reconstruct", plain, "--run", root / "cal", "--out", root / "p"], capsys)
    assert rc == 0, cap.err
    # the medians of the calibration covariances, across and along the ring, times scale 1
    assert "pixel noise of plain.csv (no cov_uu, cov_uv, cov_vv columns): sd 0.2 px across " \
           "the ring and 2 px along it" in cap.out
    got = np.genfromtxt(root / "p" / "reconstruction.csv", delimiter=",", names=True)
    _, own = res.reconstructor()(ds.pixels, pixel_cov=cov)     # each pixel's own covariance
    _, iso = res.reconstructor(sigma_px=1.0)(ds.pixels)        # what 1 px would have been
    # the same covariances per pixel (the ring's normal is taken about the fitted principal
    # point, not 400, 300 exactly): sds within 2 %; 1 px all round is 2-5x wider
    for k, axis in enumerate("xyz"):
        np.testing.assert_allclose(got[f"sd_{axis}"], np.sqrt(own[:, k, k]), rtol=0.02)
    assert np.median(np.sqrt(iso[:, 2, 2]) / got["sd_z"]) > 2


def test_plain_pixels_without_the_run_covariances_are_refused(tmp_path):
    from bayescal.cli.matching import plain_pixel_noise
    from bayescal.errors import UsageError

    class Gone:                        # a posterior file: no covariances kept
        param_samples = np.zeros((2, 8))
        pixels = np.zeros((3, 2))

        def ring_noise(self):
            return None

    info = {"sigma_px_how": "1 x the file's per-point covariances (cov_uu, cov_uv, cov_vv)",
            "inputs": {"data": str(tmp_path / "gone.csv")}}
    with pytest.raises(UsageError, match=r"gone\.csv is gone or changed\); give --sigma-px PX"):
        plain_pixel_noise(Gone(), info, tmp_path, None)
    assert plain_pixel_noise(Gone(), info, tmp_path, 0.3) is None     # --sigma-px: taken
    assert plain_pixel_noise(Gone(), {"sigma_px_how": "given"}, tmp_path, None) is None


def test_a_truth_of_extracted_pixels(tmp_path, capsys):
    from bayescal.cli.matching import truth_for
    from bayescal.io.data import load_laser_data

    p = bc.SensorParams.paper()
    az = np.linspace(0, 2 * np.pi, 720, endpoint=False)
    ring_pts = np.column_stack([2000 * np.cos(az), 2000 * np.sin(az), np.full(720, -400.0)])
    ring_px = bc.project(p, ring_pts)
    _csv(tmp_path / "ring.csv", ["u", "v", "x", "y", "z", "azimuth"],
         np.column_stack([ring_px, ring_pts, az]))
    (tmp_path / "truth.json").write_text(json.dumps(
        {"params": p.as_dict(), "points": ring_pts[:580].tolist()}))
    k = np.arange(3, 720, 7)                                  # 103 "extracted" pixels
    _csv(tmp_path / "laser.csv", ["u", "v"], ring_px[k] + 0.01, (800, 600))
    data = load_laser_data(tmp_path / "laser.csv", need_points=False)
    truth = truth_for(tmp_path / "truth.json", data)
    assert "580 simulated points, 103 pixels in the data" in capsys.readouterr().out
    assert np.max(np.linalg.norm(truth["points"] - ring_pts[k], axis=1)) < 1.0
    assert "accuracy_note" in truth
    (tmp_path / "ring.csv").unlink()                          # no true centre line: params
    truth = truth_for(tmp_path / "truth.json", data)
    assert "points" not in truth and truth["params"] == p.as_dict()
    assert "compared: the parameters only" in capsys.readouterr().out


def test_help_shows_pairs_of_numbers_as_pairs(capsys):
    assert main(["simulate", "--help"]) == 0
    text = " ".join(capsys.readouterr().out.split())
    assert "degrees (a misaligned sensor; docs/conventions.md) (default: 0 0)" in text
    assert "along x and y, mm (default: 0 0)" in text and "(default: 800x600)" in text
    assert "0.0x0.0" not in text


def test_the_report_footnote_states_the_rule_the_rows_follow():
    from bayescal.likelihood.priors import default_prior
    from bayescal.report.report import _note, parameter_rows
    from bayescal.results.calibration import CalibrationResult, identifiability_report

    p = bc.SensorParams.paper()
    prior = default_prior(p)
    psd = np.array([prior[n].std() for n in bc.PARAM_NAMES])
    J = np.eye(8)
    J[:, 7] = J[:, 1] = 0.0                   # beta and phi: the data see neither
    res = CalibrationResult(
        method="simultaneous", params=p, points=None,
        covariance=np.diag((0.2 * psd) ** 2), covariance_identifiable=np.eye(7),
        residual_rms={}, sigma_px_estimated=None, n_residuals=10, n_unknowns=8,
        converged=True, message="ok", nfev=1,
        identifiability=identifiability_report(J, bc.PARAM_NAMES))
    rows = {r["name"]: r for r in parameter_rows(res, prior=prior)}
    # beta at sd ratio 0.2 is not flagged although the data alone leave it open: its
    # prior decides it only when the ratio says so; the footnote says both
    assert not rows["beta"]["prior_dominated"] and rows["phi"]["prior_dominated"]
    note = _note(res)
    assert "phi, alpha_u, alpha_v always" in note and "exceeds 0.5 x its prior sd" in note
    assert "Near-null directions of the data" in note and "+1.000 beta" in note
    assert "flagged only when its sd ratio shows" in note


def test_a_camera_of_another_size_without_the_data_size_line_is_hinted(room, capsys):
    root, _, _, _ = room
    lines = (root / "laser.csv").read_text().splitlines()
    (root / "nosize.csv").write_text("\n".join(lines[1:]) + "\n")     # no image_size line
    cam = _camera(root / "camera2.json")
    rc, cap = _main(["calibrate", root / "nosize.csv", "--camera", cam, "--out", root / "o6",
                     "--no-progress"], capsys)
    assert rc == 2 and not (root / "o6").exists()
    assert "degrees of azimuth around the principal point" in cap.err
    assert "camera2.json's: pixels of another camera or image size give this too" in cap.err


def test_the_licence_is_an_spdx_string_for_a_setuptools_that_takes_it():
    # setuptools >= 77 deprecates the table form ({ text = "MIT" }): pip printed its warning
    # three times per install
    import pathlib
    import re

    text = (pathlib.Path(__file__).resolve().parents[2] / "pyproject.toml").read_text()
    assert re.search(r'^license = "MIT"$', text, re.M)
    need = re.search(r'requires = \["setuptools>=(\d+)', text)
    assert need and int(need.group(1)) >= 77
