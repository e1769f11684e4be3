"""Commands that compose: ``simulate --images`` -> ``extract`` -> ``calibrate`` ->
``reconstruct`` with no hand editing, any camera size, extract's ``flagged`` column, and
the papercuts a new user met (each where it can fail)."""

import json
import os
import re
import stat

import numpy as np
import pytest
from helpers import run_cli

import bayescal as bc
from bayescal.cli.main import main
from bayescal.cli.options import cli_words

pytest.importorskip("imageio.v3")


#: ``bayescal ARGS`` in a folder, in this process
run = run_cli


def _numbers(path):
    """The numeric rows of a CSV written by bayescal ('#' lines and the header left out)."""
    with open(path) as f:
        return np.loadtxt([line for line in f if not line.startswith("#")][1:], delimiter=",",
                          ndmin=2)


def _z(res, truth):
    """z-scores of the identifiable parameters against the truth."""
    return (res.params.to_identifiable() - truth.to_identifiable()) / np.sqrt(
        np.diag(res.covariance_identifiable))


@pytest.fixture(scope="module")
def chain(tmp_path_factory):
    """simulate --images, then extract on its images: the files exactly as written."""
    root = tmp_path_factory.mktemp("chain")
    r = run("simulate", "--images", "--range-mm", 2500, "--n-points", 60, "--n-walls", 6,
            "--seed", 3, "--out", "sim", cwd=root)
    assert r.returncode == 0, r.stderr
    r = run("extract", "sim/image.png", "--background", "sim/image_off.png", "--along-sd", 1,
            "--out", "ex", cwd=root)
    assert r.returncode == 0, r.stderr
    return root


def test_chain_least_squares(chain):
    """No hand editing: extract's laser.csv goes into calibrate (flagged rows left out, the
    image size read from it) and reconstruct; the calibration holds the true sensor."""
    root = chain
    head = (root / "ex" / "laser.csv").read_text().splitlines()[:2]
    assert head == ["# image_size: 800x600", f"# offset_sd: {bc.image.extract.OFFSET_SD:g}"]
    a = _numbers(root / "ex" / "laser.csv")
    flagged = a[:, 6] == 1
    assert set(np.unique(a[:, 6])) <= {0.0, 1.0}
    r = run("calibrate", "ex/laser.csv", "--walls", "sim/walls.csv", "--out", "cal",
            "--no-progress", cwd=root)
    assert r.returncode == 0, r.stderr
    assert "ignoring column" not in r.stderr
    if flagged.any():
        assert f"{int(flagged.sum())} of {len(a)} points flagged by extract" in r.stdout
    assert "converged (converged" not in r.stdout
    # the fit took the file's per-point covariances: a scale on them, not a noise in px
    assert re.search(r"estimated pixel covariance scale: [\d.]+ \(", r.stdout), r.stdout
    assert "estimated pixel noise" not in r.stdout
    res = bc.load_result(root / "cal" / "result.json")
    assert len(res.points) == int((~flagged).sum())
    # the ring's shared translation went into the variances of u0 and v0
    assert res.extras["offset_sd"] == bc.image.extract.OFFSET_SD
    # simulate --images renders the design sensor; 5 sd: a false failure ~1e-6 per parameter
    assert np.all(np.abs(_z(res, bc.SensorParams.paper())) < 5)
    info = json.loads((root / "cal" / "run.json").read_text())
    assert info["image_size"] == [800, 600]
    r = run("reconstruct", "ex/laser.csv", "--run", "cal", "--out", "rec", cwd=root)
    assert r.returncode == 0, r.stderr
    rec = _numbers(root / "rec" / "reconstruction.csv")
    assert len(rec) == int((~flagged).sum())
    np.testing.assert_allclose(rec[:, :2], a[~flagged, :2], rtol=0, atol=1e-9)


@pytest.mark.slow
def test_chain_bayes(chain):
    """The same files into the posterior on the floor plan."""
    r = run("calibrate", "ex/laser.csv", "--walls", "sim/walls.csv", "--method", "bayes",
            "--out", "post", "--no-progress", cwd=chain)
    assert r.returncode == 0, r.stderr
    post = bc.load_posterior(chain / "post" / "posterior.npz")
    sd = post.param_samples.std(axis=0)
    z = (post.param_samples.mean(axis=0) - bc.SensorParams.paper().to_array()) / sd
    assert np.all(np.abs(z[[0, 4, 5, 6, 7]]) < 5)
    r = run("reconstruct", "ex/laser.csv", "--run", "post", "--out", "rec", cwd=chain)
    assert r.returncode == 0, r.stderr


def test_flagged_rows_left_out_and_named(tmp_path):
    """A laser file whose gross rows are flagged: they are left out, by line."""
    ds = bc.simulate_room(range_mm=1000, n_points=60, sigma_px=0.2, approx_error=0.03, rng=5)
    px = ds.pixels.copy()
    px[[3, 17]] += 40.0                                  # two gross rows, flagged
    flag = np.zeros(60, int)
    flag[[3, 17]] = 1
    cols = np.column_stack([px, ds.approx_points, np.maximum(ds.sigma_scene[:, :2], 1.0),
                            np.full(60, 0.2), flag])
    lines = ["u,v,x,y,z,sigma_x,sigma_y,sigma_px,flagged"]
    lines += [",".join(f"{v:.10g}" for v in row[:-1]) + f",{int(row[-1])}" for row in cols]
    (tmp_path / "f.csv").write_text("\n".join(lines) + "\n")
    r = run("calibrate", "f.csv", "--out", "cal", "--no-outliers", cwd=tmp_path)
    assert r.returncode == 0, r.stderr
    assert "f.csv: 2 of 60 points flagged by extract (flagged = 1) left out of the " \
           "calibration: lines 5, 19" in r.stdout
    res = bc.load_result(tmp_path / "cal" / "result.json")
    assert len(res.points) == 58 and np.all(np.abs(_z(res, ds.params)) < 5)
    bad = "\n".join(lines[:3] + [lines[3].rsplit(",", 1)[0] + ",2"]) + "\n"
    (tmp_path / "bad.csv").write_text(bad)
    r = run("calibrate", "bad.csv", "--out", "cal2", cwd=tmp_path)
    assert r.returncode == 2 and "bad.csv, line 4, column 'flagged'" in r.stderr
    assert not (tmp_path / "cal2").exists()


def test_any_camera_size(tmp_path):
    """A 1280x1024 camera: the image size travels in laser.csv, the design values derive
    from it (or come in part from --nominal), and the calibration holds the truth."""
    r = run("simulate", "--image-size", "1280x1024", "--range-mm", 2500, "--n-points", 80,
            "--n-walls", 6, "--sigma-px", 0.2, "--approx-error", 0.03, "--seed", 1,
            "--out", "sim", cwd=tmp_path)
    assert r.returncode == 0, r.stderr
    truth = bc.SensorParams(**json.loads((tmp_path / "sim" / "truth.json").read_text())
                            ["params"])
    assert (truth.u0, truth.v0) == (640.0, 512.0)
    assert (tmp_path / "sim" / "laser.csv").read_text().startswith("# image_size: 1280x1024")
    r = run("calibrate", "sim/laser.csv", "--out", "cal", cwd=tmp_path)
    assert r.returncode == 0, r.stderr
    assert "u0 = 640 (image centre)" in r.stdout and "focal scale from the approximate " \
           "points" in r.stdout
    res = bc.load_result(tmp_path / "cal" / "result.json")
    assert np.all(np.abs(_z(res, truth)) < 5)
    # the design values in part: the principal point given, the focal scale derived
    (tmp_path / "design.json").write_text('{"u0": 641, "v0": 511}')
    r = run("calibrate", "sim/laser.csv", "--walls", "sim/walls.csv", "--nominal",
            "design.json", "--out", "cal2", cwd=tmp_path)
    assert r.returncode == 0, r.stderr
    assert "u0 = " not in r.stdout.split("design values", 1)[-1].split("\n", 1)[0]
    assert "focal scale from the floor plan" in r.stdout
    assert json.loads((tmp_path / "cal2" / "run.json").read_text())["nominal"]["u0"] == 641
    (tmp_path / "bad.json").write_text('{"u0": 641, "focal": 3}')
    r = run("calibrate", "sim/laser.csv", "--nominal", "bad.json", "--out", "x", cwd=tmp_path)
    assert r.returncode == 2 and "unknown parameter(s) focal" in r.stderr
    # a value no sensor has: exit 2 naming it, not a traceback
    (tmp_path / "neg.json").write_text('{"h": -5}')
    r = run("calibrate", "sim/laser.csv", "--nominal", "neg.json", "--out", "y", cwd=tmp_path)
    assert r.returncode == 2 and "--nominal" in r.stderr and "h must be positive" in r.stderr
    assert not (tmp_path / "y").exists()


def test_simulate_floors_scene_sd_and_tiny_sds_are_read_as_known(tmp_path):
    """150 points put one on the y axis (x ~ 1e-13 mm): simulate writes its sd as 1 mm; a
    file with the library's 3.3e-15 mm (what simulate_room gives) is read with 1e-9 mm, said
    with its line, as the library fits it; and the library's model check copes with it."""
    r = run("simulate", "--range-mm", 2500, "--n-points", 150, "--n-walls", 6, "--sigma-px",
            0.2, "--approx-error", 0.03, "--seed", 2, "--out", "sim", cwd=tmp_path)
    assert r.returncode == 0, r.stderr
    sig = _numbers(tmp_path / "sim" / "laser.csv")[:, 5:8]
    assert np.nanmin(sig) == 1.0
    ds = bc.simulate_room(range_mm=2500, n_points=150, n_walls=6, sigma_px=0.2,
                          approx_error=0.03, rng=2)
    k = int(np.argmin(ds.sigma_scene[:, 0]))
    assert ds.sigma_scene[k, 0] < 1e-12
    from bayescal.io.data import write_laser_csv

    write_laser_csv(tmp_path / "old.csv", ds.pixels, ds.approx_points,
                    sigma_scene=ds.sigma_scene, sigma_px=0.2)
    r = run("calibrate", "old.csv", "--out", "cal", cwd=tmp_path)
    assert r.returncode == 0, r.stderr
    assert f"old.csv: standard deviation(s) below 1e-09 on line(s) {k + 2} (sigma_x)" in r.stderr
    res = bc.calibrate_simultaneous(ds.pixels, ds.approx_points, sigma_px=0.2,
                                    sigma_scene=ds.sigma_scene)
    assert res.model_check().fits


def test_papercuts(tmp_path, capsys):
    """Output folders follow the umask, --method lsq, a sequential report, integer
    columns, advice in the CLI's words, a matrix breakdown without a traceback."""
    old = os.umask(0o027)
    try:
        assert main(["simulate", "--n-points", "40", "--out", str(tmp_path / "sim")]) == 0
    finally:
        os.umask(old)
    assert stat.S_IMODE((tmp_path / "sim").stat().st_mode) == 0o750
    sim = tmp_path / "sim"
    assert main(["calibrate", str(sim / "laser.csv"), "--method", "lsq", "--out",
                 str(tmp_path / "lsq")]) == 0
    assert json.loads((tmp_path / "lsq" / "run.json").read_text())["method"] == "simultaneous"
    assert main(["calibrate", "--method", "sequential", "--calibration",
                 str(sim / "calibration.npz"), "--out", str(tmp_path / "seq")]) == 0
    assert "## Parameters" in (tmp_path / "seq" / "report.md").read_text()
    assert main(["report", str(tmp_path / "seq"), "--out", str(tmp_path / "seqrep")]) == 0
    grid = (sim / "grid.csv").read_text().splitlines()
    assert re.match(r"^[0-3],", grid[1])                       # plane as an integer
    half = (sim / "laser.csv").read_text().splitlines()
    (tmp_path / "a.csv").write_text("\n".join(half[:20]) + "\n")
    (tmp_path / "b.csv").write_text("\n".join(half[:4] + half[20:30]) + "\n")
    assert main(["reconstruct", str(tmp_path / "a.csv"), str(tmp_path / "b.csv"), "--run",
                 str(tmp_path / "lsq"), "--out", str(tmp_path / "rec")]) == 0
    frames = (tmp_path / "rec" / "frames.csv").read_text().splitlines()
    rows = [line.split(",") for line in frames if not line.startswith("#")]
    assert rows[0][:3] == ["frame", "points", "missed"] and rows[1][:3] == ["0", "16", "0"]
    assert cli_words("refit with outliers=False; give sigma_px explicitly; within "
                     "max_steps=300") == ("refit with --no-outliers; give --sigma-px; within "
                                          "--max-steps 300")
    capsys.readouterr()

    def broken(job, folder):
        raise np.linalg.LinAlgError("Singular matrix")

    import bayescal.cli.runs as runs

    keep, runs.run_calibrate = runs.run_calibrate, broken
    try:
        code = main(["calibrate", str(sim / "laser.csv"), "--out", str(tmp_path / "lin")])
    finally:
        runs.run_calibrate = keep
    err = capsys.readouterr().err
    assert code == 1 and "matrix computation broke down" in err and "Traceback" not in err
    assert not (tmp_path / "lin").exists()
