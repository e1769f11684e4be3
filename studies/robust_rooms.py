"""The corruption harness on two room generators, both corruption sets, both noise modes,
least squares and posterior: the table of ``docs/robustness.md``, "The harness on two
generators".

Generators (each room's true sensor drawn from the default prior, so that the design the
fit starts from is not the truth, as on any real sensor):

* ``simulate``: :func:`bayescal.simulate_room`, 300 points, 5-7 walls, 1000-4000 mm,
  0.2 px; approximate points with relative Gaussian errors in x, y and z
  (``approx_model="gaussian"``, 2 %) or, every other room, isotropic ones (1.6 % of the
  range, the reproducers' 40 mm at 2500 mm);
* ``rooms2``: ``tests/scene/rooms2.py``, written without reading the package's simulator:
  irregular rooms of 4-8 walls at 0.5-1.0 x 1000-5000 mm, 300 points at random azimuths,
  isotropic (20-60 mm) or relative (2 %) errors.

Corruption sets: ``ours`` (:data:`bayescal.validation.corruption.KINDS`, 16 kinds) and
``corrupt2`` (``tests/scene/corrupt2.py``, written without reading ours: 9 kinds and a 5 %
mix), each applied to both generators' rooms. Every case corrupts at most 5 % of the rows,
so a refusal counts as a failure. Judged by :func:`bayescal.validation.corruption.judge`
(good points' error within 1.25x the clean fit's, >= 90 % of the bad rows flagged, at most
3 good rows; a failed model check is a refusal).

Usage::

    python studies/robust_rooms.py [--rooms 12] [--posterior-rooms 2] [--json out.jsonl]

The posterior runs (``min_ess=300``) take a minute each; they cover ``--posterior-rooms``
rooms per generator and the kinds in :data:`POSTERIOR_KINDS`, and time each against the
clean posterior of the same room and noise mode.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import sys
import warnings
from collections import Counter
from pathlib import Path

import numpy as np

import bayescal as bc
from bayescal.validation.corruption import KINDS, Corruption, corrupt, run_case

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests" / "scene"))
import corrupt2  # noqa: E402
import rooms2  # noqa: E402

GENERATORS = ("simulate", "rooms2")
SETS = ("ours", "corrupt2")
#: the kinds the posterior runs (per set): correspondences, units, pixels, mixes
POSTERIOR_KINDS = {"ours": ("rows_swapped", "centimetres", "z_sign_flip", "ghost_ring",
                            "mixed", "mixed_5pct"),
                   "corrupt2": ("swap_pairs", "mispaired_block", "typed_m", "digit_typo",
                                "spurious_pixels", "mix")}


@dataclasses.dataclass(frozen=True)
class RoomView:
    """What ``corrupt2`` reads of a room (a :class:`bayescal.Dataset` seen as a rooms2 Room)."""

    params: np.ndarray
    nominal: np.ndarray
    pixels: np.ndarray
    pixels_true: np.ndarray
    approx_points: np.ndarray
    sigma_px: float
    sigma_scene: np.ndarray
    image_size: tuple


def _sensor(rng):
    return bc.SensorParams.from_array(bc.Prior().sample(rng=rng))


def make_room(generator, seed):
    """Room ``seed`` of a generator: ``(Dataset, description)``."""
    g = np.random.default_rng([GENERATORS.index(generator), seed])
    for _ in range(20):
        params = _sensor(g)
        try:
            if generator == "simulate":
                return _simulate_room(params, seed, g)
            return _rooms2_room(params, seed, g)
        except bc.BayescalError:      # a sensor whose ring leaves the image: draw again
            continue
    raise RuntimeError(f"no room for seed {seed}")


def _simulate_room(params, seed, g):
    range_mm = float(g.choice([1000.0, 1500.0, 2500.0, 4000.0]))
    walls = int(g.integers(5, 8))
    ds = bc.simulate_room(params, range_mm=range_mm, n_points=300, n_walls=walls,
                          sigma_px=0.2, approx_error=0.02, approx_model="gaussian", rng=seed)
    kind = "relative 2 %"
    if seed % 2:
        sd = 0.016 * range_mm
        apx = ds.points + g.normal(0.0, sd, ds.points.shape)
        ds = dataclasses.replace(ds, approx_points=apx, sigma_scene=np.full_like(apx, sd))
        kind = f"isotropic {sd:.0f} mm"
    return ds, f"{range_mm:.0f} mm, {walls} walls, {kind}"


def _rooms2_room(params, seed, g):
    range_mm = float(g.uniform(1000.0, 5000.0))
    walls = int(g.integers(4, 9))
    iso = seed % 2 == 0
    sd = float(g.uniform(20.0, 60.0)) if iso else 0.02
    room = rooms2.make_room(seed, range_mm=range_mm, n_points=300, n_walls=walls,
                            params=params, approx="isotropic" if iso else "relative",
                            approx_sd=sd, sort_azimuth=bool(seed % 3 == 0))
    kind = f"isotropic {sd:.0f} mm" if iso else "relative 2 %"
    return room.to_dataset(), f"{range_mm:.0f} mm, {walls} walls, {kind}"


def corruptions(ds, cset, seed, kinds=None):
    """The corruptions of one set on room ``ds``: a list of :class:`Corruption`."""
    out = []
    if cset == "ours":
        for kind in kinds or KINDS:
            out.append(corrupt(ds, kind, rng=seed + 7))
        return out
    view = RoomView(ds.params.to_array(), ds.nominal.to_array(), ds.pixels, ds.pixels_true,
                    ds.approx_points, ds.sigma_px, ds.sigma_scene, (800, 600))
    for kind in kinds or (*corrupt2.CORRUPTIONS, "mix"):
        make = corrupt2.mix if kind == "mix" else corrupt2.CORRUPTIONS[kind]
        try:
            bad, rows = make(view, seed + 7)
        except corrupt2.NoEligibleRows:
            continue
        out.append(Corruption(kind, bad.pixels, bad.approx_points, rows))
    return out


def _clean(ds, method, noise, **kw):
    c = Corruption("clean", ds.pixels, ds.approx_points, np.array([], int))
    from bayescal.validation.corruption import fit_corrupted

    res, _, misfit, seconds = fit_corrupted(ds, c, method=method, noise=noise, **kw)
    if isinstance(res, Exception):
        return None, f"{type(res).__name__}: {res}"[:160], seconds
    err = float(np.mean(np.linalg.norm(res.points - ds.points, axis=1)))
    return err, misfit, seconds


def run(generator, seed, method, noise, kinds_of, out, **kw):
    """Every case of one room: clean fit, then each corruption of both sets (each counted
    FAILED when the clean fit itself fails, so that no room drops out of the counts)."""
    ds, what = make_room(generator, seed)
    err, note, clean_s = _clean(ds, method, noise, **kw)
    head = {"generator": generator, "room": seed, "what": what, "method": method,
            "noise": noise, "clean_seconds": clean_s}
    for cset in SETS:
        for c in corruptions(ds, cset, seed, kinds_of(cset)):
            if err is None:
                r = {"kind": c.kind, "verdict": "FAILED", "why": f"clean fit: {note}",
                     "seconds": None, "error_ratio": None}
            else:
                r = run_case(ds, c, method=method, noise=noise, clean=err, seed=seed + 7, **kw)
            rec = {**head, "set": cset, "clean_note": note,
                   **{k: r[k] for k in ("kind", "verdict", "why", "seconds", "error_ratio")}}
            out.append(rec)
            print(json.dumps(rec), flush=True)


def table(records):
    """Markdown rows: handled / refused / failed per generator, set, method and noise."""
    lines = ["| fit | noise | set | " + " | ".join(GENERATORS) + " |",
             "|---|---|---|" + "---|" * len(GENERATORS)]
    for method in ("lsq", "posterior"):
        for noise in ("given", "inferred"):
            for cset in SETS:
                cells = []
                for gen in GENERATORS:
                    rs = [r for r in records if (r["generator"], r["method"], r["noise"],
                                                 r["set"]) == (gen, method, noise, cset)]
                    n = Counter(r["verdict"] for r in rs)
                    cells.append(f"{n['handled']}/{len(rs)}" + (
                        f", **{len(rs) - n['handled']} failed**" if len(rs) > n["handled"]
                        else "") if rs else "-")
                lines.append(f"| {method} | {noise} | {cset} | " + " | ".join(cells) + " |")
    return "\n".join(lines)


def timing(first, rooms, repeats=3):
    """CPU seconds of the clean least squares per room (the median of ``repeats`` calls),
    both generators and noise modes, printed as JSON lines: run it with the code before and
    after a change, room by room in turn, to measure the change's cost on clean data."""
    import time

    for gen in GENERATORS:
        for seed in range(first, first + rooms):
            ds, what = make_room(gen, seed)
            for noise in ("given", "inferred"):
                kw = ({"sigma_px": ds.sigma_px, "sigma_scene": ds.sigma_scene}
                      if noise == "given" else {"sigma_px": None, "sigma_scene": None})
                times, ok = [], True
                for _ in range(repeats):
                    t0 = time.process_time()
                    try:
                        bc.calibrate_simultaneous(ds.pixels, ds.approx_points, **kw)
                    except bc.BayescalError:
                        ok = False
                    times.append(time.process_time() - t0)
                print(json.dumps({"generator": gen, "room": seed, "noise": noise, "ok": ok,
                                  "seconds": float(np.median(times))}), flush=True)


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--rooms", type=int, default=12, help="least-squares rooms per generator")
    ap.add_argument("--first", type=int, default=0, help="first room seed")
    ap.add_argument("--posterior-rooms", type=int, default=0)
    ap.add_argument("--generators", nargs="+", default=list(GENERATORS), choices=GENERATORS)
    ap.add_argument("--noise", nargs="+", default=["given", "inferred"],
                    choices=["given", "inferred"])
    ap.add_argument("--from-json", type=Path, nargs="+",
                    help="print the table of earlier runs' JSON lines (no fitting)")
    ap.add_argument("--json", type=Path, help="also write every case as JSON lines")
    ap.add_argument("--timing", action="store_true",
                    help="only time the clean least squares of --rooms rooms (JSON lines)")
    args = ap.parse_args(argv)
    warnings.simplefilter("ignore")
    if args.timing:
        return timing(args.first, args.rooms)
    if args.from_json:
        records = [json.loads(line) for f in args.from_json for line in f.read_text().splitlines()
                   if line.startswith("{")]
        return summary(records)
    records = []
    for gen in args.generators:
        for seed in range(args.first, args.first + args.rooms):
            for noise in args.noise:
                run(gen, seed, "lsq", noise, lambda s: None, records)
        for seed in range(args.first, args.first + args.posterior_rooms):
            for noise in args.noise:
                run(gen, seed, "posterior", noise, lambda s: POSTERIOR_KINDS[s], records,
                    min_ess=300, progress=False)
    if args.json:
        args.json.write_text("".join(json.dumps(r) + "\n" for r in records))
    summary(records)


def summary(records):
    """Print the table and the posterior's time ratios."""
    print(table(records))
    post = [r for r in records if r["method"] == "posterior" and r["kind"] != "clean"]
    if post:
        ratio = [r["seconds"] / r["clean_seconds"] for r in post]
        print(f"posterior time on corrupted data / clean: median {np.median(ratio):.2f}, "
              f"max {max(ratio):.2f} ({len(post)} cases)")


if __name__ == "__main__":
    main()
