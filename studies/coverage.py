"""Coverage and simulation-based calibration of the Bayesian posterior (docs/validation.md, rung 4).

The experiments live in :mod:`bayescal.validation.coverage` (coverage replications on
fixed scenes, SBC, binomial bands, summaries); this script runs them at full
size on the shared study runner and writes ``coverage.json`` with the figures
``coverage.png``, ``nse.png`` and ``sbc.png`` into ``--out``. Usage::

    python studies/coverage.py --out docs/img/validation --seed 0 --workers 2
    python studies/coverage.py --quick --out /tmp/cov          # a smoke run, ~1 min
"""

from __future__ import annotations

import json
import time

import bayescal as bc
from bayescal.cli.studyrun import study_main
from bayescal.io.data import to_jsonable
from bayescal.plotting.validation import plot_coverage, plot_nse, plot_sbc
from bayescal.validation import coverage as v

FILES = ("coverage.json", "coverage.png", "nse.png", "sbc.png")


def _options(parser):
    parser.add_argument("--reps", type=int, default=None, help="coverage replications per room")
    parser.add_argument("--sims", type=int, default=None, help="SBC simulations")
    parser.add_argument("--points", type=int, default=100, help="laser points N (coverage)")
    parser.add_argument("--sbc-points", type=int, default=40, help="laser points N (SBC)")
    parser.add_argument("--rooms", default="small,large")


def _jsonable(x):
    """JSON-ready copy of the results (the pooled NSE arrays left out)."""
    if isinstance(x, dict):
        x = {k: w for k, w in x.items() if not k.startswith("nse_pooled")}
        return {k: _jsonable(w) for k, w in x.items()}
    return to_jsonable(x, nonfinite="null")


def run(args, out):
    """Both experiments, their figures and ``coverage.json``."""
    quick = args.mode != "full"
    reps = args.reps if args.reps is not None else (6 if quick else 200)
    sims = args.sims if args.sims is not None else (10 if quick else 200)
    t0 = time.time()
    summ = {}
    for i, room in enumerate(args.rooms.split(",")):
        reps_out = v.run_coverage(v.ROOMS[room], n_reps=reps, n_points=args.points,
                                  seed=[args.seed, i], workers=args.workers,
                                  scheduler=args.scheduler)
        summ[room] = v.summarize_coverage(reps_out)
        print(f"coverage {room}: {time.time() - t0:.0f} s", flush=True)
    sbc = v.run_sbc(n_sims=sims, n_points=args.sbc_points, seed=[args.seed, 99],
                    workers=args.workers, scheduler=args.scheduler)
    counts, chi2, p = v.summarize_sbc(sbc["ranks"])
    plot_coverage(summ, out / "coverage.png")
    plot_nse(summ, out / "nse.png")
    plot_sbc(counts, chi2, sims, out / "sbc.png")
    res = {"settings": {"seed": args.seed, "reps": reps, "sims": sims, "points": args.points,
                        "sbc_points": args.sbc_points, "sampler": v.SAMPLER, "rooms": v.ROOMS,
                        "sbc_room": v.SBC_ROOM, "scene_floor_mm": v.SCENE_FLOOR_MM,
                        "bayescal": bc.__version__, "seconds": time.time() - t0},
           "coverage": summ,
           "sbc": {"names": list(v.THETA_NAMES) + ["phi"], "counts": counts, "chi2": chi2,
                   "p": p, "n_converged": int(sbc["converged"].sum()),
                   "seconds_mean": float(sbc["seconds"].mean())}}
    (out / "coverage.json").write_text(json.dumps(_jsonable(res), indent=1))


def main(argv=None):
    """Command line entry point (see the module docstring)."""
    return study_main(run, __doc__.splitlines()[0], argv, FILES, add_arguments=_options)


if __name__ == "__main__":
    raise SystemExit(main())
