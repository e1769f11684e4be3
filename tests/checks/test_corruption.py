"""The corruption harness: seeded corruptions of laser data and floor plans, each judged by
the robustness invariant (bayescal.validation.corruption, docs/robustness.md): the fit
either handles it (good points' error <= 1.25x the clean fit's, >= 90 % of the corrupted
rows flagged, <= 1 % of the good ones) or refuses with a bayescal error naming rows; never
a converged result that missed it, never a numpy/scipy exception.

The default run covers every kind once (2500 mm room, noise inferred: the command line's
default, and the case that used to fail); ``-m slow`` runs the whole grid and prints the
table of docs/robustness.md (``pytest -s``)."""

import dataclasses
import time
import warnings

import numpy as np
import pytest

import bayescal as bc
from bayescal.mcmc.steps import BUDGET_FACTOR
from bayescal.validation.corruption import (
    KINDS,
    MIXED_KINDS,
    PIXEL_KINDS,
    PLAN_KINDS,
    PLAN_MIXED_KINDS,
    corrupt,
    run_case,
)

#: the kinds the default run covers with the noise inferred (those of the first harness);
#: the rest run once with the noise given, which is cheaper, and all in the slow grid
FIRST_KINDS = ("gross_pixel", "streak", "random_gross", "metres", "sign_flip", "times_ten",
               "xy_swap", "rows_swapped", "duplicated_block")

#: the cases the invariant still fails (docs/robustness.md says why); a new failure, or one
#: of these passing, fails the grid test so that this list and the docs are kept true
KNOWN_FAILURES = {(2500.0, "plan", "given", "streak")}


def _room(range_mm, model="gaussian"):
    ds = bc.simulate_room(range_mm=range_mm, n_points=300, n_walls=6, sigma_px=0.2,
                          approx_error=0.02, approx_model=model, rng=1)
    if model == "wall":       # the plan as measured: wall errors of the same size
        plan = bc.FloorPlan(ds.floor_plan.walls, distance_sd=0.02 * ds.floor_plan.distances,
                            angle_sd=0.01)
        ds = dataclasses.replace(ds, floor_plan=plan)
    return ds


@pytest.fixture(scope="module")
def room():
    return _room(2500.0)


@pytest.fixture(scope="module")
def plan_room():
    return _room(2500.0, "wall")


def test_corruptions_are_seeded_and_say_where_they_are(room):
    a, b = corrupt(room, "streak", rng=3), corrupt(room, "streak", rng=3)
    np.testing.assert_array_equal(a.pixels, b.pixels)
    moved = np.flatnonzero(np.any(a.pixels != room.pixels, axis=1))
    np.testing.assert_array_equal(moved, a.rows)
    assert len(a.rows) == 15
    with pytest.raises(ValueError, match="kind must be one of"):
        corrupt(room, "typo")


@pytest.mark.parametrize("kind", FIRST_KINDS + ("mixed",))
def test_least_squares_with_inferred_noise(room, kind):
    out = run_case(room, kind, method="lsq", noise="inferred")
    assert out["verdict"] in ("handled", "refused"), out


@pytest.mark.parametrize("kind", [k for k in KINDS if k not in FIRST_KINDS])
def test_least_squares_with_given_noise_handles_the_new_kinds(room, kind):
    """Swaps (also 3 m apart), a block mis-paired, cm and z sign slips, a ghost ring and
    the mixes: 5 % of the rows or fewer, so a refusal does not count."""
    out = run_case(room, kind, method="lsq", noise="given")
    assert out["verdict"] == "handled", out


def test_a_5_percent_mix_is_5_percent_of_the_rows_on_distinct_rows(room):
    for seed in range(5):
        c = corrupt(room, "mixed_5pct", rng=seed)
        assert len(c.rows) == int(0.05 * room.n_points), seed
        assert len(np.unique(c.rows)) == len(c.rows)
    assert set(MIXED_KINDS) <= set(KINDS) and set(PIXEL_KINDS) <= set(KINDS)


@pytest.mark.parametrize("kind", ["streak", "random_gross"] + list(PLAN_MIXED_KINDS + PLAN_KINDS))
def test_floor_plan_with_inferred_noise(plan_room, kind):
    out = run_case(plan_room, kind, method="plan", noise="inferred")
    assert out["verdict"] in ("handled", "refused"), out


def test_posterior_with_inferred_noise_and_a_streak(room):
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", bc.NotConvergedWarning)
        out = run_case(room, "streak", method="posterior", noise="inferred", progress=False,
                       min_ess=300)
    assert out["verdict"] in ("handled", "refused"), out


#: the row corruptions of a floor-plan file (pixels only)
PLAN_ROW_KINDS = PIXEL_KINDS + PLAN_MIXED_KINDS

#: the posterior's share of the grid (2500 mm room; each case costs a posterior run)
POSTERIOR_KINDS = ("rows_swapped", "far_swap", "block_mispaired", "centimetres",
                   "z_sign_flip", "ghost_ring", "mixed", "mixed_5pct")


@pytest.mark.slow
def test_the_whole_grid():
    """Every kind x three rooms x noise given or inferred for the least squares on
    approximate points and on a floor plan (pixel kinds and a wall drawn off), the
    posterior on the 2500 mm room's new kinds; prints the table of docs/robustness.md and
    fails on any FAILED row but the known ones."""
    rows = []
    for range_mm in (1000.0, 2500.0, 5000.0):
        pts, plan = _room(range_mm), _room(range_mm, "wall")
        for noise in ("given", "inferred"):
            for method, ds, kinds in (("lsq", pts, KINDS),
                                      ("posterior", pts, POSTERIOR_KINDS if range_mm == 2500
                                       else ()),
                                      ("plan", plan, PLAN_ROW_KINDS + PLAN_KINDS)):
                kw = {"progress": False, "min_ess": 300} if method == "posterior" else {}
                for kind in kinds:
                    with warnings.catch_warnings():
                        warnings.simplefilter("ignore")
                        out = run_case(ds, kind, method=method, noise=noise, **kw)
                    rows.append((range_mm, out))
    print("\n| room | method | noise | kind | verdict | what happened |\n|---|---|---|---|---|---|")
    for range_mm, o in rows:
        print(f"| {range_mm:.0f} mm | {o['method']} | {o['noise']} | {o['kind']} | "
              f"{o['verdict']} | {o['why'][:90]} |")
    failed = {(r, o["method"], o["noise"], o["kind"]) for r, o in rows
              if o["verdict"] == "FAILED"}
    print(f"\n{len(rows) - len(failed)} of {len(rows)} cases handled or refused")
    assert failed == KNOWN_FAILURES, failed


#: the floor-plan grid's known failures (docs/robustness.md): (room, model, noise, kind).
#: The misaligned model's wall 30 % off at 5000 mm fails with the noise given and inferred
#: alike (measured 2026-11-26, the same on every main commit since this test was added):
#: the cone's tilt absorbs the wall (tilt_y -5.1 and -5.2 degrees), its wall chi-square
#: stays at 35.9 and 35.5 on 12 degrees of freedom (p = 3.4e-4 and 4.0e-4, above the
#: check's 1e-4), the good points' error x5.09 and x5.15: a limit of the plan check, not a
#: regression (the aligned model refuses both, p = 4.9e-8 and 2.6e-6)
KNOWN_PLAN_FAILURES = {(2500.0, "aligned", "given", "streak"),
                       (5000.0, "misaligned", "given", "wall_off"),
                       (5000.0, "misaligned", "inferred", "wall_off")}


@pytest.mark.slow
def test_the_floor_plan_grid():
    """The floor-plan least squares with both laser models (three rooms x noise given or
    inferred x the pixel kinds, a 5 % pixel mix and a wall drawn off) and the plan
    posterior on the 2500 mm room's row kinds with the noise inferred, whose cost must
    stay within the time budget: at most 3x the clean posterior's (same run); prints the
    table of docs/robustness.md."""
    rows, failed = [], set()
    for range_mm in (1000.0, 2500.0, 5000.0):
        plan = _room(range_mm, "wall")
        for model in ("aligned", "misaligned"):
            for noise in ("given", "inferred"):
                for kind in PLAN_ROW_KINDS + PLAN_KINDS:
                    with warnings.catch_warnings():
                        warnings.simplefilter("ignore")
                        out = run_case(plan, kind, method="plan", noise=noise, model=model)
                    rows.append((range_mm, model, out))
                    if out["verdict"] == "FAILED":
                        failed.add((range_mm, model, noise, kind))
    print("\n| room | model | noise | kind | verdict | robust start | what happened |"
          "\n|---|---|---|---|---|---|---|")
    for range_mm, model, o in rows:
        print(f"| {range_mm:.0f} mm | {model} | {o['noise']} | {o['kind']} | {o['verdict']} | "
              f"{o['robust_start']} | {o['why'][:90]} |")
    plan = _room(2500.0, "wall")
    kw = {"progress": False, "min_ess": 300, "rng": 7}
    start = time.perf_counter()
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        post = bc.sample_posterior(plan.pixels, plan.floor_plan, sigma_px=None, **kw)
    clean_s = time.perf_counter() - start
    error = float(np.mean(np.linalg.norm(post.points - plan.points, axis=1)))
    for kind in PLAN_ROW_KINDS:
        start = time.perf_counter()
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            out = run_case(plan, kind, method="plan_posterior", noise="inferred",
                           clean=error, **kw)
        ratio = (time.perf_counter() - start) / clean_s
        print(f"| 2500 mm | posterior | inferred | {kind} | {out['verdict']} | "
              f"{ratio:.2f}x the clean time | {out['why'][:90]} |")
        if out["verdict"] == "FAILED" or ratio > BUDGET_FACTOR:
            failed.add((2500.0, "posterior", "inferred", kind))
    assert failed == KNOWN_PLAN_FAILURES, failed


# -- rooms the harness did not make, and a sensor off the design ---------------------------
# The rooms above use the paper's sensor, the default prior's mean: every fit started at the
# truth there. studies/robust_rooms.py draws each room's sensor from the prior, on bayescal's
# generator and on tests/scene/rooms2.py (written without reading it), and corrupts with
# both sets (ours and tests/scene/corrupt2.py); these tests run a few of its cases.

def _study():
    import importlib
    import sys
    from pathlib import Path

    sys.path.insert(0, str(Path(__file__).resolve().parents[2] / "studies"))
    return importlib.import_module("robust_rooms")


@pytest.mark.parametrize("generator, room, cset, kind, noise", [
    ("simulate", 1, "ours", "rows_swapped", "inferred"),
    ("simulate", 0, "corrupt2", "typed_cm", "inferred"),
    ("rooms2", 2, "ours", "mixed", "given"),
    ("rooms2", 3, "corrupt2", "swap_pairs", "inferred"),
])
def test_a_room_of_either_generator_with_its_sensor_off_the_design(generator, room, cset,
                                                                      kind, noise):
    study = _study()
    ds, _ = study.make_room(generator, room)
    c = study.corruptions(ds, cset, room, [kind])[0]
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        out = run_case(ds, c, method="lsq", noise=noise)
    assert out["verdict"] == "handled", out


def _public_calls(ds, c, noise, *, posterior):
    """What the public functions do with corrupted data: result or exception per call."""
    spx = ds.sigma_px if noise == "given" else None
    scene = ds.sigma_scene if noise == "given" else None
    if scene is not None and len(c.pixels) > len(scene):
        scene = np.concatenate([scene, scene[:len(c.pixels) - len(scene)]])
    calls = {"lsq": lambda: bc.calibrate_simultaneous(c.pixels, c.approx_points, sigma_px=spx,
                                                      sigma_scene=scene)}
    if posterior:
        calls["posterior"] = lambda: bc.sample_posterior(
            c.pixels, c.approx_points, sigma_px=spx, sigma_scene=scene, rng=0, min_ess=20,
            n_samples=40, max_steps=120, n_walkers=32, progress=False)
    if ds.calibration is not None and len(c.pixels) == len(ds.pixels):
        calls["sequential"] = lambda: bc.calibrate_sequential(
            dataclasses.replace(ds, pixels=c.pixels, approx_points=c.approx_points))
    out = {}
    for name, call in calls.items():
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            try:
                out[name] = call()
            except Exception as exc:  # noqa: BLE001 (what escapes is the test)
                out[name] = exc
    return out


def _foreign(outcomes):
    return {k: f"{type(v).__name__}: {v}" for k, v in outcomes.items()
            if isinstance(v, Exception) and not isinstance(v, bc.BayescalError)}


def test_nothing_but_bayescal_errors_escape_on_a_few_harness_inputs():
    """No numpy, scipy or bare Python exception escapes the least squares and the
    sequential method on corrupted data of both generators (the whole sweep, posterior and
    command line included, is the slow test below)."""
    study = _study()
    for generator, kind, noise in (("simulate", "far_swap", "inferred"),
                                   ("rooms2", "metres", "given")):
        ds, _ = study.make_room(generator, 5)
        c = study.corruptions(ds, "ours", 5, [kind])[0]
        assert not _foreign(_public_calls(ds, c, noise, posterior=False)), (generator, kind)


@pytest.mark.slow
@pytest.mark.parametrize("generator", ["simulate", "rooms2"])
def test_nothing_but_bayescal_errors_escape_the_public_functions(generator, tmp_path):
    """Every corruption of both sets on a room of each generator, both noise modes, through
    calibrate_simultaneous, sample_posterior (short runs), calibrate_sequential (where the
    room has calibration patterns) and the command line's calibrate (exit 0, 1 or 2,
    never a traceback)."""
    from bayescal.cli.main import main

    study = _study()
    ds, _ = study.make_room(generator, 1)
    bad = {}
    for cset in ("ours", "corrupt2"):
        for c in study.corruptions(ds, cset, 1):
            for noise in ("given", "inferred"):
                found = _foreign(_public_calls(ds, c, noise, posterior=True))
                if found:
                    bad[(cset, c.kind, noise)] = found
            path = tmp_path / f"{cset}_{c.kind}.csv"
            rows = [",".join(f"{v:.9g}" for v in (*p, *a))
                    for p, a in zip(c.pixels, c.approx_points, strict=True)]
            path.write_text("u,v,x,y,z\n" + "\n".join(rows) + "\n")
            try:
                rc = main(["calibrate", str(path), "--out", str(tmp_path / f"o_{path.stem}")])
            except Exception as exc:  # noqa: BLE001
                rc = exc
            if rc not in (0, 1, 2):
                bad[(cset, c.kind, "cli")] = repr(rc)
    assert not bad, bad
