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
        "the same run (a plain Python loop doing the same work), so it is comparable across runs",
        "on this shared, noisy machine; the absolute times are not. The two timings of a pair",
        "are still taken one after the other, so ratios move between runs (by up to ~2x for",
        "the sub-millisecond rows): read them as orders of magnitude.",
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
    args = parser.parse_args(argv)
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
