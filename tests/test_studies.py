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
    # DESIGN fact 2: conditioning falls fast with range
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
