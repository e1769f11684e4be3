"""Speed-target rows of the benchmark (``studies/benchmark.py --only targets --only
targets_plan``).

Each row is a same-run ratio checked against its target and marked PASS or FAIL:

* **aligned posterior / least squares**: ``bc.sample_posterior`` (default settings,
  CPU seconds per 1000 honest ESS) over ``bc.calibrate_simultaneous`` on the same data
  (median CPU seconds of 5 calls, timed beside each posterior call), target <= 15x for
  every sampler seed (the verdict is the worst seed's; the median is in the notes), on
  four rooms (5000 mm, 5 % z-unknown points; 1000 mm, 3 % z-unknown points;
  1000 mm, 1 % z-known points at 0.5 px; 4000 mm, 1 % z-unknown points at 0.4 px: the
  last two have a fast least squares, the hardest for the ratio in
  ``studies/aligned_rooms.py``). CPU time, this process's: under a changing load the wall
  times of a seconds-long and a sub-second call meet different loads (the median wall
  time is in the notes);
* **misaligned plan posterior / aligned plan posterior**: the misaligned model on a floor
  plan (N = 300, a tilted and offset sensor) over the aligned model on the same pixels,
  both in CPU seconds per 1000 honest ESS (wall times under a changing load made the
  ratio swing 3x; the median wall time is in the notes), target <= 5x for every sampler
  seed (the worst seed's ratio decides), on six plans: the three the sampler was tuned on
  (the tilt and offset of the misaligned rows, (1, 0.5) deg, (3, -2) mm on another room,
  and a 5-wall 3500 mm room tilted the other way) and three it was not (from
  ``studies/plan_ratio_rooms.py``: a 5000 mm room, a 4000 mm room with a small tilt at
  0.4 px, a 1000 mm room tilted 2 deg both ways with the noise inferred);
* **camera posterior** (``--only targets_camera``): ``bc.sample_camera_posterior`` on 10
  simulated views (``bc.simulate_views``, default settings) in CPU seconds per 1000 ESS
  (the smallest over the sampled parameters, median over 3 sampler seeds), target <= 5 s;
  its same-run baseline is ``bc.calibrate_camera`` on the same views. CPU time (this
  process's), not wall time: the target is absolute and the machine shared; on an idle
  machine the two agree (the median wall time is in the notes);
* **N = 20 000** (``--large-n``): the wall time of the call <= 120 s and its peak
  resident memory <= 0.5 GiB, in a spawned child process.

The baseline and the candidate of a row are timed alternately, seed by seed, so that a
change of the machine's load hits both. Rows are plain tuples ``(name, setting, seconds,
ratio, notes)`` (``ratio`` = baseline time / candidate time, as in the other rows; the
cost ratio checked against the target is its inverse, in the notes). Imports only the
public API of bayescal.
"""

from __future__ import annotations

import statistics
import time
import warnings

import numpy as np

import bayescal as bc

__all__ = ["target_rows", "verdict", "camera_rows"]

NAME = "speed target"
#: the plan rows' benchmark name (a separate --only run must not replace the others)
PLAN_NAME = "speed target, plan"
#: targets: posterior per 1000 ESS over the least squares; misaligned over aligned plan
LSQ_TARGET, PLAN_TARGET = 15.0, 5.0
#: the camera rows' benchmark name and target (CPU seconds per 1000 ESS, 10 views)
CAMERA_NAME, CAMERA_TARGET = "speed target, camera", 5.0
#: the camera rows' views: simulate_views keywords
CAMERA_VIEWS = dict(n_views=10, rng=0)
#: the N = 20 000 call: wall time (s) and peak resident memory (GiB)
LARGE_N_SECONDS, LARGE_N_GIB = 120.0, 0.5

#: rooms of the aligned rows: label, simulate_room keywords
ROOMS = (
    ("N=580, 5000 mm, fig9 (z unknown) 5 %, 0.1 px",
     dict(range_mm=5000, n_points=580, sigma_px=0.1, approx_error=0.05, approx_model="fig9",
          rng=3)),
    ("N=580, 1000 mm, fig9 (z unknown) 3 %, 0.1 px",
     dict(range_mm=1000, n_points=580, sigma_px=0.1, approx_error=0.03, approx_model="fig9",
          rng=5)),
    ("N=600, 1000 mm, gaussian (z known) 1 %, 0.5 px",
     dict(range_mm=1000, n_points=600, sigma_px=0.5, approx_error=0.01,
          approx_model="gaussian", rng=22)),
    ("N=540, 4000 mm, fig9 (z unknown) 1 %, 0.4 px",
     dict(range_mm=4000, n_points=540, sigma_px=0.4, approx_error=0.01, approx_model="fig9",
          rng=26)),
)
#: plans of the misaligned rows: label, simulate_room keywords
PLANS = (
    ("N=300, 2500 mm, 3 % plan, tilt (1, 0.5) deg, offset (5, -5) mm",
     dict(range_mm=2500, n_points=300, n_walls=6, sigma_px=0.2, approx_error=0.03,
          approx_model="wall", tilt=tuple(np.radians((1.0, 0.5))), offset=(5.0, -5.0), rng=0)),
    ("N=300, 2500 mm, 3 % plan, tilt (1, 0.5) deg, offset (3, -2) mm, another room",
     dict(range_mm=2500, n_points=300, n_walls=6, sigma_px=0.2, approx_error=0.03,
          approx_model="wall", tilt=tuple(np.radians((1.0, 0.5))), offset=(3.0, -2.0), rng=7)),
    ("N=300, 3500 mm, 3 % plan, 5 walls, tilt (-0.7, 1.2) deg, offset (-4, 6) mm, a third room",
     dict(range_mm=3500, n_points=300, n_walls=5, sigma_px=0.2, approx_error=0.03,
          approx_model="wall", tilt=tuple(np.radians((-0.7, 1.2))), offset=(-4.0, 6.0),
          rng=11)),
    ("N=300, 5000 mm, 3 % plan, 7 walls, tilt (1, 0.5) deg, offset (5, -5) mm (not tuned on)",
     dict(range_mm=5000, n_points=300, n_walls=7, sigma_px=0.2, approx_error=0.03,
          approx_model="wall", tilt=tuple(np.radians((1.0, 0.5))), offset=(5.0, -5.0),
          rng=32)),
    ("N=300, 4000 mm, 2 % plan, 5 walls, 0.4 px, tilt (0.3, 0.2) deg, offset (-3, 8) mm "
     "(not tuned on)",
     dict(range_mm=4000, n_points=300, n_walls=5, sigma_px=0.4, approx_error=0.02,
          approx_model="wall", tilt=tuple(np.radians((0.3, 0.2))), offset=(-3.0, 8.0),
          rng=37)),
    ("N=300, 1000 mm, 5 % plan, 5 walls, 0.3 px inferred, tilt (2, 2) deg, offset (4, 4) mm "
     "(not tuned on)",
     dict(range_mm=1000, n_points=300, n_walls=5, sigma_px=0.3, approx_error=0.05,
          approx_model="wall", tilt=tuple(np.radians((2.0, 2.0))), offset=(4.0, 4.0),
          rng=40), None),
)


def verdict(cost_ratio, target):
    """``"PASS"`` when the cost ratio is at most the target, else ``"FAIL"``."""
    return "PASS" if np.isfinite(cost_ratio) and cost_ratio <= target else "FAIL"


def _posterior(pixels, scene, seed, *, cpu=False, **kw):
    """One ``bc.sample_posterior`` call: seconds per 1000 ESS (wall, or this process's CPU
    with ``cpu``) and the run's facts (wall seconds first)."""
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        c0, t0 = time.process_time(), time.perf_counter()
        post = bc.sample_posterior(pixels, scene, rng=seed, progress=False, **kw)
        c, t = time.process_time() - c0, time.perf_counter() - t0
    ess = float(np.min(post.ess))
    return 1000.0 * (c if cpu else t) / ess, (t, post.converged, ess, float(np.max(post.tau)),
                                              post.n_steps)


def _worst(ratios, seeds):
    """``(median, worst, its seed)`` of per-seed cost ratios."""
    k = int(np.argmax(ratios))
    return statistics.median(ratios), ratios[k], seeds[k]


def _facts(facts):
    conv = sum(f[1] for f in facts)
    return (f"median wall {statistics.median(f[0] for f in facts):.1f} s; {conv}/{len(facts)} "
            f"converged; min ESS {min(f[2] for f in facts):.0f}, max tau "
            f"{max(f[3] for f in facts):.1f}, steps {'/'.join(str(f[4]) for f in facts)}")


def _lsq_seconds(ds, sigma_scene, repeats=5):
    """Median CPU seconds (this process's) of ``repeats`` least-squares fits."""
    times = []
    for _ in range(repeats):
        c0 = time.process_time()
        bc.calibrate_simultaneous(ds.pixels, ds.approx_points, sigma_px=ds.sigma_px,
                                  sigma_scene=sigma_scene)
        times.append(time.process_time() - c0)
    return statistics.median(times)


def aligned_rows(seeds):
    """Aligned posterior per 1000 ESS against the least squares of the same data."""
    rows = []
    for label, spec in ROOMS:
        ds = bc.simulate_room(**spec)
        sig = np.maximum(ds.sigma_scene, 1.0)
        lsq, per_k, facts = [], [], []
        for seed in seeds:                        # alternate: a load change hits both
            lsq.append(_lsq_seconds(ds, sig))
            k, f = _posterior(ds.pixels, ds.approx_points, seed, sigma_px=ds.sigma_px,
                              sigma_scene=sig, cpu=True)
            per_k.append(k)
            facts.append(f)
        base, cand = statistics.median(lsq), statistics.median(per_k)
        med, worst, ws = _worst([k / b for k, b in zip(per_k, lsq, strict=True)], seeds)
        rows += [(NAME, f"least squares (CPU s), {label} (calibrate_simultaneous)", base, 1.0,
                  f"baseline; median of 5 calls per seed, median over {len(seeds)} seeds"),
                 (NAME, "aligned posterior per 1000 ESS (CPU s), same data", cand, base / cand,
                  f"cost {med:.1f}x the least squares by the median, {worst:.1f}x at worst "
                  f"(sampler seed {ws}; each seed against its own least squares; target <= "
                  f"{LSQ_TARGET:g}x for every seed): **{verdict(worst, LSQ_TARGET)}**; "
                  + _facts(facts))]
    return rows


def plan_rows(seeds):
    """Misaligned plan posterior per 1000 ESS against the aligned one on the same pixels,
    in CPU seconds (a minute-long misaligned run and a seconds-long aligned one meet
    different loads on a shared machine; wall times in the notes)."""
    rows = []
    for label, spec, *sigma in PLANS:
        ds = bc.simulate_room(**spec)
        sig = sigma[0] if sigma else ds.sigma_px          # None: the noise inferred
        al, mis, fa, fm = [], [], [], []
        for seed in seeds:
            k, f = _posterior(ds.pixels, ds.floor_plan, seed, sigma_px=sig, cpu=True)
            al.append(k)
            fa.append(f)
            k, f = _posterior(ds.pixels, ds.floor_plan, seed, sigma_px=sig,
                              model="misaligned", cpu=True)
            mis.append(k)
            fm.append(f)
        base, cand = statistics.median(al), statistics.median(mis)
        med, worst, ws = _worst([m / a for m, a in zip(mis, al, strict=True)], seeds)
        rows += [(PLAN_NAME, f"aligned plan posterior per 1000 ESS (CPU s), {label}", base,
                  1.0, "baseline (biased on this sensor); " + _facts(fa)),
                 (PLAN_NAME, "misaligned plan posterior per 1000 ESS (CPU s), same pixels", cand,
                  base / cand, f"cost {med:.1f}x the aligned plan posterior by the median, "
                  f"{worst:.1f}x at worst (sampler seed {ws}, both models with that seed; "
                  f"target <= {PLAN_TARGET:g}x for every seed): "
                  f"**{verdict(worst, PLAN_TARGET)}**; " + _facts(fm))]
    return rows


def _camera_posterior(views, seed):
    """One ``bc.sample_camera_posterior`` call: CPU and wall seconds per 1000 ESS, facts."""
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        c0, t0 = time.process_time(), time.perf_counter()
        post = bc.sample_camera_posterior(views, rng=seed)
        cpu, wall = time.process_time() - c0, time.perf_counter() - t0
    d = post.diagnostics
    ess = float(np.min(d.ess))
    return 1000.0 * cpu / ess, 1000.0 * wall / ess, (wall, post.converged, ess,
                                                    float(np.max(d.tau)), d.n_steps)


def camera_rows(seeds):
    """The camera posterior per 1000 ESS (CPU) against its least squares, same views."""
    views, _ = bc.simulate_views(**CAMERA_VIEWS)
    lsq, cpu, wall, facts = [], [], [], []
    for seed in seeds:                            # alternate: a load change hits both
        for _ in range(5):
            c0 = time.process_time()
            bc.calibrate_camera(views)
            lsq.append(time.process_time() - c0)
        c, w, f = _camera_posterior(views, seed)
        cpu.append(c)
        wall.append(w)
        facts.append(f)
    base, cand = statistics.median(lsq), statistics.median(cpu)
    label = f"{CAMERA_VIEWS['n_views']} simulated views (simulate_views, 8x6 board)"
    return [(CAMERA_NAME, f"least squares, {label} (calibrate_camera)", base, 1.0,
             f"baseline; CPU s, median of 5 calls per seed over {len(seeds)} seeds"),
            (CAMERA_NAME, "camera posterior per 1000 ESS (CPU s), same views", cand,
             base / cand,
             f"{cand:.2f} s CPU per 1000 ESS, max over seeds {max(cpu):.2f} s (target <= "
             f"{CAMERA_TARGET:g} s): **{verdict(cand, CAMERA_TARGET)}**; {cand / base:.1f}x "
             f"the least squares; wall per 1000 ESS median {statistics.median(wall):.2f} s "
             f"(shared machine); " + _facts(facts))]


def large_n_check(wall_s, peak_gib):
    """The N = 20 000 verdict text: wall time and peak memory against their targets."""
    ok = wall_s <= LARGE_N_SECONDS and peak_gib <= LARGE_N_GIB
    return (f"targets <= {LARGE_N_SECONDS:g} s and <= {LARGE_N_GIB:g} GiB: "
            f"**{'PASS' if ok else 'FAIL'}**")


def target_rows(*, quick=False, plans=True, large_n=0):
    """All target rows (one seed with ``quick``; the plan rows only with ``plans``; the
    large-N row when ``large_n`` > 0, its ratio column empty: its targets are absolute)."""
    from bench_sampler import large_n_row

    seeds = (0,) if quick else (0, 1, 2)
    rows = aligned_rows(seeds) + (plan_rows(seeds) if plans else [])
    if large_n:
        name, setting, per_k, _, notes = large_n_row(float("nan"), large_n)
        rows.append((NAME, setting, per_k, float("nan"), notes.replace("vs naive N=40; ", "")))
    return rows
