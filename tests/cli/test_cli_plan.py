"""The command line with a floor plan (``--walls``) and with outliers (in process: fast).

Bad-input cases check exit code 2, one line naming the file and line, and that
nothing was written.
"""

import json
import re

import numpy as np
import pytest

import bayescal as bc
from bayescal import DuplicateRowsWarning, NoiseCollapseError
from bayescal.cli.main import main
from bayescal.io.planfile import load_walls

N_POINTS = 60


def _main(args, capsys):
    rc = main([str(a) for a in args])
    return rc, capsys.readouterr()


@pytest.fixture(scope="module")
def sim(tmp_path_factory):
    root = tmp_path_factory.mktemp("plan")
    assert main(["simulate", "--out", str(root / "sim"), "--n-points", str(N_POINTS),
                 "--seed", "4"]) == 0
    return root / "sim"


@pytest.fixture(scope="module")
def plan_run(sim):
    out = sim.parent / "planrun"
    rc = main(["calibrate", str(sim / "laser.csv"), "--walls", str(sim / "walls.csv"),
               "--truth", str(sim / "truth.json"), "--out", str(out)])
    assert rc == 0
    return out


def test_calibrate_walls_end_to_end(plan_run, sim):
    info = json.loads((plan_run / "run.json").read_text())
    plan, _ = load_walls(sim / "walls.csv")
    np.testing.assert_allclose(info["plan"]["segments"], plan.segments)
    np.testing.assert_allclose(info["plan"]["distance_sd"], plan.distance_sd)
    assert info["inputs"]["walls"].endswith("walls.csv")
    res = bc.load_result(plan_run / "result.json")
    walls, cov = res.extras["walls"], res.extras["wall_covariance"]
    truth = bc.FloorPlan(np.asarray(json.loads((sim / "truth.json").read_text())["walls"]),
                         distance_sd=1.0, angle_sd=1.0)
    z = (walls - np.column_stack([truth.distances, truth.angles])).ravel() / np.sqrt(np.diag(cov))
    # 14 wall coordinates within 4 sd of the truth: a correct Laplace covariance fails this
    # about once in 900 datasets (14 x 6.3e-5)
    assert np.all(np.abs(z) < 4), z
    for name in ("plan.png", "predictive.png", "report.html", "points.csv"):
        assert (plan_run / name).is_file(), name
    md = (plan_run / "report.md").read_text()
    assert "Floor plan" in md and "Posterior predictive check" in md


def test_report_and_reconstruct_on_a_plan_run(plan_run, sim, capsys):
    out = plan_run.parent
    rc, cap = _main(["report", plan_run, "--out", out / "rep"], capsys)
    assert rc == 0, cap.err
    assert (out / "rep" / "plan.png").is_file()
    rc, cap = _main(["reconstruct", sim / "laser.csv", "--run", plan_run, "--out",
                     out / "rec"], capsys)
    assert rc == 0, cap.err
    rec = np.loadtxt(out / "rec" / "reconstruction.csv", delimiter=",", skiprows=1)
    pts = np.loadtxt(plan_run / "points.csv", delimiter=",", skiprows=1)
    # the same pixels through the same calibration: the same points (the run's are on the
    # estimated walls, the reconstruction's on the cone along each pixel's ray)
    err = np.linalg.norm(rec[:, 2:5] - pts[:, :3], axis=1)
    assert np.median(err) < np.median(np.linalg.norm(pts[:, 3:6], axis=1)) * 3


BAD_WALLS = [
    ("x0,y0,x1,y1\n1000,0,0,1000\n0,1000,-1000,0\n-1000,0,0,-1000\n0,-1000,500,0\n",
     r"closed polygon; wall 3 \(line 5\) ends at"),
    ("x0,y0,x1,y1\n3000,1000,2000,2000\n2000,2000,1000,1000\n1000,1000,2000,0\n"
     "2000,0,3000,1000\n", r"enclose the sensor axis .* wall \d \(line \d\)"),
    ("x0,y0,x1,y1,angle_sd\n1000,0,0,1000,0.1\n0,1000,-1000,0,abc\n-1000,0,0,-1000,0.1\n"
     "0,-1000,1000,0,0.1\n", r"line 3, column 'angle_sd': could not read 'abc'"),
    ("x0,y0,x1,y1,distance_sd\n1000,0,0,1000,10\n0,1000,-1000,0,10\n-1000,0,0,-1000,-5\n"
     "0,-1000,1000,0,10\n", r"line 4, column 'distance_sd': -5 is not a valid standard"),
    ("x0,y0,x1,y1\n1000,0,0,1000\n0,1000,-1000,nan\n-1000,0,0,-1000\n0,-1000,1000,0\n",
     r"line 3, column 'y1': NaN is not allowed"),
    ("x0,y0,x1\n1000,0,0\n", r"missing column\(s\) 'y1'"),
    ("x0,y0,x1,y1\n1000,0,0,1000\n0,1000,-1000,0\n", r"2 wall\(s\); expected at least 3"),
]


@pytest.mark.parametrize("text, match", BAD_WALLS)
def test_bad_walls_file_exit_2_nothing_written(sim, tmp_path, capsys, monkeypatch, text, match):
    monkeypatch.chdir(tmp_path)
    (tmp_path / "w.csv").write_text(text)
    rc, cap = _main(["calibrate", sim / "laser.csv", "--walls", "w.csv", "--out", "o"], capsys)
    assert rc == 2 and re.search(match, cap.err), cap.err
    assert len(cap.err.strip().splitlines()) == 1 and "w.csv" in cap.err
    assert sorted(p.name for p in tmp_path.iterdir()) == ["w.csv"]


@pytest.mark.parametrize("extra, match", [
    (["--sigma-scene", "5%"], "not used with --sigma-scene"),
    (["--method", "sequential", "--calibration", "CAL"], "not used with --method sequential"),
    (["--distance-sd", "0"], "--distance-sd: '0' is not a finite positive number"),
    (["--angle-sd", "x"], "--angle-sd: could not read 'x'"),
])
def test_walls_option_clashes_exit_2(sim, tmp_path, capsys, monkeypatch, extra, match):
    monkeypatch.chdir(tmp_path)
    extra = [str(sim / "calibration.npz") if e == "CAL" else e for e in extra]
    rc, cap = _main(["calibrate", sim / "laser.csv", "--walls", sim / "walls.csv", *extra,
                     "--out", "o"], capsys)
    assert rc == 2 and match in cap.err, cap.err
    assert not (tmp_path / "o").exists()


def test_distance_sd_option_applies_without_sd_columns(sim, tmp_path):
    lines = (sim / "walls.csv").read_text().splitlines()
    rows = [ln.rsplit(",", 2)[0] for ln in lines if not ln.startswith("#")]
    (tmp_path / "w.csv").write_text("\n".join(rows) + "\n")
    plan, _ = load_walls(tmp_path / "w.csv", distance_sd=("percent", 3.0), angle_sd=0.02)
    np.testing.assert_allclose(plan.distance_sd, 0.03 * plan.distances)
    np.testing.assert_allclose(plan.angle_sd, 0.02)
    plan, _ = load_walls(tmp_path / "w.csv", distance_sd=25.0)
    np.testing.assert_allclose(plan.distance_sd, 25.0)


def test_bayes_with_walls(sim, tmp_path, capsys, monkeypatch):
    ds = bc.simulate_room(range_mm=5000, n_points=N_POINTS, sigma_px=0.1, approx_error=0.05,
                          rng=4)
    monkeypatch.chdir(tmp_path)
    rc, cap = _main(["calibrate", sim / "laser.csv", "--walls", sim / "walls.csv", "--method",
                     "bayes", "--max-steps", "150", "--allow-unconverged", "--no-progress",
                     "--truth", sim / "truth.json", "--out", "b"], capsys)
    assert rc == 0, cap.err
    post = bc.load_posterior(tmp_path / "b" / "posterior.npz")
    assert post.wall_samples.shape[1:] == (ds.floor_plan.n_walls, 2)
    for name in ("plan.png", "predictive.png", "points.csv"):
        assert (tmp_path / "b" / name).is_file(), name
    rc, cap = _main(["report", tmp_path / "b", "--out", "r"], capsys)
    assert rc == 0, cap.err


# -- outliers ------------------------------------------------------------------------------

def _data_lines(path):
    lines = path.read_text().splitlines()
    first = next(i for i, t in enumerate(lines) if t and not t.startswith("#")) + 1
    return lines, first


def test_gross_errors_are_flagged_by_file_line(sim, tmp_path, capsys, monkeypatch):
    monkeypatch.chdir(tmp_path)
    lines, first = _data_lines(sim / "laser.csv")
    bad = [first + 4, first + 31]                         # 0-based indices in `lines`
    for i in bad:
        cells = lines[i].split(",")
        cells[2] = repr(float(cells[2]) + 5000.0)        # x off by 5 m
        lines[i] = ",".join(cells)
    (tmp_path / "d.csv").write_text("\n".join(lines) + "\n")
    rc, cap = _main(["calibrate", "d.csv", "--out", "o"], capsys)
    assert rc == 0, cap.err
    want = ", ".join(str(i + 1) for i in bad)            # file line numbers, header included
    assert f"d.csv lines {want}" in cap.out, cap.out
    assert "outliers (probability > 0.5)" not in cap.out     # no 0-based rows anywhere
    assert f"d.csv lines {want}" in (tmp_path / "o" / "report.md").read_text()
    header = (tmp_path / "o" / "points.csv").read_text().splitlines()[0].split(",")
    prob = np.loadtxt(tmp_path / "o" / "points.csv", delimiter=",", skiprows=1)[
        :, header.index("outlier_prob")]
    assert np.flatnonzero(prob > 0.5).tolist() == [i - first for i in bad]


def test_no_outliers_switch(sim, tmp_path, capsys, monkeypatch):
    monkeypatch.chdir(tmp_path)
    rc, cap = _main(["calibrate", sim / "laser.csv", "--no-outliers", "--out", "o"], capsys)
    assert rc == 0, cap.err
    assert json.loads((tmp_path / "o" / "run.json").read_text())["outliers"] is False
    header = (tmp_path / "o" / "points.csv").read_text().splitlines()[0]
    assert "outlier_prob" not in header


def test_noise_collapse_exit_2_with_file_lines(sim, tmp_path, capsys, monkeypatch):
    monkeypatch.chdir(tmp_path)
    _, first = _data_lines(sim / "laser.csv")

    def collapse(*args, **kwargs):
        raise NoiseCollapseError("the inferred pixel noise sigma_px ended at 1e-08, at its "
                                 "lower bound (0.001-10): ... Rows driving it most (0-based): "
                                 "0, 7. Check those rows, or give sigma_px explicitly",
                                 name="sigma_px", value=1e-8, rows=[0, 7])

    monkeypatch.setattr(bc, "calibrate_simultaneous", collapse)
    rc, cap = _main(["calibrate", sim / "laser.csv", "--out", "o"], capsys)
    assert rc == 2
    assert len(cap.err.strip().splitlines()) == 1
    assert f"laser.csv lines {first + 1}, {first + 8}. Check those lines" in cap.err
    assert not (tmp_path / "o").exists()


def test_library_duplicate_warning_names_file_lines(sim, tmp_path, capsys, monkeypatch):
    import warnings

    monkeypatch.chdir(tmp_path)
    _, first = _data_lines(sim / "laser.csv")
    real = bc.calibrate_simultaneous

    def dup(*args, **kwargs):
        w = DuplicateRowsWarning("exact duplicate input rows (0-based): rows 2, 9; ...")
        warnings.warn(w, stacklevel=1)
        return real(*args, **kwargs)

    monkeypatch.setattr(bc, "calibrate_simultaneous", dup)
    rc, cap = _main(["calibrate", sim / "laser.csv", "--out", "o"], capsys)
    assert rc == 0, cap.err
    assert f"laser.csv: exact duplicate lines {first + 3}, {first + 10}" in cap.err
    assert "(0-based)" not in cap.err


def test_plan_residuals_are_standard_normal_across_the_track():
    """One residual per point, across the image track its azimuth moves it along.

    N = 200 points: the RMS of N(0, 1) residuals has sd ~ 1/sqrt(2N) = 0.05, so the band
    0.85-1.15 is 3 sd each side (false failure ~3e-3 for a fresh seed; the seed is fixed).
    """
    from bayescal.checks.residuals import least_squares_residuals

    ds = bc.simulate_room(range_mm=1000, n_points=200, sigma_px=0.5, approx_error=0.05,
                          rng=11)
    res = bc.calibrate_simultaneous(ds.pixels, ds.floor_plan, sigma_px=0.5)
    raw, z = least_squares_residuals(res, ds.pixels, 0.5)
    assert np.all(np.isnan(z[:, 1]))
    rms = float(np.sqrt(np.mean(z[:, 0] ** 2)))
    assert 0.85 < rms < 1.15, rms


def _exact_model_room(seed, sigma_scene=30.0):
    ds = bc.simulate_room(range_mm=1000, n_points=300, sigma_px=0.5, approx_error=0.0,
                          approx_model="gaussian", rng=seed)
    rng = np.random.default_rng(100 + seed)
    pix = ds.pixels_true + rng.normal(0, 0.5, ds.pixels.shape)
    apx = ds.points + rng.normal(0, sigma_scene, ds.points.shape)
    return ds, pix, apx


def test_least_squares_check_residuals_are_the_fit_residuals():
    """The check's per-point components carry exactly the fit's whitened residual norm."""
    from bayescal.checks.residuals import least_squares_scene_residuals

    ds, pix, apx = _exact_model_room(0)
    res = bc.calibrate_simultaneous(pix, apx, sigma_px=0.5, sigma_scene=30.0, outliers=False)
    z = least_squares_scene_residuals(res, pix, apx, 0.5, 30.0)
    r2 = (np.sum(((pix - bc.project(res.params, res.points)) / 0.5) ** 2, axis=1)
          + np.sum(((apx - res.points) / 30.0) ** 2, axis=1))
    np.testing.assert_allclose(np.sum(z**2, axis=1), r2, rtol=1e-8)
    inf_z = least_squares_scene_residuals(res, pix, apx, 0.5, np.array([30.0, 30.0, np.inf]))
    assert np.all(np.isnan(inf_z[:, 2])) and np.all(np.isfinite(inf_z[:, :2]))


def test_least_squares_check_fits_the_model_and_flags_wall_errors():
    """Exact-model data pass; scene errors shared per wall are flagged.

    The pass is one fixed seed (by design each of the three statistics fails 1 % of
    fresh datasets); the wall data's neighbour correlation is ~0.9 against ~0.
    """
    from bayescal.checks.model import predictive_check

    ds, pix, apx = _exact_model_room(1)
    res = bc.calibrate_simultaneous(pix, apx, sigma_px=0.5, sigma_scene=30.0)
    res.extras["sigma_scene"] = np.full(apx.shape, 30.0)
    check = predictive_check(res, {"sigma_px": 0.5}, pix, approx_points=apx)
    assert check["fits"], check["message"]
    ws = bc.simulate_room(range_mm=1000, n_points=300, sigma_px=0.5, approx_error=0.05,
                          approx_model="wall", rng=2)
    res = bc.calibrate_simultaneous(ws.pixels, ws.approx_points, sigma_px=0.5,
                                    sigma_scene=ws.sigma_scene)
    res.extras["sigma_scene"] = ws.sigma_scene
    check = predictive_check(res, {"sigma_px": 0.5}, ws.pixels, approx_points=ws.approx_points)
    assert not check["fits"] and check["p_values"]["neighbour_corr"] < 0.01, check["message"]
    assert "neighbouring points' scene errors" in check["message"]
