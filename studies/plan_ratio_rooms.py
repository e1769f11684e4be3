"""Spread of the misaligned floor-plan posterior's cost over plans it was not tuned on.

The speed target (``studies/bench_targets.py``, ``PLANS``) holds the misaligned floor-plan
posterior (``bc.sample_posterior(pixels, plan, model="misaligned")``) to at most 5x the
aligned plan posterior on the same pixels per 1000 effective samples, both in CPU seconds
of this process, timed in one run. Three benchmark plans cannot say how far the ratio
moves on plans not seen; this study times it on :data:`PLANS`: ranges 1000-5000 mm, 4-8
walls, tilts 0-2 deg in several directions, offsets 0-10 mm, pixel noise 0.1-0.5 px given
or inferred, plan errors 1-5 %, N 150-580.

Per plan and sampler seed, alternately (a change of the machine's load hits both): one
aligned and one misaligned posterior call. Each run's record: CPU seconds per 1000 ESS
(the smallest ESS over the sampled coordinates), the CPU shares of the tuning rounds,
the production run and the point draws (``post.diagnostics.extra["cpu_seconds"]``; the
rest is the least-squares start, the outlier probabilities and the assembly), steps,
density and gradient evaluations, max tau and the coordinate that has it, the first
tuning round's and the production run's independence acceptance, the HMC step, whether a
budget-stopped chain was rerun with HMC, and "converged".

Usage::

    python studies/plan_ratio_rooms.py [--plans 0 3] [--seeds 0 1] [--jsonl out.jsonl]
                                       [--only misaligned]

Each run is appended to ``--jsonl`` as it ends (a long study can be read while it runs);
the summary table (median and worst seed per plan) is printed at the end, or from a
finished file with ``--summary out.jsonl``.
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


def _plan(range_mm, n_walls, sigma_px, error, tilt_deg, offset, n, seed, infer, note=""):
    """``(label, simulate_room keywords, whether sigma_px is inferred)`` of one plan."""
    label = (f"{range_mm} mm, {n_walls} walls, {100 * error:g} % plan, {sigma_px:g} px"
             f"{' inferred' if infer else ''}, tilt ({tilt_deg[0]:g}, {tilt_deg[1]:g}) deg, "
             f"offset ({offset[0]:g}, {offset[1]:g}) mm, N={n}{note}")
    return label, dict(range_mm=range_mm, n_points=n, n_walls=n_walls, sigma_px=sigma_px,
                       approx_error=error, approx_model="wall",
                       tilt=tuple(np.radians(tilt_deg)), offset=tuple(offset), rng=seed), infer


#: label, simulate_room keywords, whether sigma_px is inferred. The first three are the
#: benchmark's PLANS (tuned on); the others were not used to tune anything.
PLANS = tuple(_plan(*p) for p in (
    (2500, 6, 0.2, 0.03, (1.0, 0.5), (5.0, -5.0), 300, 0, False, " (benchmark plan 1)"),
    (2500, 6, 0.2, 0.03, (1.0, 0.5), (3.0, -2.0), 300, 7, False, " (benchmark plan 2)"),
    (3500, 5, 0.2, 0.03, (-0.7, 1.2), (-4.0, 6.0), 300, 11, False, " (benchmark plan 3)"),
    (1000, 6, 0.2, 0.03, (0.5, -0.3), (2.0, 1.0), 300, 31, False),
    (5000, 7, 0.2, 0.03, (1.0, 0.5), (5.0, -5.0), 300, 32, False),
    (2500, 6, 0.5, 0.03, (1.0, 0.5), (5.0, -5.0), 300, 33, True),
    (2500, 4, 0.1, 0.01, (2.0, 0.0), (0.0, 3.0), 300, 34, False),
    (2500, 8, 0.3, 0.05, (0.0, 0.0), (0.0, 0.0), 300, 35, False),
    (1500, 6, 0.1, 0.03, (-1.5, 1.0), (-6.0, -2.0), 300, 36, True),
    (4000, 5, 0.4, 0.02, (0.3, 0.2), (-3.0, 8.0), 300, 37, False),
    (2500, 6, 0.2, 0.03, (1.0, 0.5), (5.0, -5.0), 580, 38, False),
    (3000, 7, 0.5, 0.01, (0.0, -2.0), (10.0, 0.0), 300, 39, False),
    (1000, 5, 0.3, 0.05, (2.0, 2.0), (4.0, 4.0), 300, 40, True),
    (2000, 6, 0.2, 0.03, (0.7, -0.7), (0.0, 0.0), 150, 41, False),
))

MODELS = ("aligned", "misaligned")


def posterior_run(ds, sigma_px, seed, model):
    """One posterior call on the plan: a dict of its cost and the chain's facts."""
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        c0 = time.process_time()
        post = bc.sample_posterior(ds.pixels, ds.floor_plan, sigma_px=sigma_px, rng=seed,
                                   progress=False, model=model)
        cpu = time.process_time() - c0
    d = post.diagnostics
    ess = np.asarray(d.ess, float)
    tau = np.asarray(d.tau, float)
    phases = d.extra.get("cpu_seconds", {})
    shares = [phases.get(k, float("nan")) / cpu for k in ("tuning", "production", "points")]
    timu = d.extra.get("tuning_imh_acceptance") or [float("nan")]
    return {"model": model, "per_k": 1000.0 * cpu / float(ess.min()), "cpu": cpu,
            "ess": float(ess.min()), "tau": float(tau.max()),
            "tau_name": str(d.names[int(np.argmax(tau))]),
            "ess_name": str(d.names[int(np.argmin(ess))]), "steps": int(d.n_steps),
            "burn": int(d.burn), "evals": int(d.extra["n_evaluations"]),
            "grad_evals": int(d.extra["n_gradient_evaluations"]),
            "tune_evals": int(d.extra["n_tuning_evaluations"]),
            "shares": shares + [1.0 - sum(shares)],
            "tune_imh": [float(a) for a in timu], "imh": float(d.extra["imh_acceptance"]),
            "hmc_step": float(d.extra["hmc_step_size"]), "moves": d.moves,
            "rerun": d.extra.get("rerun_with_hmc"), "converged": bool(post.converged),
            "n_walkers": int(d.n_walkers), "ndim": len(d.names)}


def study_plan(index, seeds, models, out):
    """Alternate the two models seed by seed on plan ``index``; append each run to ``out``."""
    label, spec, infer = PLANS[index]
    ds = bc.simulate_room(**spec)
    sig = None if infer else ds.sigma_px
    runs = []
    for seed in seeds:
        for model in models:
            run = posterior_run(ds, sig, seed, model)
            run.update(plan=index, label=label, seed=seed,
                       load=float(open("/proc/loadavg").read().split()[0]))
            runs.append(run)
            if out is not None:
                with open(out, "a") as fh:
                    fh.write(json.dumps(run) + "\n")
            print(f"plan {index} seed {seed} {model}: {run['per_k']:.2f} s/1000 ESS, "
                  f"tau {run['tau']:.1f} ({run['tau_name']}), steps {run['steps']}, "
                  f"converged {run['converged']}", flush=True)
    return runs


def summary(runs):
    """Markdown table: per plan, the median and the worst seed of the CPU ratio."""
    lines = ["| plan | aligned CPU s / 1000 ESS | misaligned CPU s / 1000 ESS | ratio median "
             "(worst seed) | misaligned max tau (coordinate) | misaligned steps | "
             "tuning / production / points / rest | converged |",
             "|---|---|---|---|---|---|---|---|"]
    worst = []
    for p in sorted({r["plan"] for r in runs}):
        rs = [r for r in runs if r["plan"] == p]
        al = {r["seed"]: r for r in rs if r["model"] == "aligned"}
        mi = {r["seed"]: r for r in rs if r["model"] == "misaligned"}
        seeds = sorted(set(al) & set(mi))
        if not seeds:
            continue
        ratios = [mi[s]["per_k"] / al[s]["per_k"] for s in seeds]
        worst.append(max(ratios))
        shares = np.median([mi[s]["shares"] for s in seeds], axis=0)
        lines.append("| " + " | ".join((
            rs[0]["label"], "/".join(f"{al[s]['per_k']:.2f}" for s in seeds),
            "/".join(f"{mi[s]['per_k']:.1f}" for s in seeds),
            f"{statistics.median(ratios):.2f}x ({max(ratios):.2f}x)",
            "/".join(f"{mi[s]['tau']:.1f} ({mi[s]['tau_name']})" for s in seeds),
            "/".join(str(mi[s]["steps"]) for s in seeds),
            " / ".join(f"{100 * x:.0f} %" for x in shares),
            f"{sum(al[s]['converged'] for s in seeds)}+{sum(mi[s]['converged'] for s in seeds)}"
            f"/{2 * len(seeds)}")) + " |")
    if worst:
        lines.append(f"\nworst seed over every plan: {max(worst):.2f}x")
    return "\n".join(lines)


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--plans", type=int, nargs="+", default=None,
                    help="indices into PLANS (default: all)")
    ap.add_argument("--seeds", type=int, nargs="+", default=[0, 1])
    ap.add_argument("--only", choices=MODELS, default=None)
    ap.add_argument("--jsonl", default=None, help="append every run here")
    ap.add_argument("--summary", default=None, help="only summarise this finished file")
    args = ap.parse_args(argv)
    if args.summary:
        with open(args.summary) as fh:
            print(summary([json.loads(line) for line in fh if line.strip()]))
        return 0
    models = MODELS if args.only is None else (args.only,)
    picked = range(len(PLANS)) if args.plans is None else args.plans
    runs = []
    for i in picked:
        runs += study_plan(i, args.seeds, models, args.jsonl)
    print(summary(runs))
    return 0


if __name__ == "__main__":
    sys.exit(main())
