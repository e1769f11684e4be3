"""Spread of the aligned posterior's cost over rooms: CPU per 1000 ESS against the least squares.

The speed target (``studies/bench_targets.py``) holds ``bc.sample_posterior`` (aligned cone,
approximate points, collapsed sampler) to at most 15x the least-squares fit
``bc.calibrate_simultaneous`` of the same data per 1000 effective samples, timed in one
run. Two rooms cannot show how far the ratio moves on rooms not seen; this study times it
on :data:`ROOMS`: ranges 1000-5000 mm, the three approximate-point kinds (``fig9`` and
``wall``: z unknown, ``gaussian``: z known), 1-10 % approximate points, 0.1-0.5 px pixel
noise, ``sigma_px`` given or inferred, N 540-620.

Per room and sampler seed, alternately (a change of the machine's load hits both): the
least squares (median CPU seconds of ``--lsq-repeats`` calls, the noise given or inferred
as the posterior has it) and one posterior call (CPU seconds of this process per 1000 ESS,
the smallest ESS over the parameters). Reported per room, medians over the seeds: both
times, their ratio, the chain's max tau, steps, density evaluations per effective sample,
the CPU shares of tuning, production run and point draws
(``post.diagnostics.extra["cpu_seconds"]``), the rest being the least-squares start and the
outlier probabilities, and the independence acceptance of the first tuning round and of
the production run.

Usage::

    python studies/aligned_rooms.py [--seeds 0 1 2] [--rooms 0 3] [--json out.json] [--warmup]

``--warmup`` first runs one untimed small posterior, so that the first timed call does not
carry the process's one-time costs (imports, caches): use it when each process times only a
few calls (e.g. one process per room and code version).
"""

from __future__ import annotations

import argparse
import json
import statistics
import sys
import time
import warnings

import numpy as np

import bayescal as bc


def _room(range_mm, kind, error, sigma_px, n, seed, infer, note=""):
    """``(label, simulate_room keywords, whether sigma_px is inferred)`` of one room."""
    label = (f"{range_mm} mm, {kind} {100 * error:g} %, {sigma_px:g} px"
             f"{', sigma_px inferred' if infer else ''}, N={n}{note}")
    return label, dict(range_mm=range_mm, n_points=n, sigma_px=sigma_px, approx_error=error,
                       approx_model=kind, rng=seed), infer


#: label, simulate_room keywords, whether sigma_px is inferred
ROOMS = tuple(_room(*r) for r in (
    (5000, "fig9", 0.05, 0.1, 580, 3, False, " (benchmark room 1)"),
    (1000, "fig9", 0.03, 0.1, 580, 5, False, " (benchmark room 2)"),
    (2500, "wall", 0.03, 0.3, 580, 21, False),
    (1000, "gaussian", 0.01, 0.5, 600, 22, False),
    (3000, "fig9", 0.10, 0.2, 560, 23, True),
    (5000, "wall", 0.08, 0.5, 580, 24, True),
    (1500, "gaussian", 0.05, 0.1, 620, 25, True),
    (4000, "fig9", 0.01, 0.4, 540, 26, False),
    (2000, "wall", 0.01, 0.1, 580, 27, True),
))

COLUMNS = ("room", "posterior CPU s / 1000 ESS", "lsq CPU s", "ratio (max)", "max tau",
           "steps", "evals / ESS", "tuning / production / points / rest",
           "IMH acceptance (tuning round 1, production)", "converged")


def lsq_cpu(ds, sigma_px, sigma_scene, repeats):
    """Median CPU seconds of ``repeats`` least-squares fits of the room."""
    times = []
    for _ in range(repeats):
        c0 = time.process_time()
        bc.calibrate_simultaneous(ds.pixels, ds.approx_points, sigma_px=sigma_px,
                                  sigma_scene=sigma_scene)
        times.append(time.process_time() - c0)
    return statistics.median(times)


def posterior_cpu(ds, sigma_px, sigma_scene, seed):
    """One posterior call: a dict of its cost and the chain's facts."""
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        c0 = time.process_time()
        post = bc.sample_posterior(ds.pixels, ds.approx_points, sigma_px=sigma_px,
                                   sigma_scene=sigma_scene, rng=seed, progress=False)
        cpu = time.process_time() - c0
    d = post.diagnostics
    ess = float(np.min(d.ess))
    phases = d.extra.get("cpu_seconds", {})
    shares = [phases.get(k, float("nan")) / cpu for k in ("tuning", "production", "points")]
    return {"per_k": 1000.0 * cpu / ess, "cpu": cpu, "ess": ess, "tau": float(np.max(d.tau)),
            "steps": int(d.n_steps), "evals_per_ess": d.extra["n_evaluations"] / ess,
            "shares": shares + [1.0 - sum(shares)], "converged": bool(post.converged),
            "imh": (d.extra["tuning_imh_acceptance"][0] if d.extra["tuning_imh_acceptance"]
                    else float("nan"), d.extra.get("imh_acceptance", float("nan")))}


def warmup():
    """One untimed small posterior (60 points, min_ess=100): the process's one-time costs."""
    ds = bc.simulate_room(range_mm=1000, n_points=60, sigma_px=0.2, approx_error=0.03,
                          rng=0)
    sig_scene = np.maximum(ds.sigma_scene, 1.0)
    lsq_cpu(ds, ds.sigma_px, sig_scene, 1)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        bc.sample_posterior(ds.pixels, ds.approx_points, sigma_px=ds.sigma_px,
                            sigma_scene=sig_scene, rng=0, progress=False, min_ess=100)


def study_room(spec, infer, seeds, repeats):
    """Alternate least squares and posterior seed by seed; the per-seed records."""
    ds = bc.simulate_room(**spec)
    sig_px = None if infer else ds.sigma_px
    sig_scene = np.maximum(ds.sigma_scene, 1.0)
    runs = []
    for seed in seeds:
        lsq = lsq_cpu(ds, sig_px, sig_scene, repeats)
        run = posterior_cpu(ds, sig_px, sig_scene, seed)
        run.update(seed=seed, lsq=lsq, ratio=run["per_k"] / lsq)
        runs.append(run)
    return runs


def summary_row(label, runs):
    """One Markdown table row: medians over the seeds (the ratio also its max)."""
    med = lambda k: statistics.median(r[k] for r in runs)      # noqa: E731
    shares = np.median([r["shares"] for r in runs], axis=0)
    imh = np.median([r["imh"] for r in runs], axis=0)
    cells = (label, f"{med('per_k'):.2f}", f"{med('lsq'):.3f}",
             f"{med('ratio'):.1f}x ({max(r['ratio'] for r in runs):.1f}x)", f"{med('tau'):.1f}",
             "/".join(str(r["steps"]) for r in runs), f"{med('evals_per_ess'):.1f}",
             " / ".join(f"{100 * s:.0f} %" for s in shares),
             f"{imh[0]:.2f}, {imh[1]:.2f}", f"{sum(r['converged'] for r in runs)}/{len(runs)}")
    return "| " + " | ".join(cells) + " |"


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", type=int, nargs="+", default=[0, 1, 2])
    ap.add_argument("--rooms", type=int, nargs="+", default=None,
                    help="indices into ROOMS (default: all)")
    ap.add_argument("--lsq-repeats", type=int, default=5)
    ap.add_argument("--json", default=None, help="also write every run here")
    ap.add_argument("--warmup", action="store_true",
                    help="run one untimed small posterior first (one-time costs)")
    args = ap.parse_args(argv)
    if args.warmup:
        warmup()
    picked = range(len(ROOMS)) if args.rooms is None else args.rooms
    print("| " + " | ".join(COLUMNS) + " |")
    print("|" + "---|" * len(COLUMNS))
    out = {}
    for i in picked:
        label, spec, infer = ROOMS[i]
        runs = study_room(spec, infer, args.seeds, args.lsq_repeats)
        out[label] = runs
        print(summary_row(label, runs), flush=True)
    ratios = [r["ratio"] for runs in out.values() for r in runs]
    print(f"\nratio over every run: median {statistics.median(ratios):.1f}x, "
          f"max {max(ratios):.1f}x")
    if args.json:
        with open(args.json, "w") as fh:
            json.dump(out, fh, indent=1)
    return 0


if __name__ == "__main__":
    sys.exit(main())
