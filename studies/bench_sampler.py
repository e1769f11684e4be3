"""Sampler rows of the benchmark (``studies/benchmark.py --only sampler``).

Every row times ``bc.sample_posterior`` with default settings until every
identifiable parameter has an honest ESS >= 1000, and gives the median over
seeds of the time per 1000 effective samples (min ESS over parameters) and the
median wall time, beside a same-run baseline:

* the naive full-joint emcee at N = 10 and 40 (the baseline of the ratios);
* the collapsed sampler at N = 40, 580 (both rooms, z known and unknown, the
  "wall" model, sigma_px inferred), 5000, and on a rough floor plan (N = 580);
* optionally N = 20 000 in a child process, with its peak resident memory;
* the independent full-joint NumPyro NUTS reference (:mod:`bayescal.mcmc.nuts`) on
  the data of its slow test, when jax and numpyro can be imported.

Rows are returned as plain tuples ``(name, setting, seconds, ratio, notes)``;
the harness in ``benchmark.py`` turns them into its ``Row``. Imports only the
public API of bayescal, except the NUTS reference (an optional validation module).
"""

from __future__ import annotations

import multiprocessing
import resource
import time
import warnings
from concurrent.futures import ProcessPoolExecutor

import numpy as np

import bayescal as bc

__all__ = ["sampler_rows", "once", "SAMPLER_SEEDS"]

#: sampler seeds of every N <= 1000 row (one seed above)
SAMPLER_SEEDS = (0, 1, 2)
NAME = "posterior sampling"


def once(func):
    """Wall time of a single call (for runs too long to repeat), and its result."""
    t0 = time.perf_counter()
    out = func()
    return time.perf_counter() - t0, out


def _room_for(range_mm, model, n_points, *, approx_error=0.05, sigma_px=0.1, rng=3):
    ds = bc.simulate_room(range_mm=range_mm, n_points=n_points, sigma_px=sigma_px,
                          approx_error=approx_error, approx_model=model, rng=rng)
    return ds, np.maximum(ds.sigma_scene, 1.0)


def _naive_joint(n_points, n_steps):
    """Full-joint emcee (8 + 3N unknowns as 7 + 2N) on an N-point small room: time,
    effective samples (walkers x kept steps / max tau) and tau."""
    from bayescal.mcmc.sampling import sample_joint

    ds = bc.simulate_room(range_mm=1000, n_points=n_points, sigma_px=0.3, approx_error=0.02,
                          approx_model="gaussian", rng=4)
    t, out = once(lambda: sample_joint(ds.pixels, ds.approx_points, sigma_px=0.3,
                                       sigma_scene=ds.sigma_scene, rng=0, n_steps=n_steps))
    n_walkers = out["chain"].shape[1]
    tau = float(np.max(out["tau"]))
    ess = n_walkers * (n_steps // 2) / tau
    return ds, t, ess, tau, n_walkers


def _collapsed_runs(ds, scene, seeds, *, sigma_px="given", **kw):
    """Run ``bc.sample_posterior(ds.pixels, scene, ...)`` once per seed.

    ``scene`` is the approximate points (then give ``sigma_scene`` in ``kw``) or a
    ``bc.FloorPlan``. Returns the median wall time, the median time per 1000 ESS
    (min over parameters) and each run's facts (converged, min ESS, max tau,
    steps, NotConvergedWarning texts).
    """
    sp = ds.sigma_px if sigma_px == "given" else sigma_px
    times, per_k, facts = [], [], []
    for seed in seeds:
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always")
            t, post = once(lambda s=seed: bc.sample_posterior(
                ds.pixels, scene, sigma_px=sp, rng=s, progress=False, **kw))
        ess = float(np.min(post.ess))
        times.append(t)
        per_k.append(1000 * t / ess)
        facts.append((post.converged, ess, float(np.max(post.tau)), post.n_steps,
                      [str(w.message)[:60] for w in caught
                       if issubclass(w.category, bc.NotConvergedWarning)]))
    return float(np.median(times)), float(np.median(per_k)), facts


def _facts_text(facts):
    conv = sum(f[0] for f in facts)
    return (f"{conv}/{len(facts)} converged; min ESS {min(f[1] for f in facts):.0f}, "
            f"max tau {max(f[2] for f in facts):.1f}, steps {'/'.join(str(f[3]) for f in facts)}")


def _collapsed_row(label, base, runs, target):
    med, per_k, facts = runs
    return (NAME, label, per_k, base / per_k, f"vs naive N=40; median wall {med:.1f} s "
            f"(target <= {target} s); " + _facts_text(facts))


PER_POINT_SETTINGS = (
    # label, range_mm, approx_model, N, sample_posterior options
    ("1000 mm, fig9 (z unknown)", 1000, "fig9", 580, {}),
    ("5000 mm, fig9 (z unknown)", 5000, "fig9", 580, {}),
    ("1000 mm, gaussian (z known)", 1000, "gaussian", 580, {}),
    ("5000 mm, gaussian (z known)", 5000, "gaussian", 580, {}),
    ("1000 mm, wall", 1000, "wall", 580, {}),
    ("5000 mm, fig9, sigma_px inferred", 5000, "fig9", 580, {"sigma_px": None}),
    ("1000 mm, fig9 (z unknown)", 1000, "fig9", 5000, {}),
)


def sampler_rows(*, quick=False, large_n=0, nuts=True):
    """All sampler rows: tuples ``(name, setting, seconds, ratio, notes)``.

    ``quick`` shortens the naive baseline, uses one seed and shortens NUTS;
    ``large_n`` > 0 adds the child-process row at that N; ``nuts`` adds the
    NUTS reference row when jax/numpyro can be imported.
    """
    steps = 1000 if quick else 3000
    seeds = SAMPLER_SEEDS[:1] if quick else SAMPLER_SEEDS
    rows, base = [], {}
    for n in (10, 40):
        ds, t, ess, tau, nw = _naive_joint(n, steps)
        base[n] = (ds, 1000 * t / ess)
        rows.append((NAME, f"naive full-joint emcee, N={n} ({7 + 2 * n} dims, {nw} walkers)",
                     1000 * t / ess, 1.0, f"baseline; {steps} steps in {t:.1f} s, max tau >= "
                     f"{tau:.0f} (chain < 50 tau: tau underestimated, so its ESS/s "
                     f"{ess / t:.2g} is an upper bound)"))
    ds40, b40 = base[40]
    med, per_k, facts = _collapsed_runs(ds40, ds40.approx_points, seeds,
                                        sigma_scene=ds40.sigma_scene)
    rows.append((NAME, "collapsed sample_posterior, same N=40 data", per_k, b40 / per_k,
                 f"vs naive N=40; median wall {med:.1f} s; " + _facts_text(facts)))
    for label, range_mm, model, n, kw in PER_POINT_SETTINGS:
        ds, sig = _room_for(range_mm, model, n)
        runs = _collapsed_runs(ds, ds.approx_points, seeds[:1] if n > 1000 else seeds,
                               sigma_scene=sig, **kw)
        rows.append(_collapsed_row(f"collapsed, N={n}, {label}, 0.1 px, 5 %", b40, runs,
                                   10 if n <= 1000 else 60))
    rows.append(floor_plan_row(b40, seeds))
    if nuts:
        rows += nuts_rows(seeds, quick=quick)
    if large_n:
        rows.append(large_n_row(b40, large_n))
    return rows


def floor_plan_row(base, seeds, *, n_points=580):
    """The floor-plan posterior: N = 580, 1000 mm, "wall" errors 5 %, 0.5 px."""
    ds, _ = _room_for(1000, "wall", n_points, sigma_px=0.5)
    runs = _collapsed_runs(ds, ds.floor_plan, seeds)
    return _collapsed_row(f"floor plan, N={n_points}, 1000 mm, wall, 0.5 px, 5 % "
                          f"(sample_posterior(pixels, floor_plan))", base, runs, 10)


def peak_rss():
    """This process's peak resident memory, KiB, and where the number comes from.

    Linux: ``VmHWM`` of ``/proc/self/status``, the high-water mark of this process's
    own address space. Not ``ru_maxrss``: Linux carries it over ``fork`` and
    ``exec``, so a spawned child reports at least its parent's peak (a 1 GiB parent
    made a 30 MB child report 1.03 GiB). Elsewhere ``ru_maxrss`` with that caveat.
    """
    try:
        with open("/proc/self/status") as f:
            for line in f:
                if line.startswith("VmHWM:"):
                    return int(line.split()[1]), "VmHWM of /proc/self/status"
    except OSError:
        pass
    return (resource.getrusage(resource.RUSAGE_SELF).ru_maxrss,
            "ru_maxrss: includes the parent's peak before the spawn")


def _large_n_child(n_points):
    """Run in a fresh (spawned) process: the timing and the process's own peak RSS."""
    ds, sig = _room_for(1000, "fig9", n_points)
    runs = _collapsed_runs(ds, ds.approx_points, (0,), sigma_scene=sig, n_samples=200)
    return runs, peak_rss()


def large_n_row(base, n_points):
    """One run at large N (n_samples=200: 200 x N x 3 point draws) in a spawned child
    process, so that its peak resident memory is its own (no tracemalloc overhead)."""
    # an executor, not a Pool: if the child dies (e.g. out of memory) the result raises
    # BrokenProcessPool instead of waiting forever
    ctx = multiprocessing.get_context("spawn")
    with ProcessPoolExecutor(max_workers=1, mp_context=ctx) as pool:
        (med, per_k, facts), (peak_kib, source) = pool.submit(_large_n_child,
                                                               n_points).result()
    from bench_targets import large_n_check

    return (NAME, f"collapsed, N={n_points}, 1000 mm, fig9, 0.1 px, 5 %, n_samples=200",
            per_k, base / per_k, f"vs naive N=40; one run, wall {med:.1f} s (the "
            f"sample_posterior call only), peak resident memory {peak_kib / 2**20:.2f} GiB: "
            f"{large_n_check(med, peak_kib / 2**20)} (memory: {source} in the spawned child "
            f"process that "
            f"simulated the data and ran the call: Python, numpy and bayescal included); "
            + _facts_text(facts))


#: the z-unknown scene of tests/mcmc/test_nuts_reference.py, and its NUTS settings
NUTS_SCENE = dict(range_mm=1000.0, n_points=300, sigma_px=0.5, approx_error=0.03,
                  approx_model="fig9")
NUTS_SETTINGS = dict(num_warmup=500, num_samples=1000, num_chains=2, rng=0)


def _nuts_min_ess(params, num_chains):
    """Min over the 7 identifiable parameters of NumPyro's ESS (chains kept apart)."""
    from numpyro.diagnostics import effective_sample_size

    from bayescal.sensor.parameters import to_identifiable

    t = to_identifiable(params).reshape(num_chains, -1, 7)
    return float(np.min(np.asarray(effective_sample_size(t))))


def nuts_rows(seeds, *, quick=False, scene=None, settings=None):
    """NUTS on the full joint against the collapsed sampler, same data, same run."""
    from bayescal.mcmc.nuts import nuts_available, sample_nuts

    scene = dict(NUTS_SCENE, **(scene or {}))
    settings = dict(NUTS_SETTINGS, **(settings or {}))
    if quick:
        settings.update(num_warmup=100, num_samples=100)
    where = (f"N={scene['n_points']}, {scene['range_mm']:.0f} mm, {scene['approx_model']} "
             f"{100 * scene['approx_error']:.0f} %, {scene['sigma_px']} px")
    if not nuts_available():
        return [(NAME, f"NumPyro NUTS full joint, {where}", float("nan"), float("nan"),
                 "skipped: jax/numpyro cannot be imported (pip install bayescal[nuts])")]
    ds = bc.simulate_room(rng=3, **scene)
    sig = np.maximum(ds.sigma_scene, 1.0)
    t_nuts, ref = once(lambda: sample_nuts(
        ds.pixels, ds.approx_points, sigma_px=scene["sigma_px"], sigma_scene=sig,
        prior=bc.Prior(), q_init=ds.approx_points[:, :2], **settings))
    ess = _nuts_min_ess(ref["params"], settings["num_chains"])
    nuts_k = 1000 * t_nuts / ess
    med, per_k, facts = _collapsed_runs(ds, ds.approx_points, seeds, sigma_scene=sig,
                                        prior=bc.Prior())
    shortened = (" (as tests/mcmc/test_nuts_reference.py)" if settings == NUTS_SETTINGS else
                 " (shortened from tests/mcmc/test_nuts_reference.py's "
                 f"{NUTS_SETTINGS['num_warmup']} + {NUTS_SETTINGS['num_samples']})")
    return [
        (NAME, f"NumPyro NUTS full joint ({8 + 2 * scene['n_points']} dims), {where}",
         nuts_k, 1.0, f"baseline of the next row; one run of {settings['num_chains']} chains "
         f"x ({settings['num_warmup']} warm-up + {settings['num_samples']} draws){shortened}, "
         f"wall {t_nuts:.0f} s including JIT compilation; min ESS {ess:.0f} over the 7 "
         f"identifiable parameters (NumPyro's estimator), max r_hat "
         f"{np.max(ref['r_hat']):.3f} (8 paper parameters), {ref['divergences']} divergences"),
        (NAME, f"collapsed sample_posterior, same N={scene['n_points']} data", per_k,
         nuts_k / per_k, f"vs NUTS, same run; median wall {med:.1f} s; " + _facts_text(facts)),
    ]


MISALIGNED = "misaligned posterior"
#: the tilted sensor of the misaligned rows: (1, 0.5) deg, apex offset (5, -5) mm
TILT_DEG, OFFSET_MM = (1.0, 0.5), (5.0, -5.0)


def misaligned_rows(*, quick=False):
    """The misaligned model's posterior at N = 580 (0.1 px, 5 %, fig9): on an aligned
    sensor beside the aligned model on the same data (the same-run baseline: the issue's
    "<= 1.5x the aligned model's time"), and on a tilted, offset sensor."""
    seeds = SAMPLER_SEEDS[:1] if quick else SAMPLER_SEEDS
    ds, sig = _room_for(1000, "fig9", 580)
    base = _collapsed_runs(ds, ds.approx_points, seeds, sigma_scene=sig)
    mis = _collapsed_runs(ds, ds.approx_points, seeds, sigma_scene=sig, model="misaligned")
    rows = [(MISALIGNED, "aligned model, N=580, 1000 mm, fig9, aligned sensor", base[1], 1.0,
             f"baseline; median wall {base[0]:.1f} s; " + _facts_text(base[2])),
            (MISALIGNED, "misaligned model, same data", mis[1], base[1] / mis[1],
             f"target <= 10 s per 1000 ESS and <= 1.5x the aligned model's; median wall "
             f"{mis[0]:.1f} s; " + _facts_text(mis[2]))]
    tilted = bc.simulate_room(range_mm=2500, n_points=580, sigma_px=0.1, approx_error=0.05,
                              approx_model="fig9", tilt=tuple(np.radians(TILT_DEG)),
                              offset=OFFSET_MM, rng=3)
    runs = _collapsed_runs(tilted, tilted.approx_points, seeds,
                           sigma_scene=np.maximum(tilted.sigma_scene, 1.0), model="misaligned")
    rows.append((MISALIGNED, f"misaligned model, N=580, 2500 mm, fig9, sensor tilted "
                 f"{TILT_DEG} deg, offset {OFFSET_MM} mm", runs[1], base[1] / runs[1],
                 f"target <= 10 s per 1000 ESS; median wall {runs[0]:.1f} s; "
                 + _facts_text(runs[2])))
    return rows + misaligned_plan_rows(seeds)


def misaligned_plan_rows(seeds):
    """The misaligned model on a floor plan (300 points, 2500 mm, 6 walls, 3 % plan, the
    tilted sensor), beside the aligned model on the same data (which converges but puts
    v0 tens of sds off on a tilted sensor: docs/floorplan.md section 13)."""
    ds = bc.simulate_room(range_mm=2500, n_points=300, n_walls=6, sigma_px=0.2,
                          approx_error=0.03, approx_model="wall",
                          tilt=tuple(np.radians(TILT_DEG)), offset=OFFSET_MM, rng=0)
    base = _collapsed_runs(ds, ds.floor_plan, seeds)
    mis = _collapsed_runs(ds, ds.floor_plan, seeds, model="misaligned")
    where = f"floor plan 3 %, N=300, 2500 mm, sensor tilted {TILT_DEG} deg, offset {OFFSET_MM} mm"
    return [(MISALIGNED, f"aligned model, {where}", base[1], 1.0,
             f"baseline (biased on this sensor); median wall {base[0]:.1f} s; "
             + _facts_text(base[2])),
            (MISALIGNED, "misaligned model, same plan data", mis[1], base[1] / mis[1],
             f"HMC on the plan gradient; median wall {mis[0]:.1f} s; " + _facts_text(mis[2]))]
