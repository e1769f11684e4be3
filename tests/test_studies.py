"""Smoke tests of the paper-reproduction studies in ``studies/``.

Each study runs in its hidden ``--smoke`` mode (60 laser points, tiny sampler
targets; a few seconds) by importing its ``main(argv)``. The tests check the
documented JSON keys, that results do not depend on the executor (1 worker,
2 processes, a Dask LocalCluster) and the refusal to overwrite results.
"""

import importlib
import json
import pathlib
import sys

import numpy as np
import pytest

STUDIES = pathlib.Path(__file__).resolve().parents[1] / "studies"


def _load(name):
    """Import ``studies/NAME.py`` as module ``name`` (so that its trials pickle)."""
    if str(STUDIES) not in sys.path:
        sys.path.insert(0, str(STUDIES))
    return importlib.import_module(name)


def _run(name, out, *extra):
    rc = _load(name).main(["--smoke", "--out", str(out), *extra])
    assert rc == 0
    return json.loads((out / f"{name}.json").read_text())


@pytest.fixture(scope="module")
def fig9_serial(tmp_path_factory):
    out = tmp_path_factory.mktemp("fig9_w1")
    return out, _run("fig9", out, "--workers", "1")


def test_fig9_keys_and_files(fig9_serial):
    out, res = fig9_serial
    for key in ("approx_error_percent", "sequential_mm", "simultaneous_mm", "bayes_mm"):
        assert len(res[key]) == len(res["approx_error_percent"])
    assert res["approx_error_percent"] == [0.0, 5.0]
    assert all(np.isfinite(v) and v > 0 for v in res["simultaneous_mm"])
    assert (out / "fig9.png").stat().st_size > 10_000
    # the approximate points at 5 % are worse than at 0 % (their error grows with the level)
    assert res["approx_mm"][1] > res["approx_mm"][0]
    # the floor-plan columns run by default (least squares and posterior), one chain each
    assert res["plan_bayes"] is True
    assert all(np.isfinite(v) and v > 0 for v in res["plan_mm"] + res["plan_bayes_mm"])
    assert len(res["plan_bayes_unconverged"]) == len(res["approx_error_percent"])
    assert all(t["plan_bayes_failed"] is None for t in res["trials"])


def test_fig9_same_results_with_two_processes(fig9_serial, tmp_path):
    _, serial = fig9_serial
    parallel = _run("fig9", tmp_path, "--workers", "2")
    assert parallel["trials"] == serial["trials"]


def test_fig9_same_results_on_dask(fig9_serial, tmp_path):
    distributed = pytest.importorskip("distributed")
    _, serial = fig9_serial
    with distributed.LocalCluster(n_workers=1, processes=False, dashboard_address=None) as cl:
        res = _run("fig9", tmp_path, "--scheduler", cl.scheduler_address)
    assert res["trials"] == serial["trials"]


def test_seed_changes_results(fig9_serial, tmp_path):
    _, serial = fig9_serial
    other = _run("fig9", tmp_path, "--workers", "1", "--seed", "1")
    assert other["trials"][0]["true_params"] != serial["trials"][0]["true_params"]


@pytest.mark.parametrize("name", ["fig7", "fig8"])
def test_room_studies(name, tmp_path):
    res = _run(name, tmp_path, "--workers", "1")
    for key in ("sequential_mm", "simultaneous_mm", "bayes_mm", "simultaneous_triangulated_mm",
                "sigma_px", "sigma_3d_mm", "summary", "trials"):
        assert key in res
    assert res["range_mm"] == {"fig7": 1000.0, "fig8": 5000.0}[name]
    assert len(res["sequential_mm"]) == len(res["trials"]) == 1
    assert (tmp_path / f"{name}.png").is_file()


def test_refuses_to_overwrite(tmp_path, capsys):
    mod = _load("fig7")
    (tmp_path / "fig7.json").write_text("{}")
    assert mod.main(["--smoke", "--out", str(tmp_path), "--workers", "1"]) == 2
    assert "--force" in capsys.readouterr().err
    assert (tmp_path / "fig7.json").read_text() == "{}"


def test_bad_arguments_are_rejected(tmp_path):
    mod = _load("fig7")
    with pytest.raises(SystemExit):
        mod.main(["--smoke", "--out", str(tmp_path), "--workers", "0"])
    with pytest.raises(SystemExit):
        mod.main(["--smoke"])                                    # --out is required


def test_identifiability_study(tmp_path):
    res = _run("identifiability", tmp_path, "--workers", "1")
    assert set(res["posteriors"]) == {"default", "tight_phi"}
    # the data cannot see phi: the report has the phi/alpha null direction
    comps = res["null_directions"][0]["components"]
    assert {"phi", "alpha_u", "alpha_v"} <= set(comps)
    sd = {k: {r["name"]: r["sd"] for r in v["summary"]} for k, v in res["posteriors"].items()}
    # a prior 10x tighter on phi narrows alpha_u along the ridge
    assert sd["tight_phi"]["phi"] < sd["default"]["phi"]
    assert sd["tight_phi"]["alpha_u"] < sd["default"]["alpha_u"]
    assert (tmp_path / "identifiability.png").is_file()
    assert "near-null direction" in (tmp_path / "identifiability.txt").read_text()


def test_design_study(tmp_path):
    res = _run("design", tmp_path, "--workers", "1")
    rows = {(r["vary"], r["value"]): r for r in res["rows"]}
    small, large = rows[("range_mm", 1000.0)], rows[("range_mm", 5000.0)]
    # docs/model.md, fact 2: conditioning falls fast with range
    assert large["new_point_sd_mm"] > 5 * small["new_point_sd_mm"]
    assert (tmp_path / "design.png").is_file()


def test_predicted_new_point_sd_matches_pixel_noise_alone():
    import bayescal as bc

    design = _load("design")
    p = bc.SensorParams.paper()
    ds = bc.simulate_room(range_mm=1000, n_points=20, sigma_px=0.0, rng=0)
    sd0 = design.predicted_new_point_sd(p, np.zeros((8, 8)), ds.pixels, 1.0)
    # with exact parameters, sd = pixel noise through the triangulation Jacobian; Monte Carlo
    # over 4000 draws per point: sqrt(mean |e|^2) has relative sd ~ kurtosis-dependent, the
    # 15 % tolerance is > 5 standard errors for these near-Gaussian small-noise errors
    rng = np.random.default_rng(1)
    e = bc.triangulate(p, ds.pixels + rng.normal(0.0, 0.01, (4000, 20, 2))) - ds.points
    mc = np.sqrt(np.mean(np.sum(e**2, axis=-1), axis=0)) / 0.01
    np.testing.assert_allclose(sd0, mc, rtol=0.15)


_TINY_STUDY = '''"""tiny: a study whose trials report the process that ran them."""
import json
import os

from bayescal.cli.studyrun import run_trials, study_main


def trial(spec, rng):
    return {"k": spec["k"], "x": float(rng.random()), "pid": os.getpid()}


def run(args, out):
    res = run_trials(trial, [{"k": k} for k in range(6)], seed=args.seed, workers=args.workers,
                     scheduler=args.scheduler, progress=False)
    (out / "tiny.json").write_text(json.dumps(res))


if __name__ == "__main__":
    raise SystemExit(study_main(run, "tiny", None, ("tiny.json",)))
'''


def _free_port():
    import socket

    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


@pytest.mark.slow
def test_bayescal_study_passes_scheduler_to_a_real_dask_cluster(tmp_path):
    """``bayescal study NAME --scheduler ADDRESS`` on a ``dask scheduler`` + 2 ``dask worker``.

    About 25 s (the processes start), so in the slow set; skipped when they cannot start.
    """
    import os
    import shutil
    import subprocess
    import time

    pytest.importorskip("distributed")
    dask = shutil.which("dask") or str(pathlib.Path(sys.executable).parent / "dask")
    if not pathlib.Path(dask).exists():
        pytest.skip("no dask command")
    (tmp_path / "studies").mkdir()
    (tmp_path / "studies" / "tiny.py").write_text(_TINY_STUDY)
    root = str(pathlib.Path(__file__).resolve().parents[1])
    env = dict(os.environ, PYTHONPATH=root, BAYESCAL_STUDIES_DIR=str(tmp_path / "studies"),
               MPLBACKEND="agg")
    addr = f"tcp://127.0.0.1:{_free_port()}"
    log = open(tmp_path / "dask.log", "w")
    procs = [subprocess.Popen([dask, "scheduler", "--host", "127.0.0.1", "--port",
                               addr.rsplit(":", 1)[1], "--no-dashboard"], env=env,
                              stdout=log, stderr=log)]
    try:
        time.sleep(3)
        for _ in range(2):
            procs.append(subprocess.Popen([dask, "worker", addr, "--nthreads", "1",
                                           "--no-dashboard"], env=env, stdout=log, stderr=log,
                                          cwd=tmp_path))
        time.sleep(5)
        if any(p.poll() is not None for p in procs):
            pytest.skip("the dask scheduler or a worker could not start")
        cmd = [sys.executable, "-m", "bayescal", "study", "tiny", "--scheduler", addr,
               "--seed", "3"]
        r = subprocess.run(cmd + ["--out", "dask"], cwd=tmp_path, env=env, capture_output=True,
                           text=True, timeout=120)
        assert r.returncode == 0, r.stderr
        inline = subprocess.run(cmd[:5] + ["--workers", "1", "--seed", "3", "--out", "inline"],
                                cwd=tmp_path, env=env, capture_output=True, text=True,
                                timeout=120)
        assert inline.returncode == 0, inline.stderr
    finally:
        for p in procs[::-1]:
            p.terminate()
        for p in procs:
            try:
                p.wait(timeout=20)
            except subprocess.TimeoutExpired:
                p.kill()
        log.close()
    on_dask = json.loads((tmp_path / "dask" / "tiny.json").read_text())
    local = json.loads((tmp_path / "inline" / "tiny.json").read_text())
    assert [t["x"] for t in on_dask] == [t["x"] for t in local]      # same seeds, same numbers
    pids = {t["pid"] for t in on_dask}
    assert os.getpid() not in pids and len(pids) >= 1               # ran in the worker processes


def test_extraction_smoke(tmp_path):
    res = _run("extraction", tmp_path, "--workers", "1")
    assert [r["range_mm"] for r in res["rows"]] == [1000.0, 2500.0]
    for r in res["rows"]:
        assert 0 < r["robust_sd"] < 0.5 and 0 < r["given_sd"] < 0.5
    assert (tmp_path / "extraction.png").stat().st_size > 10_000


def test_misalignment_smoke(tmp_path):
    res = _run("misalignment", tmp_path, "--workers", "1")
    s = res["summary"]
    assert list(s) == ["aligned", "tilt 1 deg"] and res["replications"] == 1
    for m in ("aligned", "misaligned"):
        assert set(s["aligned"][f"{m}_z_rms"]) == set(s["aligned"]["misaligned_z_rms"])
        assert np.isfinite(s["tilt 1 deg"][f"{m}_heldout_mm"])
    # the aligned model has no pose to score; a 1 degree tilt moves its principal point
    assert s["aligned"]["aligned_z_rms"]["tilt_x"] is None
    z = {m: max(s["tilt 1 deg"][f"{m}_z_rms"][p] for p in ("u0", "v0"))
         for m in ("aligned", "misaligned")}
    assert z["aligned"] > 5 > z["misaligned"], z
    assert s["tilt 1 deg"]["prefers_misaligned"] == 1 and s["aligned"]["prefers_misaligned"] == 0
    assert (tmp_path / "misalignment.png").stat().st_size > 10_000
    assert "| tilt 1 deg | misaligned |" in (tmp_path / "misalignment.md").read_text()


@pytest.mark.slow
def test_realcam_on_the_shared_views(tmp_path):
    import os

    data = pathlib.Path(os.environ.get("BAYESCAL_PARA_DIR")
                        or STUDIES.parents[1] / "shared" / "data" / "para")
    if not data.is_dir():
        pytest.skip(f"real views not found at {data}")
    pytest.importorskip("cv2")
    res = _run("realcam", tmp_path, "--data", str(data))
    assert res["missed"] == [] and res["corners"] == [48] * len(res["views"])
    plain = res["models"][0]
    assert plain["noise"] == "plain" and 0.2 < plain["rms"] < 0.4
    # OpenCV's own fit on the views it keeps agrees with bayescal's on the same views
    o = res["opencv"]
    for name in ("xi", "gamma_u", "u0", "v0"):
        assert abs(o[name] - o["bayescal_same_views"][name]) < 1e-3 * abs(o[name])
    assert "| OpenCV omnidir.calibrate |" in (tmp_path / "realcam.md").read_text()
