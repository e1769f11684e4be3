"""Benchmark harness: time the package's hot paths and write docs/performance.md.

A small registry: every benchmark is a function decorated with
``@benchmark("name")`` that takes a :class:`Timer` and returns a list of
:class:`Row` (name, setting, median seconds per call, ratio against a baseline
measured *in the same run*, notes). The ratio, not the absolute time, is the
number to compare across machines and runs: the machine is shared and noisy,
the baseline suffers the same noise. Later issues add rows by adding a
function here (e.g. the log posterior, the least-squares fit, the sampler).

Usage::

    python studies/benchmark.py                      # all benchmarks -> docs/performance.md
    python studies/benchmark.py --quick              # fewer repeats (smoke test)
    python studies/benchmark.py --only project_triangulate --out /tmp/perf.md

Imports only the public API of bayescal.
"""

from __future__ import annotations

import argparse
import datetime
import os
import pathlib
import platform
import statistics
import sys
import time
from dataclasses import dataclass

import numpy as np

import bayescal as bc

BENCHMARKS = {}


def benchmark(name):
    """Register ``func(timer) -> list[Row]`` under ``name``."""
    def register(func):
        if name in BENCHMARKS:
            raise ValueError(f"benchmark {name!r} is registered twice")
        BENCHMARKS[name] = func
        return func
    return register


@dataclass(frozen=True)
class Row:
    """One line of the results table.

    ``seconds`` is the median time of one call; ``ratio`` is
    ``baseline seconds / seconds`` (speed-up over the baseline row of the same
    group, 1.0 for the baseline itself).
    """

    name: str
    setting: str
    seconds: float
    ratio: float
    notes: str = ""


class Timer:
    """Median wall time of one call, over ``repeats`` repeats of ``number`` calls.

    ``number`` is chosen so that one repeat lasts at least ``min_time`` seconds.
    """

    def __init__(self, *, repeats=7, min_time=0.05):
        self.repeats = repeats
        self.min_time = min_time

    def __call__(self, func):
        func()                                              # warm-up
        number, t = 1, 0.0
        while True:
            t = self._run(func, number)
            if t >= self.min_time or number >= 1 << 20:
                break
            number *= max(2, int(self.min_time / max(t, 1e-9)))
        times = [t] + [self._run(func, number) for _ in range(self.repeats - 1)]
        return statistics.median(times) / number

    @staticmethod
    def _run(func, number):
        t0 = time.perf_counter()
        for _ in range(number):
            func()
        return time.perf_counter() - t0


def compare(timer, name, setting, baseline, candidates, *, baseline_note="", notes=None):
    """Time ``baseline`` and each of ``candidates`` ({label: func}); rows with ratios."""
    t_base = timer(baseline)
    rows = [Row(name, f"{setting}, {baseline_note}", t_base, 1.0, "baseline")]
    for label, func in candidates.items():
        t = timer(func)
        rows.append(Row(name, f"{setting}, {label}", t, t_base / t, (notes or {}).get(label, "")))
    return rows


def _room_pixels(n_points, rng):
    ds = bc.simulate_room(range_mm=5000, n_points=n_points, sigma_px=0.1, rng=rng)
    return ds.params, ds.points, ds.pixels


def _walkers(params, n_walkers, rng):
    a = np.tile(params.to_array(), (n_walkers, 1))
    a[:, 2:6] += rng.normal(0.0, 0.5, (n_walkers, 4))
    a[:, 6] += rng.normal(0.0, 2.0, n_walkers)
    a[:, 7] += rng.normal(0.0, 0.005, n_walkers)
    return a


@benchmark("project_triangulate")
def bench_project_triangulate(timer):
    """Eq. (1) and the ray/cone intersection: one sensor, and 64 walkers at once."""
    rng = np.random.default_rng(0)
    p, pts, pix = _room_pixels(580, rng)
    rows = []
    for fname in ("project", "triangulate"):
        f = getattr(bc, fname)
        data = pts if fname == "project" else pix
        rows += compare(
            timer, fname, "580 points",
            lambda f=f, data=data: [f(p, x) for x in data],
            {"vectorized": lambda f=f, data=data: f(p, data)},
            baseline_note="Python loop over points")
    a = _walkers(p, 64, rng)
    for fname in ("project", "triangulate"):
        f = getattr(bc, fname)
        data = pts if fname == "project" else pix
        rows += compare(
            timer, fname, "64 walkers x 580 points",
            lambda f=f, data=data: [f(a[w], data) for w in range(len(a))],
            {"vectorized, params (64, 1, 8)": lambda f=f, data=data: f(a[:, None, :], data)},
            baseline_note="Python loop over walkers",
            notes={"vectorized, params (64, 1, 8)": "each looped call already spans 580 "
                   "points, so only the per-call overhead is saved"})
    return rows


def _once(func):
    """Wall time of a single call (for runs too long to repeat), and its result."""
    t0 = time.perf_counter()
    out = func()
    return time.perf_counter() - t0, out


def _large_room_580():
    """The setting of fact 3 (docs/model.md): 580 points, 5000 mm, 0.1 px, 5 % approximate."""
    ds = bc.simulate_room(range_mm=5000, n_points=580, sigma_px=0.1, approx_error=0.05,
                          approx_model="gaussian", rng=3)
    return ds, np.maximum(ds.sigma_scene, 1.0)


def _dense_joint_lsq(ds, sigma_scene, *, max_nfev):
    """Baseline for the simultaneous fit: the same whitened residuals (pixel, scene and
    prior rows of bayescal.model.LaserLikelihood and bayescal.priors.Prior) handed to
    scipy.optimize.least_squares over all 8 + 2N unknowns at once, with a dense '2-point'
    finite-difference Jacobian and no Schur complement (internal API on purpose: the
    baseline must share the model to be a fair comparison)."""
    from scipy.optimize import least_squares

    from bayescal.model import LaserLikelihood
    from bayescal.parameters import from_identifiable, to_identifiable

    lik = LaserLikelihood(ds.pixels, ds.approx_points, sigma_px=0.1, sigma_scene=sigma_scene)
    prior = bc.Prior()
    sig, w, _ = lik.noise(np.zeros(0))
    theta0 = to_identifiable(prior.mean().to_array())
    x0 = np.concatenate([theta0, [prior.mean().phi], lik.initial_q(theta0).ravel()])

    def fun(x):
        R = lik.residuals(x[:7], x[8:].reshape(-1, 2), sig, w)
        rp = prior.residuals(from_identifiable(x[:7], x[7]))
        return np.nan_to_num(np.concatenate([R.ravel(), rp]), nan=1e6)

    opt = least_squares(fun, x0, jac="2-point", method="trf", x_scale="jac",
                        max_nfev=max_nfev)
    return opt


@benchmark("simultaneous_lsq")
def bench_simultaneous_lsq(timer):
    """Simultaneous calibration on the 580-point large room: Schur-complement LM with
    analytic Jacobians against dense scipy least squares with finite differences."""
    ds, sigma_scene = _large_room_580()
    fit = lambda: bc.calibrate_simultaneous(ds.pixels, ds.approx_points,  # noqa: E731
                                            sigma_px=0.1, sigma_scene=sigma_scene)
    t_ours = Timer(repeats=min(timer.repeats, 5), min_time=0.0)(fit)
    res = fit()
    cost_ours = res.extras["map"].cost
    max_nfev = 3                       # ~17 s per iteration on the 2-core machine
    t_base, opt = _once(lambda: _dense_joint_lsq(ds, sigma_scene, max_nfev=max_nfev))
    n_unk = 8 + 2 * ds.n_points
    note_base = (f"one run, capped at max_nfev={max_nfev} iterations (each needs a "
                 f"{n_unk}-column finite-difference Jacobian): stopped with cost "
                 f"{opt.cost:.4g} vs {cost_ours:.4g} at the Schur solution; "
                 f"{'converged' if opt.success and opt.status > 0 else 'not converged'}")
    return [Row("simultaneous fit", "580 pts, 5000 mm, 0.1 px, 5 %, scipy least_squares "
                "dense 2-point Jacobian", t_base, 1.0, "baseline; " + note_base),
            Row("simultaneous fit", "580 pts, 5000 mm, 0.1 px, 5 %, calibrate_simultaneous "
                "(Schur LM, analytic Jacobian)", t_ours, t_base / t_ours,
                f"median of {min(timer.repeats, 5)}; target < 1 s; {res.nfev} evaluations, "
                f"converged={res.converged}; a lower bound on the speed-up (baseline capped)")]


def _naive_joint(n_points, n_steps):
    """Full-joint emcee (8 + 3N unknowns as 7 + 2N) on an N-point small room: time,
    effective samples (walkers x kept steps / max tau) and tau."""
    from bayescal.sampling import sample_joint

    ds = bc.simulate_room(range_mm=1000, n_points=n_points, sigma_px=0.3, approx_error=0.02,
                          approx_model="gaussian", rng=4)
    t, out = _once(lambda: sample_joint(ds.pixels, ds.approx_points, sigma_px=0.3,
                                        sigma_scene=ds.sigma_scene, rng=0, n_steps=n_steps))
    n_walkers = out["chain"].shape[1]
    tau = float(np.max(out["tau"]))
    ess = n_walkers * (n_steps // 2) / tau
    return ds, t, ess, tau, n_walkers


SAMPLER_SEEDS = (0, 1, 2)
#: N of the one large-N sampler row (set by --large-n; 0 = skipped)
LARGE_N = 0


def _room_for(range_mm, model, n_points, *, approx_error=0.05, sigma_px=0.1, rng=3):
    ds = bc.simulate_room(range_mm=range_mm, n_points=n_points, sigma_px=sigma_px,
                          approx_error=approx_error, approx_model=model, rng=rng)
    return ds, np.maximum(ds.sigma_scene, 1.0)


def _collapsed_runs(ds, sigma_scene, seeds, *, sigma_px="given", **kw):
    """Median wall time, median time per 1000 ESS (min over parameters), the runs' facts."""
    import warnings

    sp = ds.sigma_px if sigma_px == "given" else sigma_px
    times, per_k, facts = [], [], []
    for seed in seeds:
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always")
            t, post = _once(lambda s=seed: bc.sample_posterior(
                ds.pixels, ds.approx_points, sigma_px=sp, sigma_scene=sigma_scene, rng=s,
                progress=False, **kw))
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


@benchmark("sampler")
def bench_sampler(timer):
    """Collapsed sampler until every parameter has an honest ESS >= 1000 (default settings),
    beside the naive full-joint emcee at N = 10 and N = 40 (the same-run baseline). Rows
    give the median over seeds of the time per 1000 effective samples (lower is better) and
    the median wall time; the target is <= 10 s at N = 580, <= 60 s at N = 5000, <= 5 min
    at N = 20 000."""
    quick = timer.repeats < 7
    steps = {10: 1000 if quick else 3000, 40: 1000 if quick else 3000}
    seeds = SAMPLER_SEEDS[:1] if quick else SAMPLER_SEEDS
    rows = []
    base = {}
    for n in (10, 40):
        ds, t, ess, tau, nw = _naive_joint(n, steps[n])
        base[n] = (ds, 1000 * t / ess)
        rows.append(Row("posterior sampling", f"naive full-joint emcee, N={n} "
                        f"({7 + 2 * n} dims, {nw} walkers)", 1000 * t / ess, 1.0,
                        f"baseline; {steps[n]} steps in {t:.1f} s, max tau >= {tau:.0f} "
                        f"(chain < 50 tau: tau underestimated, so its ESS/s "
                        f"{ess / t:.2g} is an upper bound)"))
    ds40 = base[40][0]
    med, per_k, facts = _collapsed_runs(ds40, ds40.sigma_scene, seeds)
    rows.append(Row("posterior sampling", "collapsed sample_posterior, same N=40 data",
                    per_k, base[40][1] / per_k, f"vs naive N=40; median wall {med:.1f} s; "
                    + _facts_text(facts)))
    settings = [("1000 mm, fig9 (z unknown)", 1000, "fig9", 580, {}),
                ("5000 mm, fig9 (z unknown)", 5000, "fig9", 580, {}),
                ("1000 mm, gaussian (z known)", 1000, "gaussian", 580, {}),
                ("5000 mm, gaussian (z known)", 5000, "gaussian", 580, {}),
                ("1000 mm, wall", 1000, "wall", 580, {}),
                ("5000 mm, fig9, sigma_px inferred", 5000, "fig9", 580, {"sigma_px": None}),
                ("1000 mm, fig9 (z unknown)", 1000, "fig9", 5000, {})]
    for label, range_mm, model, n, kw in settings:
        ds, sig = _room_for(range_mm, model, n)
        med, per_k, facts = _collapsed_runs(ds, sig, seeds[:1] if n > 1000 else seeds, **kw)
        target = 10 if n <= 1000 else 60
        rows.append(Row("posterior sampling", f"collapsed, N={n}, {label}, 0.1 px, 5 %",
                        per_k, base[40][1] / per_k,
                        f"vs naive N=40; median wall {med:.1f} s (target <= {target} s); "
                        + _facts_text(facts)))
    if LARGE_N:
        rows.append(_large_n_row(base[40][1], LARGE_N))
    return rows


def _large_n_row(base_seconds, n_points):
    """One run at N = 20 000 (n_samples=200: 200 x N x 3 point draws), with peak memory."""
    import tracemalloc

    ds, sig = _room_for(1000, "fig9", n_points)
    tracemalloc.start()
    med, per_k, facts = _collapsed_runs(ds, sig, (0,), n_samples=200)
    peak = tracemalloc.get_traced_memory()[1]
    tracemalloc.stop()
    return Row("posterior sampling", f"collapsed, N={n_points}, 1000 mm, fig9, 0.1 px, 5 %, "
               f"n_samples=200", per_k, base_seconds / per_k,
               f"vs naive N=40; one run, wall {med:.1f} s (target <= 300 s); peak traced "
               f"memory {peak / 2**20:.0f} MiB (tracemalloc: numpy arrays included); "
               + _facts_text(facts))


def machine_facts():
    """Facts that make the timings interpretable."""
    try:
        affinity = len(os.sched_getaffinity(0))
    except AttributeError:
        affinity = os.cpu_count()
    return {
        "date (UTC)": datetime.datetime.now(datetime.timezone.utc).strftime("%Y-%m-%d %H:%M"),
        "cores (os.cpu_count / usable)": f"{os.cpu_count()} / {affinity}",
        "platform": platform.platform(),
        "processor": platform.processor() or platform.machine(),
        "python": sys.version.split()[0],
        "numpy": np.__version__,
        "bayescal": bc.__version__,
        "load average (1 min) at the end": f"{os.getloadavg()[0]:.1f} on "
        f"{os.cpu_count()} cores (the machine is shared with other jobs: compare ratios, "
        f"not absolute times)",
    }


def _fmt_seconds(s):
    for unit, scale in (("s", 1.0), ("ms", 1e-3), ("us", 1e-6)):
        if s >= scale:
            return f"{s / scale:.3g} {unit}"
    return f"{s / 1e-9:.3g} ns"


def table(rows):
    """Markdown table of ``rows``."""
    lines = ["| benchmark | setting | median time / call | speed-up vs baseline | notes |",
             "|---|---|---:|---:|---|"]
    for r in rows:
        lines.append(f"| {r.name} | {r.setting} | {_fmt_seconds(r.seconds)} | "
                     f"{r.ratio:.1f}x | {r.notes} |")
    return "\n".join(lines)


def write_markdown(path, rows, facts, args):
    text = [
        "# Performance",
        "",
        "Written by `studies/benchmark.py` (`make bench`); do not edit by hand. Each time is the",
        "median over repeats of one call. The speed-up is measured against a baseline timed in",
        "the same run (a plain Python loop doing the same work, or the naive method the package",
        "replaces), so it is comparable across runs",
        "on this shared, noisy machine; the absolute times are not. The two timings of a pair",
        "are still taken one after the other, so ratios move between runs (by up to ~2x for",
        "the sub-millisecond rows): read them as orders of magnitude. Rows whose notes say",
        "\"one run\" or give a wall time were timed once (they take seconds to minutes); the",
        "sampler rows give the time per 1000 effective samples (min over parameters).",
        "",
        "## Machine",
        "",
        *[f"- {k}: {v}" for k, v in facts.items()],
        f"- run: `{' '.join(['python studies/benchmark.py'] + args)}`",
        "",
        "## Results",
        "",
        table(rows),
        "",
        "## Adding a benchmark",
        "",
        "Write a function `f(timer) -> list[Row]` in `studies/benchmark.py`, decorate it with",
        "`@benchmark(\"name\")`, and build its rows with `compare(timer, name, setting, baseline,",
        "{label: candidate})` so every group carries its own same-run baseline.",
        "",
    ]
    path = pathlib.Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text("\n".join(text))


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out", default="docs/performance.md",
                        help="Markdown file to write (default: docs/performance.md)")
    parser.add_argument("--quick", action="store_true", help="fewer, shorter repeats")
    parser.add_argument("--only", choices=sorted(BENCHMARKS), action="append",
                        help="run only this benchmark (repeatable)")
    argv = sys.argv[1:] if argv is None else list(argv)
    parser.add_argument("--large-n", type=int, default=0,
                        help="also time the sampler once at this N (e.g. 20000; minutes)")
    args = parser.parse_args(argv)
    global LARGE_N
    LARGE_N = args.large_n
    timer = Timer(repeats=3, min_time=0.01) if args.quick else Timer()
    rows = []
    for name in args.only or BENCHMARKS:
        rows += BENCHMARKS[name](timer)
    print(table(rows))
    write_markdown(args.out, rows, machine_facts(), argv)
    print(f"wrote {args.out}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
