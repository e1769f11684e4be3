"""The command line end to end (subprocess), its output-folder rules, and the report helpers.

Every bad-input case checks three things: exit code 2, a message naming the
file, line and column, and that nothing was written.
"""

import json
import os
import subprocess
import sys

import numpy as np
import pytest

import bayescal
import bayescal as bc
import bayescal.io
from bayescal.cli import MANIFEST
from bayescal.report import linear_reconstruction

N_POINTS = 60


def run(*args, cwd, env=None, timeout=600):
    """Run ``python -m bayescal ARGS`` in ``cwd``; returns the CompletedProcess."""
    full_env = dict(os.environ, MPLBACKEND="agg", **(env or {}))
    return subprocess.run([sys.executable, "-m", "bayescal", *map(str, args)], cwd=cwd,
                          capture_output=True, text=True, env=full_env, timeout=timeout)


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
    r = run("calibrate", "x.csv", "--method", "magic", cwd=tmp_path)
    assert r.returncode == 2 and "invalid choice: 'magic'" in r.stderr
    assert list(tmp_path.iterdir()) == []


def test_console_script_entry_point_is_main():
    from importlib.metadata import entry_points

    eps = [e for e in entry_points(group="console_scripts") if e.name == "bayescal"]
    assert [e.value for e in eps] == ["bayescal.cli:main"]


# -- simulate -------------------------------------------------------------------------

def test_simulate_writes_inputs_that_match_the_library(sim):
    truth = json.loads((sim / "truth.json").read_text())
    ds = bc.simulate_room(range_mm=5000, n_points=N_POINTS, sigma_px=0.1, approx_error=0.05,
                          rng=4)
    data = bayescal.io.load_laser_data(sim / "laser.csv")
    np.testing.assert_array_equal(data.pixels, ds.pixels)
    np.testing.assert_array_equal(data.approx_points, ds.approx_points)
    np.testing.assert_array_equal(np.asarray(truth["points"]), ds.points)
    assert truth["params"] == ds.params.as_dict()
    npz = bayescal.io.load_laser_data(sim / "laser.npz")
    np.testing.assert_array_equal(npz.sigma_scene, data.sigma_scene)
    manifest = json.loads((sim / MANIFEST).read_text())
    assert sorted(manifest["files"]) == sorted(
        ["laser.csv", "laser.npz", "calibration.npz", "grid.csv", "calib_laser.csv",
         "truth.json"])


def test_simulate_bad_option_writes_nothing(tmp_path):
    r = run("simulate", "--out", "s", "--range-mm", "-5", cwd=tmp_path)
    assert r.returncode == 2 and "range_mm must be a finite positive number" in r.stderr
    assert not (tmp_path / "s").exists()


# -- output folders ------------------------------------------------------------------

def test_output_folder_is_never_overwritten_without_force(sim, tmp_path):
    out = tmp_path / "out"
    out.mkdir()
    (out / "mine.txt").write_text("user data")
    r = run("simulate", "--out", out, "--n-points", 10, cwd=tmp_path)
    assert r.returncode == 2 and "exists and is not empty; pass --force" in r.stderr
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
    assert len(bayescal.io.load_laser_data(tmp_path / "o" / "laser.npz").pixels) == 12


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
            "--sigma-scene", "x", "--out", "out", cwd=tmp_path)
    # the pixel is now inside; the next check (the --sigma-scene value) fails instead
    assert r.returncode == 2 and "--sigma-scene: could not read 'x'" in r.stderr
    r = run("calibrate", "data.csv", "--image-size", "800by600", "--out", "o", cwd=tmp_path)
    assert r.returncode == 2 and "--image-size: image size must look like 800x600" in r.stderr
    assert sorted(p.name for p in tmp_path.iterdir()) == ["data.csv"]


@pytest.mark.parametrize("opts, match", [
    (["--prior", "h=norm200"], r"expected NAME=DIST\(ARGS\)"),
    (["--prior", "height=norm(200, 20)"], r"unknown parameter 'height'"),
    (["--prior", "h=gaussian(200, 20)"], r"'gaussian' is not a scipy.stats continuous"),
    (["--sigma-px", "-1"], r"--sigma-px must be a finite positive number"),
    (["--sigma-scene", "1,2"], r"--sigma-scene must be 'infer'"),
    (["--sigma-scene", "inf,inf,inf"], r"gives no information on any axis"),
    (["--method", "sequential"], r"needs --calibration FILE"),
    (["--nominal", "missing.json"], r"missing.json: no such file"),
])
def test_bad_options_exit_2(sim, tmp_path, opts, match):
    r = run("calibrate", sim / "laser.csv", *opts, "--out", "out", cwd=tmp_path)
    assert r.returncode == 2
    import re

    assert re.search(match, r.stderr), r.stderr
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
    s = json.loads((folder / "summary.json").read_text())
    assert s["method"] == "sequential" and s["converged"] is True
    assert [row["name"] for row in s["rows"]] == list(bc.PARAM_NAMES)
    assert np.shape(s["covariance"]) == (8, 8)
    # phi is held fixed by the sequential method: flagged, with sd 0
    assert s["rows"][1]["prior_dominated"] and s["rows"][1]["sd"] == 0
    md = _check_report(folder)
    assert "Accuracy against the simulation truth" in md
    assert "mean 3D error against the truth" in r.stdout
    pts = bayescal.io.read_table(folder / "points.csv", required=("x", "y", "z", "sd_x"))
    assert len(pts) == N_POINTS


def test_reconstruct_matches_triangulation(seq_run, sim, tmp_path):
    folder, _ = seq_run
    truth = json.loads((sim / "truth.json").read_text())
    pix = np.asarray(truth["pixels_true"])[:7]
    (tmp_path / "new.csv").write_text("u,v\n" + "".join(f"{a!r},{b!r}\n" for a, b in pix.tolist()))
    r = run("reconstruct", "new.csv", "--run", folder, "--out", "rec", cwd=tmp_path)
    assert r.returncode == 0, r.stderr
    t = bayescal.io.read_table(tmp_path / "rec" / "reconstruction.csv",
                               required=("x", "y", "z", "sd_x", "sd_y", "sd_z"))
    s = json.loads((folder / "summary.json").read_text())
    params = bc.SensorParams(**s["params"])
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
    assert r.returncode == 2 and "is not a calibration output folder" in r.stderr
    assert not (tmp_path / "rec").exists()


def test_report_rebuilds_from_a_run(seq_run, sim, tmp_path):
    folder, _ = seq_run
    r = run("report", folder, "--out", "rep", cwd=tmp_path)
    assert r.returncode == 0, r.stderr
    md = _check_report(tmp_path / "rep")
    assert "truth" in md        # the run recorded its --truth file
    r = run("report", folder, "--out", "rep", cwd=tmp_path)
    assert r.returncode == 2 and "not empty" in r.stderr


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
    s = json.loads((folder / "summary.json").read_text())
    assert s["method"] == "simultaneous" and s["converged"] is True
    rows = {row["name"]: row for row in s["rows"]}
    # DESIGN fact 1: phi, alpha_u, alpha_v are set by the prior, never by the data
    assert all(rows[n]["prior_dominated"] for n in ("phi", "alpha_u", "alpha_v"))
    assert not rows["u0"]["prior_dominated"]
    md = _check_report(folder)
    assert "residuals.png" in md and "reconstruction.png" in md
    # points.csv holds the jointly fitted points: they reproject onto the pixels (the
    # approximate points would miss them by several px at 5 % error)
    t = bayescal.io.read_table(folder / "points.csv", required=("x", "y", "z"))
    pred = bc.project(bc.SensorParams(**s["params"]),
                      np.column_stack([t.columns[c] for c in "xyz"]))
    pix = bayescal.io.load_laser_data(sim / "laser.csv").pixels
    assert np.sqrt(np.mean((pred - pix) ** 2)) < 3 * 0.1     # residual RMS below 3 sigma_px
    d = bayescal.io.load_laser_data(sim / "laser.csv")
    approx_pred = bc.project(bc.SensorParams(**s["params"]), d.approx_points)
    assert np.sqrt(np.mean((approx_pred - pix) ** 2)) > 3 * 0.1


def test_calibrate_simultaneous_split_files_agree(simul_run, sim, tmp_path):
    d = bayescal.io.load_laser_data(sim / "laser.csv")
    (tmp_path / "pix.csv").write_text("u,v\n" + "".join(f"{a!r},{b!r}\n" for a, b in
                                                         d.pixels.tolist()))
    (tmp_path / "pts.csv").write_text("x,y,z,sigma_x,sigma_y\n" + "".join(
        f"{x!r},{y!r},{z!r},{sx!r},{sy!r}\n" for (x, y, z), (sx, sy, _) in
        zip(d.approx_points.tolist(), d.sigma_scene.tolist(), strict=True)))
    r = run("calibrate", "pix.csv", "--points", "pts.csv", "--sigma-px", "0.1", "--out", "a",
            cwd=tmp_path)
    assert r.returncode == 0, r.stderr
    a = json.loads((tmp_path / "a" / "summary.json").read_text())["params"]
    b = json.loads((simul_run[0] / "summary.json").read_text())["params"]
    np.testing.assert_allclose(list(a.values()), list(b.values()), rtol=1e-10)


@pytest.fixture(scope="module")
def bayes_run(sim):
    root = sim.parent
    r = run("calibrate", sim / "laser.csv", "--method", "bayes", "--max-steps", 40,
            "--no-progress", "--truth", sim / "truth.json", "--out", "bayes", cwd=root)
    return root / "bayes", r


def test_bayes_unconverged_is_exit_1_with_outputs(bayes_run):
    folder, r = bayes_run
    # 40 steps cannot hold 50 autocorrelation times: tau >= 1 and the burn-in takes >= 1/4
    assert r.returncode == 1, r.stderr
    assert "did not converge" in r.stderr and "--allow-unconverged" in r.stderr
    s = json.loads((folder / "summary.json").read_text())
    assert s["method"] == "bayes" and s["converged"] is False
    assert (folder / "posterior.npz").is_file() and (folder / "corner.png").is_file()
    _check_report(folder)


def test_bayes_reconstruct_and_report(bayes_run, sim, tmp_path):
    folder, _ = bayes_run
    d = bayescal.io.load_laser_data(sim / "laser.csv")
    (tmp_path / "new.csv").write_text("u,v\n" + "".join(f"{a!r},{b!r}\n" for a, b in
                                                         d.pixels[:5].tolist()))
    r = run("reconstruct", "new.csv", "--run", folder, "--out", "rec", cwd=tmp_path)
    assert r.returncode == 0, r.stderr
    r = run("report", folder, "--out", "rep", cwd=tmp_path)
    assert r.returncode == 0, r.stderr
    assert (tmp_path / "rep" / "corner.png").is_file()


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


def test_study_runs_the_script_with_out_and_quick(tmp_path):
    (tmp_path / "studies").mkdir()
    (tmp_path / "studies" / "echo.py").write_text(
        "import pathlib, sys\n"
        "args = sys.argv[1:]\n"
        "out = pathlib.Path(args[args.index('--out') + 1])\n"
        "(out / 'args.txt').write_text(' '.join(args))\n"
        "sys.exit(3 if '--fail' in out.name else 0)\n")
    env = {"BAYESCAL_STUDIES_DIR": str(tmp_path / "studies")}
    r = run("study", "echo", "--out", "o", "--quick", cwd=tmp_path, env=env)
    assert r.returncode == 0, r.stderr
    assert (tmp_path / "o" / "args.txt").read_text() == "--out o --quick"
    r = run("study", "echo", "--out", "x--fail", cwd=tmp_path, env=env)
    assert r.returncode == 1 and "study echo exited with code 3" in r.stderr


def test_default_studies_dir_is_beside_the_package():
    from pathlib import Path

    from bayescal.cli import studies_dir

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
              "simultaneous/report.html", "bayes/report.html", "bayes/posterior.npz"):
        assert (out / f).is_file(), f
    r = run("demo", "--out", "out", "--n-points", 30, cwd=tmp_path)
    assert r.returncode == 2 and "--force" in r.stderr


@pytest.mark.slow
def test_demo_full_as_make_demo(tmp_path):
    """``make demo``: the paper's large room, all three methods, in a few minutes."""
    r = run("demo", "--out", "out", "--force", "--no-progress", cwd=tmp_path, timeout=1200)
    assert r.returncode == 0, r.stdout + r.stderr
    index = (tmp_path / "out" / "index.md").read_text()
    assert "| simultaneous | ok |" in index and "| bayes | ok |" in index


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
    from bayescal.laser import triangulate_theta

    pts, _ = triangulate_theta(th[:, None, :], noisy)
    for i in range(2):
        emp = np.cov(pts[:, i].T)
        np.testing.assert_allclose(np.diag(cov[i]), np.diag(emp), rtol=0.06)


def test_write_report_without_optional_parts(tmp_path):
    """A report from a bare summary (no points, no posterior) still has the table."""
    from bayescal.report import write_report

    p = bc.SensorParams.paper()
    rows = [{"name": n, "mean": v, "sd": 0.1, "q05": v - 0.2, "q95": v + 0.2,
             "prior_dominated": n == "phi"} for n, v in p.as_dict().items()]
    summary = {"method": "simultaneous", "converged": False, "params": p.as_dict(),
               "rows": rows}
    files = write_report(tmp_path, summary, pixels=bc.project(p, [[1000.0, 0, 0]] * 3))
    html = files["html"].read_text()
    assert "NOT CONVERGED" in html and "<tr class='flag'><td>phi</td>" in html
    assert set(files) == {"image", "markdown", "html"}


def test_prior_option_overrides_one_default_and_keeps_the_rest(tmp_path):
    from bayescal.cli import _priors, build_parser
    from bayescal.priors import default_prior

    design = bc.SensorParams.paper().replace(h=150.0)
    (tmp_path / "design.json").write_text(json.dumps({"params": design.as_dict()}))
    args = build_parser().parse_args(["calibrate", "d.csv", "--nominal",
                                      str(tmp_path / "design.json"),
                                      "--prior", "beta=uniform(0.9, 0.3)"])
    nominal, prior = _priors(args)
    assert nominal == design
    assert prior["beta"].dist.name == "uniform"
    np.testing.assert_allclose(prior["beta"].support(), (0.9, 1.2), rtol=1e-15)
    ref = default_prior(design)
    for name in bc.PARAM_NAMES:
        if name != "beta":
            assert (prior[name].mean(), prior[name].std()) == (ref[name].mean(), ref[name].std())
    assert prior["h"].mean() == 150.0
    # no option at all: the library's defaults are used untouched (prior=None)
    assert _priors(build_parser().parse_args(["calibrate", "d.csv"]))[1] is None


def test_result_summary_flags_prior_dominated_parameters():
    """sd_ratio > PRIOR_DOMINATED_RATIO, or a near-null direction, marks a parameter."""
    from bayescal.priors import default_prior
    from bayescal.report import result_summary
    from bayescal.results import CalibrationResult, identifiability_report

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
    rows = {r["name"]: r for r in result_summary(res, prior=prior)["rows"]}
    flagged = sorted(n for n, r in rows.items() if r["prior_dominated"])
    assert flagged == ["beta", "phi", "xi"]
    np.testing.assert_allclose(rows["h"]["sd_ratio"], 0.4, rtol=1e-12)
    np.testing.assert_allclose(rows["u0"]["q95"] - rows["u0"]["q05"], 2 * 1.6448536 * sd[4],
                               rtol=1e-7)
