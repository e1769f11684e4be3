"""The command line end to end (in this process; by subprocess where the interpreter
matters), its output-folder rules, and the report helpers.

Every bad-input case checks three things: exit code 2, a message naming the
file, line and column, and that nothing was written.
"""

import json
import os
import pathlib
import re
import subprocess
import sys

import numpy as np
import pytest
from helpers import run_cli

import bayescal
import bayescal as bc
import bayescal.io.data
from bayescal.cli.main import MANIFEST
from bayescal.report.report import linear_reconstruction

N_POINTS = 60


#: ``bayescal ARGS`` in a folder, in this process
run = run_cli


@pytest.fixture(scope="module")
def sim(tmp_path_factory):
    """A simulated 60-point room written by ``bayescal simulate``."""
    root = tmp_path_factory.mktemp("cli")
    r = run("simulate", "--out", "sim", "--n-points", N_POINTS, "--seed", 4, cwd=root)
    assert r.returncode == 0, r.stderr
    return root / "sim"


@pytest.fixture(scope="module")
def seq_run(sim):
    """A sequential calibration run (reused by reconstruct and report tests)."""
    root = sim.parent
    r = run("calibrate", sim / "laser.csv", "--method", "sequential", "--calibration",
            sim / "calibration.npz", "--truth", sim / "truth.json", "--out", "seq", cwd=root)
    assert r.returncode == 0, r.stderr
    return root / "seq", r


# -- help and usage -----------------------------------------------------------------

@pytest.mark.parametrize("cmd", ["", "simulate", "calibrate", "reconstruct", "report", "study",
                                 "demo"])
def test_help_on_every_command(tmp_path, cmd):
    r = run(*([cmd] if cmd else []), "--help", cwd=tmp_path)
    assert r.returncode == 0
    assert "usage: bayescal" in r.stdout
    if cmd in ("simulate", "calibrate", "demo"):
        assert "--seed" in r.stdout and "--force" in r.stdout and "--out" in r.stdout
    assert list(tmp_path.iterdir()) == []


def test_usage_errors_exit_2(tmp_path):
    assert run(cwd=tmp_path).returncode == 2
    r = run("calibrate", "--method", "magic", cwd=tmp_path)
    assert r.returncode == 2 and "invalid choice: 'magic'" in r.stderr
    assert list(tmp_path.iterdir()) == []


def test_console_script_entry_point_is_console_main():
    from importlib.metadata import PackageNotFoundError, distribution, entry_points

    try:
        distribution("bayescal")
    except PackageNotFoundError:
        pytest.skip("bayescal is not installed (run from a source tree): no entry points")
    eps = [e for e in entry_points(group="console_scripts") if e.name == "bayescal"]
    assert [e.value for e in eps] == ["bayescal.cli.main:console_main"]


# -- simulate -------------------------------------------------------------------------

def test_simulate_writes_inputs_that_match_the_library(sim):
    truth = json.loads((sim / "truth.json").read_text())
    ds = bc.simulate_room(range_mm=5000, n_points=N_POINTS, sigma_px=0.1, approx_error=0.05,
                          rng=4)
    data = bayescal.io.data.load_laser_data(sim / "laser.csv")
    np.testing.assert_array_equal(data.pixels, ds.pixels)
    np.testing.assert_array_equal(data.approx_points, ds.approx_points)
    np.testing.assert_array_equal(np.asarray(truth["points"]), ds.points)
    assert truth["params"] == ds.params.as_dict()
    npz = bayescal.io.data.load_laser_data(sim / "laser.npz")
    np.testing.assert_array_equal(npz.sigma_scene, data.sigma_scene)
    manifest = json.loads((sim / MANIFEST).read_text())
    assert sorted(manifest["files"]) == sorted(
        ["laser.csv", "laser.npz", "calibration.npz", "grid.csv", "calib_laser.csv",
         "truth.json", "walls.csv"])
    from bayescal.io.planfile import load_walls

    plan, _ = load_walls(sim / "walls.csv")        # the simulation's rough plan, sds included
    np.testing.assert_allclose(plan.segments, ds.floor_plan.segments, rtol=1e-15)
    np.testing.assert_allclose(plan.distance_sd, ds.floor_plan.distance_sd, rtol=1e-15)
    np.testing.assert_allclose(plan.angle_sd, ds.floor_plan.angle_sd, rtol=1e-15)


def test_simulate_bad_option_writes_nothing(tmp_path):
    r = run("simulate", "--out", "s", "--range-mm", "-5", cwd=tmp_path)
    assert r.returncode == 2 and "--range-mm" in r.stderr
    assert "'-5' is not a finite positive number" in r.stderr and len(r.stderr.splitlines()) == 1
    assert not (tmp_path / "s").exists()


# -- output folders ------------------------------------------------------------------

def test_output_folder_is_never_overwritten_without_force(sim, tmp_path):
    out = tmp_path / "out"
    out.mkdir()
    (out / "mine.txt").write_text("user data")
    # a folder bayescal did not write: --force is not suggested (it would be refused too)
    r = run("simulate", "--out", out, "--n-points", 10, cwd=tmp_path)
    assert r.returncode == 2 and "was not written by bayescal" in r.stderr
    assert "--force or not: choose a new or empty folder, e.g. --out" in r.stderr
    assert f"{out}-2" in r.stderr
    r = run("simulate", "--out", out, "--n-points", 10, "--force", cwd=tmp_path)
    assert r.returncode == 2 and "was not written by bayescal" in r.stderr
    assert [p.name for p in out.iterdir()] == ["mine.txt"]


def test_force_replaces_only_bayescal_files(tmp_path):
    assert run("simulate", "--out", "o", "--n-points", 10, cwd=tmp_path).returncode == 0
    (tmp_path / "o" / "notes.txt").write_text("keep me")
    (tmp_path / "o" / "laser.npz").unlink()
    r = run("simulate", "--out", "o", "--n-points", 12, "--force", cwd=tmp_path)
    assert r.returncode == 0, r.stderr
    assert (tmp_path / "o" / "notes.txt").read_text() == "keep me"
    assert len(bayescal.io.data.load_laser_data(tmp_path / "o" / "laser.npz").pixels) == 12


def test_refuses_to_write_into_the_folder_holding_the_inputs(sim):
    before = sorted(p.name for p in sim.iterdir())
    r = run("calibrate", "laser.csv", "--method", "sequential", "--calibration",
            "calibration.npz", "--out", ".", "--force", cwd=sim)
    assert r.returncode == 2 and "holds the input file" in r.stderr
    assert sorted(p.name for p in sim.iterdir()) == before


# -- bad input: exit 2, located message, nothing written --------------------------------

BAD_CSV = [
    ("", r"the file is empty"),
    ("u,v,x,y\n450,300,1000,0\n", r"line 1: missing column\(s\) 'z'"),
    ("u,v,X_mm,y,z\n450,300,1000,0,377\n", r"missing column\(s\) 'x'"),
    ("u,v,x,y,z\n450,300,1000,0,377\n451,301,nan,0,377\n", r"line 3, column 'x': NaN"),
    ("u,v,x,y,z\n450,300,1000,0,377\n451,30l,1000,0,377\n",
     r"line 3, column 'v': could not read '30l' as a number"),
    ("u,v,x,y,z\n450,300,1000,0,377\n4500,300,1000,0,377\n",
     r"line 3, column 'u': pixel u = 4500 is outside the image; expected -50 <= u <= 850"),
    ("u,v,x,y,z\n450,300,1000,0,377\n451,301,0,0,800\n",
     r"line 3, column 'x, y, z': point \(0, 0, 800\) mm is outside the projection domain"),
    ("u,v,x,y,z\n450,300,1000,0,377\n451,301,1000,0\n", r"line 3: 4 fields, expected 5"),
    # checked by the model itself before anything is written (no sigma given: inferred
    # relative to the horizontal range, impossible on the axis)
    ("u,v,x,y,z\n450,300,1000,0,377\n400,300,0,0,-300\n", r"approx_points on the axis"),
]


@pytest.mark.parametrize("text, match", BAD_CSV)
def test_bad_input_exit_2_and_nothing_written(tmp_path, text, match):
    (tmp_path / "data.csv").write_text(text)
    r = run("calibrate", "data.csv", "--out", "out", cwd=tmp_path)
    assert r.returncode == 2, r.stderr
    assert "data.csv" in r.stderr
    import re

    assert re.search(match, r.stderr), r.stderr
    assert sorted(p.name for p in tmp_path.iterdir()) == ["data.csv"]


def test_mismatched_pixel_and_point_files(tmp_path):
    (tmp_path / "pix.csv").write_text("u,v\n450,300\n451,301\n452,302\n")
    (tmp_path / "pts.csv").write_text("x,y,z\n1000,0,377\n1000,10,377\n")
    r = run("calibrate", "pix.csv", "--points", "pts.csv", "--out", "out", cwd=tmp_path)
    assert r.returncode == 2
    assert "pix.csv has 3 points (u, v) but" in r.stderr and "pts.csv has 2" in r.stderr
    assert not (tmp_path / "out").exists()


def test_image_size_option_moves_the_limit(tmp_path):
    (tmp_path / "data.csv").write_text("u,v,x,y,z\n1500,300,1000,0,377\n")
    r = run("calibrate", "data.csv", "--image-size", "1600x1200", "--image-margin", "0",
            "--out", "out", cwd=tmp_path)
    # the pixel is now inside; the next check (too few points) fails instead
    assert r.returncode == 2 and "1 laser point(s); expected at least 5" in r.stderr
    r = run("calibrate", "data.csv", "--image-size", "800by600", "--out", "o", cwd=tmp_path)
    assert r.returncode == 2 and "--image-size: '800by600': expected WIDTHxHEIGHT" in r.stderr
    assert sorted(p.name for p in tmp_path.iterdir()) == ["data.csv"]


@pytest.mark.parametrize("opts, match", [
    (["--prior", "h=norm200"], r"expected NAME=DIST\(ARGS\)"),
    (["--prior", "height=norm(200, 20)"], r"unknown parameter 'height'"),
    (["--prior", "h=gaussian(200, 20)"], r"'gaussian' is not a scipy.stats continuous"),
    (["--sigma-px", "-1"], r"--sigma-px: '-1' is not a finite positive number"),
    (["--sigma-scene", "1,2"], r"--sigma-scene: '1,2': expected 'infer'"),
    (["--sigma-scene", "x"], r"--sigma-scene: could not read 'x' as a number"),
    (["--seed", "-3"], r"--seed: -3 is negative; expected an integer >= 0"),
    (["--max-steps", "0"], r"--max-steps: 0 is not positive"),
    (["--sigma-scene", "inf,inf,inf"], r"gives no information on any axis"),
    (["--method", "sequential"], r"needs --calibration FILE"),
    (["--nominal", "missing.json"], r"missing.json: no such file"),
])
def test_bad_options_exit_2(sim, tmp_path, opts, match):
    r = run("calibrate", sim / "laser.csv", *opts, "--out", "out", cwd=tmp_path)
    assert r.returncode == 2
    import re

    assert re.search(match, r.stderr), r.stderr
    assert len(r.stderr.strip().splitlines()) == 1 and "Traceback" not in r.stderr
    assert list(tmp_path.iterdir()) == []


def test_bad_calibration_file(sim, tmp_path):
    np.savez(tmp_path / "cal.npz", grid_points=np.zeros((4, 3)))
    r = run("calibrate", sim / "laser.csv", "--method", "sequential", "--calibration",
            "cal.npz", "--out", "out", cwd=tmp_path)
    assert r.returncode == 2 and "cal.npz: missing array(s) grid_pixels" in r.stderr
    assert not (tmp_path / "out").exists()


# -- calibrate, reconstruct, report ------------------------------------------------------

def _check_report(folder):
    html = (folder / "report.html").read_text()
    md = (folder / "report.md").read_text()
    assert "data:image/png;base64," in html and "src='" not in html.replace(
        "src='data:image/png;base64,", "")                  # self-contained
    for line in md.splitlines():
        if line.startswith("!["):
            assert (folder / line.split("](")[1].rstrip(")")).is_file()
    assert "prior-dominated" in md
    files = json.loads((folder / MANIFEST).read_text())["files"]
    assert all((folder / f).is_file() for f in files)
    return md


def test_calibrate_sequential_end_to_end(seq_run):
    folder, r = seq_run
    res = bc.load_result(folder / "result.json")
    assert res.method == "sequential" and res.converged
    rows = res.summary_rows()
    assert [row["name"] for row in rows] == list(bc.PARAM_NAMES)
    assert res.covariance().shape == (8, 8)
    # phi is held fixed by the sequential method: flagged, with sd 0
    assert rows[1]["prior_dominated"] and rows[1]["sd"] == 0
    md = _check_report(folder)
    assert "Accuracy against the simulation truth" in md
    assert "mean 3D error against the truth" in r.stdout
    # both stages' residuals are plotted (they survive the result file)
    assert (folder / "residuals.png").is_file() and "residuals of both stages" in md
    pts = bayescal.io.data.read_table(folder / "points.csv", required=("x", "y", "z", "sd_x"))
    assert len(pts) == N_POINTS


def test_reconstruct_matches_triangulation(seq_run, sim, tmp_path):
    folder, _ = seq_run
    truth = json.loads((sim / "truth.json").read_text())
    pix = np.asarray(truth["pixels_true"])[:7]
    (tmp_path / "new.csv").write_text("u,v\n" + "".join(f"{a!r},{b!r}\n" for a, b in pix.tolist()))
    r = run("reconstruct", "new.csv", "--run", folder, "--out", "rec", cwd=tmp_path)
    assert r.returncode == 0, r.stderr
    t = bayescal.io.data.read_table(tmp_path / "rec" / "reconstruction.csv",
                               required=("x", "y", "z", "sd_x", "sd_y", "sd_z"))
    params = bc.load_result(folder / "result.json").params
    got = np.column_stack([t.columns[c] for c in "xyz"])
    np.testing.assert_allclose(got, bc.triangulate(params, pix), rtol=1e-12, atol=1e-9)
    assert np.all(t.columns["sd_x"] > 0)
    assert (tmp_path / "rec" / "reconstruction.png").is_file()


def test_reconstruct_bad_pixels_and_bad_run(seq_run, tmp_path):
    folder, _ = seq_run
    (tmp_path / "new.csv").write_text("u,v\n450,300\n450,-900\n")
    r = run("reconstruct", "new.csv", "--run", folder, "--out", "rec", cwd=tmp_path)
    assert r.returncode == 2 and "line 3, column 'v': pixel v = -900" in r.stderr
    r = run("reconstruct", "new.csv", "--run", tmp_path, "--out", "rec", cwd=tmp_path)
    assert r.returncode == 2 and "not a calibration output folder" in r.stderr
    assert not (tmp_path / "rec").exists()


def test_report_rebuilds_from_a_run(seq_run, sim, tmp_path):
    folder, _ = seq_run
    r = run("report", folder, "--out", "rep", cwd=tmp_path)
    assert r.returncode == 0, r.stderr
    md = _check_report(tmp_path / "rep")
    assert "truth" in md        # the run recorded its --truth file
    r = run("report", folder, "--out", "rep", cwd=tmp_path)
    assert r.returncode == 2 and "holds an earlier bayescal run; pass --force" in r.stderr


@pytest.fixture(scope="module")
def simul_run(sim):
    """A simultaneous (MAP) run from laser.csv."""
    root = sim.parent
    r = run("calibrate", sim / "laser.csv", "--truth", sim / "truth.json", "--out", "simul",
            cwd=root)
    return root / "simul", r


def test_calibrate_simultaneous_end_to_end(simul_run, sim):
    folder, r = simul_run
    assert r.returncode == 0, r.stderr
    res = bc.load_result(folder / "result.json")
    assert res.method == "simultaneous" and res.converged
    rows = {row["name"]: row for row in res.summary_rows()}
    # phi, alpha_u, alpha_v are set by the prior, never by the data (docs/model.md)
    assert all(rows[n]["prior_dominated"] for n in ("phi", "alpha_u", "alpha_v"))
    assert not rows["u0"]["prior_dominated"]
    md = _check_report(folder)
    assert "residuals.png" in md and "reconstruction.png" in md
    # points.csv holds the jointly fitted points: they reproject onto the pixels (the
    # approximate points would miss them by several px at 5 % error)
    t = bayescal.io.data.read_table(folder / "points.csv", required=("x", "y", "z"))
    pred = bc.project(res.params,
                      np.column_stack([t.columns[c] for c in "xyz"]))
    pix = bayescal.io.data.load_laser_data(sim / "laser.csv").pixels
    assert np.sqrt(np.mean((pred - pix) ** 2)) < 3 * 0.1     # residual RMS below 3 sigma_px
    d = bayescal.io.data.load_laser_data(sim / "laser.csv")
    approx_pred = bc.project(res.params, d.approx_points)
    assert np.sqrt(np.mean((approx_pred - pix) ** 2)) > 3 * 0.1


def test_calibrate_simultaneous_split_files_agree(simul_run, sim, tmp_path):
    d = bayescal.io.data.load_laser_data(sim / "laser.csv")
    (tmp_path / "pix.csv").write_text("u,v\n" + "".join(f"{a!r},{b!r}\n" for a, b in
                                                         d.pixels.tolist()))
    (tmp_path / "pts.csv").write_text("x,y,z,sigma_x,sigma_y\n" + "".join(
        f"{x!r},{y!r},{z!r},{sx!r},{sy!r}\n" for (x, y, z), (sx, sy, _) in
        zip(d.approx_points.tolist(), d.sigma_scene.tolist(), strict=True)))
    r = run("calibrate", "pix.csv", "--points", "pts.csv", "--sigma-px", "0.1", "--out", "a",
            cwd=tmp_path)
    assert r.returncode == 0, r.stderr
    a = bc.load_result(tmp_path / "a" / "result.json").params.to_array()
    b = bc.load_result(simul_run[0] / "result.json").params.to_array()
    np.testing.assert_allclose(a, b, rtol=1e-10)


@pytest.fixture(scope="module")
def bayes_run(sim):
    root = sim.parent
    r = run("calibrate", sim / "laser.csv", "--method", "bayes", "--max-steps", 40,
            "--no-progress", "--truth", sim / "truth.json", "--out", "bayes", cwd=root)
    return root / "bayes", r


def test_converged_bayes_run_prints_nothing_on_stderr(sim, tmp_path):
    """A clean converged run says nothing on stderr: no stray library line (corner used to
    log "Too few points to create valid contours" for the alpha_u, alpha_v ridge)."""
    r = run("calibrate", sim / "laser.csv", "--method", "bayes", "--no-progress", "--out", "o",
            cwd=tmp_path)
    assert r.returncode == 0, r.stderr
    assert r.stderr == "" and (tmp_path / "o" / "corner.png").exists()


def test_bayes_unconverged_is_exit_1_with_outputs(bayes_run):
    folder, r = bayes_run
    # 40 steps cannot hold 50 autocorrelation times: tau >= 1 and the burn-in takes >= 1/4
    assert r.returncode == 1, r.stderr
    assert "did not converge" in r.stderr and "--allow-unconverged" in r.stderr
    s = json.loads((folder / "run.json").read_text())
    assert s["method"] == "bayes" and not bc.load_posterior(folder / "posterior.npz").converged
    assert (folder / "posterior.npz").is_file() and (folder / "corner.png").is_file()
    _check_report(folder)


def test_bayes_reconstruct_and_report(bayes_run, sim, tmp_path):
    folder, _ = bayes_run
    d = bayescal.io.data.load_laser_data(sim / "laser.csv")
    (tmp_path / "new.csv").write_text("u,v\n" + "".join(f"{a!r},{b!r}\n" for a, b in
                                                         d.pixels[:5].tolist()))
    r = run("reconstruct", "new.csv", "--run", folder, "--out", "rec", cwd=tmp_path)
    assert r.returncode == 0, r.stderr
    r = run("report", folder, "--out", "rep", cwd=tmp_path)
    assert r.returncode == 0, r.stderr
    assert (tmp_path / "rep" / "corner.png").is_file()


def test_bayes_report_has_the_predictive_check_and_outlier_column(bayes_run):
    folder, _ = bayes_run
    md = (folder / "report.md").read_text()
    assert "Posterior predictive check: " in md and (folder / "predictive.png").is_file()
    post = bc.load_posterior(folder / "posterior.npz")
    header = (folder / "points.csv").read_text().splitlines()[0].split(",")
    # the column is there exactly when the posterior carries outlier probabilities
    assert ("outlier_prob" in header) == (getattr(post, "outlier_prob", None) is not None)


def test_posterior_residuals_is_the_predictive_check_residuals(bayes_run):
    from bayescal.checks.predictive import posterior_predictive_residuals
    from bayescal.checks.residuals import draw_indices, posterior_residuals

    post = bc.load_posterior(bayes_run[0] / "posterior.npz")
    pix, scene = posterior_residuals(post, n_draws=7, scene=True)
    idx = draw_indices(post.n_samples, 7)
    ref_pix, ref_scene = posterior_predictive_residuals(
        post.param_samples[idx], post.point_samples[idx], post.pixels, post.approx_points,
        sigma_px=post._sigma_px_samples()[idx], sigma_scene=post.sigma_scene)
    np.testing.assert_allclose(pix, -ref_pix, rtol=1e-12)
    np.testing.assert_allclose(scene, -ref_scene, rtol=1e-12)
    # data minus model: the first draw's first pixel by hand
    p0 = bc.SensorParams.from_array(post.param_samples[idx[0]])
    hand = (post.pixels[0] - bc.project(p0, post.point_samples[idx[0], 0]))
    np.testing.assert_allclose(pix[0, 0] * post._sigma_px_samples()[idx[0]], hand, rtol=1e-9)


# -- study and demo --------------------------------------------------------------------

def test_study_unknown_name_lists_available(tmp_path):
    (tmp_path / "studies").mkdir()
    (tmp_path / "studies" / "range_sweep.py").write_text("")
    (tmp_path / "studies" / "_helpers.py").write_text("")
    (tmp_path / "studies" / "benchmark.py").write_text("")
    env = {"BAYESCAL_STUDIES_DIR": str(tmp_path / "studies")}
    r = run("study", "nope", "--out", "o", cwd=tmp_path, env=env)
    assert r.returncode == 2
    assert "no study named 'nope'" in r.stderr and "available: range_sweep" in r.stderr
    assert "_helpers" not in r.stderr and "benchmark" not in r.stderr.split("available:")[1]
    assert not (tmp_path / "o").exists()
    # the benchmark script writes a file, not a study folder: not runnable as a study
    r = run("study", "benchmark", "--out", "o", cwd=tmp_path, env=env)
    assert r.returncode == 2 and "no study named 'benchmark'" in r.stderr


def test_study_runs_the_script_with_out_and_quick(tmp_path, capfd):
    (tmp_path / "studies").mkdir()
    (tmp_path / "studies" / "echo.py").write_text(
        "import pathlib, sys\n"
        "args = sys.argv[1:]\n"
        "out = pathlib.Path(args[args.index('--out') + 1])\n"
        "(out / 'args.txt').write_text(' '.join(args))\n"
        "import bayescal.cli.studyrun as s\n"
        "s.study_main(lambda a, o: (o / 'r.txt').write_text('x'), 'echo',\n"
        "             ['--out', str(out), '--force'], ['r.txt'])\n"
        "sys.exit(3 if '--fail' in out.name else 0)\n")
    env = {"BAYESCAL_STUDIES_DIR": str(tmp_path / "studies")}
    r = run("study", "echo", "--out", "o", "--quick", cwd=tmp_path, env=env)
    assert r.returncode == 0, r.stderr
    args = (tmp_path / "o" / "args.txt").read_text().split()
    assert args[args.index("--seed") + 1] == "0" and args[args.index("--workers") + 1] == "2"
    assert "--quick" in args and "--scheduler" not in args
    assert not [p for p in tmp_path.iterdir() if "bayescal-tmp" in p.name]
    # the script's last line names the final folder, not the staging one it wrote into (the
    # script is a child process: its lines go to this process's file descriptor 1)
    out = r.stdout + capfd.readouterr().out
    assert "wrote o/r.txt" in out and "bayescal-tmp" not in out, out
    r = run("study", "echo", "--out", "x--fail", cwd=tmp_path, env=env)
    assert r.returncode == 1 and "study echo exited with code 3" in r.stderr


def test_default_studies_dir_is_beside_the_package():
    from pathlib import Path

    from bayescal.cli.studyrun import studies_dir

    env = os.environ.pop("BAYESCAL_STUDIES_DIR", None)
    try:
        assert studies_dir() == Path(bayescal.__file__).resolve().parents[1] / "studies"
    finally:
        if env is not None:
            os.environ["BAYESCAL_STUDIES_DIR"] = env


@pytest.mark.slow
def test_demo_small(tmp_path):
    """The demo's plumbing on a small room (~30 s, so in the slow set)."""
    r = run("demo", "--out", "out", "--n-points", 30, "--max-steps", 200, "--no-progress",
            "--allow-unconverged", cwd=tmp_path)
    assert r.returncode == 0, r.stdout + r.stderr
    out = tmp_path / "out"
    for f in ("index.html", "index.md", "data/laser.csv", "sequential/report.html",
              "simultaneous/report.html", "bayes/report.html", "bayes/posterior.npz",
              "data/walls.csv", "floorplan/report.html", "floorplan/plan.png",
              "data/laser_image.png", "data/laser_off.png", "image/laser.csv",
              "image/overlay.png", "image/report.html"):
        assert (out / f).is_file(), f
    head = [ln for ln in (out / "image" / "laser.csv").read_text().splitlines()
            if not ln.startswith("#")][0]
    assert head == "u,v,cov_uu,cov_uv,cov_vv,snr,flagged"      # as bayescal extract
    assert "](overlay.png)" in (out / "image" / "report.md").read_text()
    index = (out / "index.md").read_text()
    for link in re.findall(r"\]\(([^)]+)\)", index):        # every link and figure resolves
        assert (out / link).is_file(), link
    r = run("demo", "--out", "out", "--n-points", 30, cwd=tmp_path)
    assert r.returncode == 2 and "--force" in r.stderr


@pytest.mark.slow
def test_demo_full_as_make_demo(tmp_path):
    """``make demo``: the paper's large room, all three methods, in a few minutes."""
    r = run("demo", "--out", "out", "--force", "--no-progress", cwd=tmp_path)
    assert r.returncode == 0, r.stdout + r.stderr
    index = (tmp_path / "out" / "index.md").read_text()
    assert "| simultaneous | ok |" in index and "| bayes | ok |" in index
    assert "| floorplan | ok |" in index and "| image | ok |" in index
    # make demo again: --force replaces the stages' folders
    r = run("demo", "--out", "out", "--force", "--no-progress", cwd=tmp_path)
    assert r.returncode == 0, r.stdout + r.stderr


# -- report helpers (in process) -----------------------------------------------------------

def test_linear_reconstruction_matches_monte_carlo(rng):
    """First-order propagation vs Monte Carlo with small perturbations.

    With n = 20000 draws the sample variance has relative sd sqrt(2 / n) = 1 %;
    the 6 % tolerance is 6 sd (false failure ~ 2e-9 per entry, 9 entries).
    The perturbations are small enough that the linearization error is far below it.
    """
    p = bc.SensorParams.paper()
    theta = p.to_identifiable()
    sd7 = np.array([1e-3, 0.05, 0.05, 0.05, 0.05, 0.5, 1e-3])
    A = rng.normal(size=(7, 7)) * 0.3 + np.eye(7)
    corr = A @ A.T
    d = np.sqrt(np.diag(corr))
    cov7 = corr / np.outer(d, d) * np.outer(sd7, sd7)
    pix = bc.project(p, [[800.0, 600.0, 100.0], [-500.0, 300.0, -50.0]])
    sig = 0.05
    mean, cov = linear_reconstruction(p, cov7, pix, sig)
    np.testing.assert_allclose(mean, bc.triangulate(p, pix), rtol=1e-12)
    n = 20000
    th = rng.multivariate_normal(theta, cov7, size=n)
    noisy = pix + sig * rng.standard_normal((n, 2, 2))
    from bayescal.sensor.laser import triangulate_theta

    pts, _ = triangulate_theta(th[:, None, :], noisy)
    for i in range(2):
        emp = np.cov(pts[:, i].T)
        np.testing.assert_allclose(np.diag(cov[i]), np.diag(emp), rtol=0.06)


def test_write_report_without_optional_parts(tmp_path):
    """A report from a result without points or truth still has the table and the image."""
    from bayescal.io.data import LaserData, Table
    from bayescal.report.report import write_report
    from bayescal.results.calibration import CalibrationResult, identifiability_report

    p = bc.SensorParams.paper()
    res = CalibrationResult(
        method="sequential", params=p, points=None, covariance=np.diag(np.full(8, 0.01)),
        covariance_identifiable=np.eye(7) * 0.01, residual_rms={}, sigma_px_estimated=None,
        n_residuals=10, n_unknowns=8, converged=False, message="stopped", nfev=1,
        identifiability=identifiability_report(np.diag([1, 0, 1, 1, 1, 1, 1, 1.0]),
                                               bc.PARAM_NAMES))
    pix = bc.project(p, [[1000.0, 0, 0]] * 3)
    table = Table(tmp_path / "d.csv", {}, np.arange(3), "csv")
    data = LaserData(pix, None, None, None, table, None)
    files, acc = write_report(tmp_path, res, {"method": "sequential"}, data=data)
    html = files["html"].read_text()
    assert "NOT CONVERGED" in html and "<tr class='flag'><td>phi</td>" in html
    assert "Warning." in html                          # the solver did not converge
    assert set(files) == {"image", "markdown", "html"} and acc is None


def test_prior_option_overrides_one_default_and_keeps_the_rest(tmp_path):
    from bayescal.cli.lasermodel import nominal_and_prior as _nominal_and_prior
    from bayescal.cli.options import prior_option
    from bayescal.likelihood.priors import default_prior

    design = bc.SensorParams.paper().replace(h=150.0)
    (tmp_path / "design.json").write_text(json.dumps({"params": design.as_dict()}))
    nominal, prior = _nominal_and_prior(tmp_path / "design.json",
                                        [prior_option("beta=uniform(0.9, 0.3)")])
    assert nominal == design
    assert prior["beta"].dist.name == "uniform"
    np.testing.assert_allclose(prior["beta"].support(), (0.9, 1.2), rtol=1e-15)
    ref = default_prior(design)
    for name in bc.PARAM_NAMES:
        if name != "beta":
            assert (prior[name].mean(), prior[name].std()) == (ref[name].mean(), ref[name].std())
    assert prior["h"].mean() == 150.0
    # no option at all: the library's defaults are used untouched (prior=None)
    assert _nominal_and_prior(None, [])[1] is None


def test_result_rows_flag_prior_dominated_parameters():
    """phi, alpha_u, alpha_v and sd_ratio > PRIOR_DOMINATED_RATIO mark a parameter; with a
    prior a near-null direction of the data alone does not (phi's here), without one it does."""
    from bayescal.likelihood.priors import default_prior
    from bayescal.report.report import parameter_rows
    from bayescal.results.calibration import CalibrationResult, identifiability_report

    p = bc.SensorParams.paper()
    prior = default_prior(p)
    psd = np.array([prior[n].std() for n in bc.PARAM_NAMES])
    sd = psd * np.array([0.9, 0.1, 0.1, 0.1, 0.01, 0.01, 0.4, 0.6])
    J = np.eye(8)
    J[:, 1] = 0.0                                       # phi: no information at all
    res = CalibrationResult(
        method="simultaneous", params=p, points=None, covariance=np.diag(sd**2),
        covariance_identifiable=np.eye(7), residual_rms={}, sigma_px_estimated=None,
        n_residuals=10, n_unknowns=8, converged=True, message="ok", nfev=1,
        identifiability=identifiability_report(J, bc.PARAM_NAMES))
    rows = {r["name"]: r for r in parameter_rows(res, prior=prior)}
    flagged = sorted(n for n, r in rows.items() if r["prior_dominated"])
    assert flagged == ["alpha_u", "alpha_v", "beta", "phi", "xi"]
    J[:, 7] = 0.0                                       # beta too: no information
    res.identifiability = identifiability_report(J, bc.PARAM_NAMES)
    rows = {r["name"]: r for r in parameter_rows(res, prior=prior)}
    assert not rows["h"]["prior_dominated"]             # ratio 0.4: the priors do not decide
    no_prior = {r["name"]: r["prior_dominated"] for r in parameter_rows(res)}
    assert sorted(n for n, f in no_prior.items() if f) == ["alpha_u", "alpha_v", "beta", "phi"]
    np.testing.assert_allclose(rows["h"]["sd_ratio"], 0.4, rtol=1e-12)
    np.testing.assert_allclose(rows["u0"]["q95"] - rows["u0"]["q05"], 2 * 1.6448536 * sd[4],
                               rtol=1e-7)


# -- every bad input, one behaviour (in process: fast) -----------------------------------

def _main(args, capsys):
    from bayescal.cli.main import main

    rc = main([str(a) for a in args])
    return rc, capsys.readouterr()


def _room_csv(path, n=12, azimuth_span=2 * np.pi, dup=None):
    p = bc.SensorParams.paper()
    az = np.linspace(0, azimuth_span, n, endpoint=False)
    pts = np.column_stack([2000 * np.cos(az), 2000 * np.sin(az), np.full(n, -300.0)])
    pix = bc.project(p, pts)
    rows = [f"{u!r},{v!r},{x!r},{y!r},{z!r}"
            for (u, v), (x, y, z) in zip(pix.tolist(), pts.tolist(), strict=True)]
    if dup is not None:
        rows.append(rows[dup])
    path.write_text("u,v,x,y,z\n" + "\n".join(rows) + "\n")
    return path


@pytest.mark.parametrize("n, span, match", [
    (1, 2 * np.pi, r"1 laser point\(s\); expected at least 5"),
    (3, 2 * np.pi, r"3 laser point\(s\); expected at least 5"),
    (12, 1e-9, r"span [0-9.e-]+ degrees of azimuth; expected at least 10"),
])
def test_degenerate_geometry_exit_2(tmp_path, capsys, monkeypatch, n, span, match):
    import re

    monkeypatch.chdir(tmp_path)
    _room_csv(tmp_path / "d.csv", n=n, azimuth_span=span)
    rc, cap = _main(["calibrate", "d.csv", "--sigma-px", "0.1", "--sigma-scene", "50",
                     "--out", "out"], capsys)
    assert rc == 2 and re.search(match, cap.err), cap.err
    assert len(cap.err.strip().splitlines()) == 1 and "d.csv" in cap.err
    assert sorted(p.name for p in tmp_path.iterdir()) == ["d.csv"]


def test_duplicate_rows_warn_with_their_lines(sim, tmp_path, capsys, monkeypatch):
    monkeypatch.chdir(tmp_path)
    lines = (sim / "laser.csv").read_text().splitlines()
    first = next(i for i, t in enumerate(lines) if t and not t.startswith("#")) + 1   # header
    lines.append(lines[first + 3])                          # copy the 4th data row to the end
    (tmp_path / "d.csv").write_text("\n".join(lines) + "\n")
    rc, cap = _main(["calibrate", "d.csv", "--out", "out"], capsys)
    assert rc == 0, cap.err
    assert f"exact duplicate lines {first + 4} and {len(lines)}" in cap.err


def test_truth_of_the_wrong_length_exit_2(sim, tmp_path, capsys, monkeypatch):
    monkeypatch.chdir(tmp_path)
    truth = json.loads((sim / "truth.json").read_text())
    truth["points"] = truth["points"][:-1]
    (tmp_path / "t.json").write_text(json.dumps(truth))
    rc, cap = _main(["calibrate", sim / "laser.csv", "--truth", "t.json", "--out", "o"], capsys)
    assert rc == 2 and f"it has {N_POINTS - 1} points but the data have {N_POINTS}" in cap.err
    assert not (tmp_path / "o").exists()


def test_read_only_output_folder_exit_2(sim, tmp_path, capsys, monkeypatch):
    monkeypatch.chdir(tmp_path)
    ro = tmp_path / "ro"
    ro.mkdir()
    ro.chmod(0o555)
    try:
        rc, cap = _main(["simulate", "--out", ro / "sim", "--n-points", 10], capsys)
    finally:
        ro.chmod(0o755)
    assert rc == 2 and "is not a writable folder" in cap.err
    assert list(ro.iterdir()) == []


@pytest.mark.parametrize("damage", ["truncate", "foreign"])
def test_damaged_posterior_file_exit_2(bayes_run, tmp_path, capsys, monkeypatch, damage):
    import shutil

    monkeypatch.chdir(tmp_path)
    run_dir = tmp_path / "run"
    shutil.copytree(bayes_run[0], run_dir)
    post = run_dir / "posterior.npz"
    if damage == "truncate":
        post.write_bytes(post.read_bytes()[: post.stat().st_size // 2])
    else:
        np.savez(post, something=np.zeros(3))
    (tmp_path / "new.csv").write_text("u,v\n450,300\n")
    rc, cap = _main(["reconstruct", "new.csv", "--run", run_dir, "--out", "rec"], capsys)
    assert rc == 2 and "posterior.npz is not a readable bayescal posterior file" in cap.err
    assert len(cap.err.strip().splitlines()) == 1 and not (tmp_path / "rec").exists()


def test_interrupt_inside_a_job_exit_130_nothing_left(sim, tmp_path, capsys, monkeypatch):
    monkeypatch.chdir(tmp_path)

    def interrupted(*args, **kwargs):
        raise KeyboardInterrupt

    monkeypatch.setattr(bc, "calibrate_simultaneous", interrupted)
    rc, cap = _main(["calibrate", sim / "laser.csv", "--out", "new/deeper/o"], capsys)
    assert rc == 130 and cap.err.strip() == "bayescal: interrupted; nothing was written"
    assert list(tmp_path.iterdir()) == []                  # no folder, no staging, no parents


def test_sigint_during_sampling_exit_130_nothing_left(sim, tmp_path):
    """A real Ctrl-C (SIGINT) while emcee runs: one line, no traceback, nothing written."""
    import signal
    import time

    root = str(pathlib.Path(bayescal.__file__).resolve().parents[1])
    env = dict(os.environ, MPLBACKEND="agg", PYTHONPATH=root)
    proc = subprocess.Popen([sys.executable, "-m", "bayescal", "calibrate", sim / "laser.csv",
                             "--method", "bayes", "--no-progress", "--out", "o"], cwd=tmp_path,
                            env=env, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    deadline = time.time() + 60
    while time.time() < deadline and not any("bayescal-tmp" in p.name
                                             for p in tmp_path.iterdir()):
        time.sleep(0.1)
    time.sleep(2.0)                                        # inside the sampler by now
    proc.send_signal(signal.SIGINT)
    out, err = proc.communicate(timeout=60)
    assert proc.returncode == 130, err
    assert err.strip().splitlines() == ["bayescal: interrupted; nothing was written"], err
    assert list(tmp_path.iterdir()) == []


def test_ctrl_c_inside_exec_of_a_string_still_exits_130(tmp_path):
    """CPython marks a KeyboardInterrupt raised inside ``exec(str)`` as unhandled even when
    caught (SciPy's distributions are built so on import): ``python -m bayescal`` must still
    leave with 130, not die by SIGINT (-2). Deterministic: the job interrupts itself there."""
    pkg = tmp_path / "fakecli"
    pkg.mkdir()
    (pkg / "__init__.py").write_text("")
    (pkg / "__main__.py").write_text(
        "import bayescal.cli.main as m\n"
        "def job(args, folders):\n"
        "    exec('import os, signal, time\\nos.kill(os.getpid(), signal.SIGINT)\\n"
        "time.sleep(5)')\n"
        "m._run = job\n"
        "m.console_main()\n")
    root = str(pathlib.Path(bayescal.__file__).resolve().parents[1])
    env = dict(os.environ, MPLBACKEND="agg", PYTHONPATH=os.pathsep.join([root, str(tmp_path)]))
    r = subprocess.run([sys.executable, "-m", "fakecli", "simulate", "--out", "o"], cwd=tmp_path,
                       capture_output=True, text=True, env=env, timeout=120)
    assert r.returncode == 130, (r.returncode, r.stderr)
    assert r.stderr.strip() == "bayescal: interrupted; nothing was written"


def test_interrupt_after_the_commit_says_the_folder_is_complete(tmp_path, capsys, monkeypatch):
    """A Ctrl-C that lands after the files moved into place must not claim nothing was written."""
    from bayescal.io.outputs import OutputFolder

    monkeypatch.chdir(tmp_path)
    commit = OutputFolder.commit

    def commit_then_interrupt(self):
        commit(self)
        raise KeyboardInterrupt

    monkeypatch.setattr(OutputFolder, "commit", commit_then_interrupt)
    rc, cap = _main(["simulate", "--out", "o", "--n-points", 10], capsys)
    assert rc == 130
    assert cap.err.strip() == "bayescal: interrupted after o was written in full"
    assert (tmp_path / "o" / MANIFEST).exists()


def test_force_never_replaces_a_file_bayescal_did_not_write(tmp_path, capsys, monkeypatch):
    monkeypatch.chdir(tmp_path)
    assert _main(["simulate", "--out", "o", "--n-points", 10], capsys)[0] == 0
    manifest = json.loads((tmp_path / "o" / MANIFEST).read_text())
    manifest["files"].remove("truth.json")                 # as if the user had put it there
    (tmp_path / "o" / MANIFEST).write_text(json.dumps(manifest))
    (tmp_path / "o" / "truth.json").write_text("mine")
    rc, cap = _main(["simulate", "--out", "o", "--n-points", 12, "--force"], capsys)
    assert rc == 2 and "truth.json, which bayescal did not write" in cap.err
    assert (tmp_path / "o" / "truth.json").read_text() == "mine"
    assert len(bayescal.io.data.load_laser_data(tmp_path / "o" / "laser.npz").pixels) == 10
    assert not [p for p in tmp_path.iterdir() if "bayescal-tmp" in p.name]


def test_version_and_help_without_markup(tmp_path, capsys):
    from bayescal.cli.main import main

    with pytest.raises(SystemExit) as exc:
        from bayescal.cli.main import build_parser

        build_parser().parse_args(["--version"])
    assert exc.value.code == 0 and capsys.readouterr().out.strip() == f"bayescal {bc.__version__}"
    for cmd in ("simulate", "calibrate", "reconstruct", "report", "study", "demo"):
        assert main([cmd, "--help"]) == 0
        text = capsys.readouterr().out
        assert "%%" not in text and "`" not in text, cmd
        if cmd == "study":
            assert "fig9" in text and "conditioning" in text


@pytest.mark.parametrize("method", ["simultaneous", "bayes"])
def test_input_that_cannot_calibrate_is_bad_input(sim, tmp_path, method):
    """All scene sds inf: the pixels alone cannot calibrate. Exit 2, one line naming the
    file and what to give, nothing written (was exit 1 for least squares, a traceback
    for bayes)."""
    lines = (sim / "laser.csv").read_text().splitlines()
    data = [ln for ln in lines if not ln.startswith("#")]
    head = data[0].split(",")
    cols = [head.index(c) for c in ("sigma_x", "sigma_y", "sigma_z")]
    rows = [ln.split(",") for ln in data[1:]]
    for r in rows:
        for c in cols:
            r[c] = "inf"
    (tmp_path / "allinf.csv").write_text("\n".join([data[0]] + [",".join(r) for r in rows]))
    r = run("calibrate", "allinf.csv", "--method", method, "--out", "o", cwd=tmp_path)
    assert r.returncode == 2, r.stderr
    assert "allinf.csv" in r.stderr and "sigma_scene is inf everywhere" in r.stderr
    assert "Traceback" not in r.stderr and len(r.stderr.strip().splitlines()) == 1
    assert not (tmp_path / "o").exists()


def test_messy_file_with_inferred_noise_is_not_called_converged(sim, tmp_path):
    """Bad rows in a file without sigma columns (the noise inferred): the fit either
    flags the rows or exits 1 naming them; never exit 0 with the noise dragged."""
    lines = (sim / "laser.csv").read_text().splitlines()
    data = [ln.split(",") for ln in lines if not ln.startswith("#")]
    head = data[0]
    keep = [i for i, h in enumerate(head) if not h.startswith("sigma")]
    rows = [[r[i] for i in keep] for r in data]
    h = rows[0]
    rows[6][h.index("u")] = str(float(rows[6][h.index("u")]) + 25.0)     # file line 7
    rows[21][h.index("x")] = str(float(rows[21][h.index("x")]) * 10.0)   # file line 22
    (tmp_path / "messy.csv").write_text("\n".join(",".join(r) for r in rows))
    r = run("calibrate", "messy.csv", "--method", "simultaneous", "--out", "o", cwd=tmp_path)
    assert r.returncode in (0, 1, 2), r.stderr
    assert "Traceback" not in r.stderr
    if r.returncode == 0:
        assert "lines 7, 22" in r.stdout or ("7" in r.stdout and "22" in r.stdout), r.stdout
    else:
        assert "line" in r.stderr, r.stderr


def test_reconstruct_frames_to_point_clouds(sim, seq_run, tmp_path):
    """Several frames: one PLY each (read back by meshio) and a summary line per frame;
    per-pixel covariance columns are used."""
    meshio = pytest.importorskip("meshio")
    lines = [ln for ln in (sim / "laser.csv").read_text().splitlines()
             if not ln.startswith("#")]
    head = lines[0].split(",")
    iu, iv = head.index("u"), head.index("v")
    rows = [ln.split(",") for ln in lines[1:]]
    for k, (a, b) in enumerate(((0, 20), (20, 45))):
        txt = ["u,v,cov_uu,cov_uv,cov_vv"] + [f"{r[iu]},{r[iv]},{0.04 * (k + 1)},0,0.04"
                                              for r in rows[a:b]]
        (tmp_path / f"f{k}.csv").write_text("\n".join(txt) + "\n")
    r = run("reconstruct", "f0.csv", "f1.csv", "--run", seq_run[0], "--out", "rec",
            cwd=tmp_path)
    assert r.returncode == 0, r.stderr
    out = tmp_path / "rec"
    m0, m1 = meshio.read(out / "f0.ply"), meshio.read(out / "f1.ply")
    assert m0.points.shape == (20, 3) and m1.points.shape == (25, 3)
    assert np.all(np.isfinite(m0.point_data["cov_xx"]))
    body = [ln for ln in (out / "frames.csv").read_text().splitlines()
            if not ln.startswith("#")]
    assert body[0].split(",")[:2] == ["frame", "points"]
    assert [float(ln.split(",")[1]) for ln in body[1:]] == [20, 25]
    bad = tmp_path / "bad.csv"
    bad.write_text("u,v,cov_uu\n400,380,0.1\n")
    r = run("reconstruct", "f0.csv", "bad.csv", "--run", seq_run[0], "--out", "rec2",
            cwd=tmp_path)
    assert r.returncode == 2 and "cov_uv" in r.stderr and not (tmp_path / "rec2").exists()


def test_reconstruct_an_image_frame(tmp_path):
    """An image as a frame: the laser extractor's unflagged pixels, with their covariances,
    reconstructed into a PLY."""
    meshio = pytest.importorskip("meshio")
    r = run("simulate", "--images", "--n-points", 60, "--range-mm", 2500, "--out", "sim",
            cwd=tmp_path)
    assert r.returncode == 0, r.stderr
    r = run("calibrate", "sim/laser.csv", "--method", "simultaneous", "--out", "run",
            cwd=tmp_path)
    assert r.returncode == 0, r.stderr
    r = run("reconstruct", "sim/image.png", "--run", "run", "--out", "rec", cwd=tmp_path)
    assert r.returncode == 0, r.stderr
    cloud = meshio.read(tmp_path / "rec" / "reconstruction.ply")
    assert len(cloud.points) > 100 and np.mean(np.isfinite(cloud.point_data["cov_zz"])) > 0.9
    (tmp_path / "broken.png").write_bytes(b"not an image")
    r = run("reconstruct", "broken.png", "--run", "run", "--out", "rec2", cwd=tmp_path)
    assert r.returncode == 2 and "broken.png" in r.stderr and not (tmp_path / "rec2").exists()


def test_truth_of_the_parameters_only_draws_the_report(sim, tmp_path, capsys, monkeypatch):
    # a truth file without points (a renderer's): its report's reconstruction figure
    # ended calibrate in a traceback
    monkeypatch.chdir(tmp_path)
    truth = json.loads((sim / "truth.json").read_text())
    truth.pop("points")
    (tmp_path / "t.json").write_text(json.dumps(truth))
    rc, cap = _main(["calibrate", sim / "laser.csv", "--truth", "t.json", "--out", "o"], capsys)
    assert rc == 0, cap.err
    assert "Traceback" not in cap.err and (tmp_path / "o" / "reconstruction.png").exists()
