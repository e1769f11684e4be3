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
    python studies/benchmark.py --only sampler --large-n 20000   # sampler rows only
    python studies/benchmark.py --only targets       # the speed targets, PASS/FAIL
    python studies/benchmark.py --only targets_camera   # the camera posterior's target

An ``--only`` run keeps the other benchmarks' rows of the existing output file
(and says from which run they come). The sampler rows live in
``studies/bench_sampler.py``.

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

sys.path.insert(0, str(pathlib.Path(__file__).resolve().parent))

from bench_sampler import once as _once  # noqa: E402

import bayescal as bc  # noqa: E402

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


def _plain_peaks(img, center, n):
    """The naive baseline: a Python loop over azimuths, argmax and a 3-point parabola."""
    out = []
    radii = np.arange(3.0, 280.0)
    for phi in np.linspace(-np.pi, np.pi, n, endpoint=False):
        u = np.rint(center[0] + np.cos(phi) * radii).astype(int)
        v = np.rint(center[1] + np.sin(phi) * radii).astype(int)
        prof = img[v, u].astype(float)
        k = int(np.clip(np.argmax(prof), 1, len(prof) - 2))
        a, b, c = prof[k - 1:k + 2]
        den = a - 2 * b + c
        out.append(radii[k] + (0.5 * (a - c) / den if den != 0 else 0.0))
    return np.array(out)


@benchmark("image")
def bench_image(timer):
    """One 800x600 image: rendering it, and extracting its laser pixels with covariances
    (target <= 1 s) against a plain per-azimuth Python loop without covariances."""
    p = bc.SensorParams.paper()
    img, truth = bc.render_image(p, bc.room_walls(2500), rng=0, n_lamps=2, ghost=0.3,
                                 with_background=True)
    rows = compare(timer, "render_image", "800x600, 2500 mm, lamps, ghost, laser-off image",
                   lambda: bc.render_image(p, bc.room_walls(2500), rng=0, n_lamps=2, ghost=0.3,
                                           with_background=True), {},
                   baseline_note="vectorised over pixels")
    n = len(bc.extract_laser(img, background=truth.background))
    rows += compare(timer, "extract_laser", f"800x600, {n} azimuths",
                    lambda: _plain_peaks(img.astype(float) - truth.background, (400.0, 300.0), n),
                    {"extract_laser (laser-off image, centre fitted, covariances)":
                     lambda: bc.extract_laser(img, background=truth.background)},
                    baseline_note="plain peak finder, Python loop over azimuths")
    return rows


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


@benchmark("reconstruction")
def bench_reconstruction(timer):
    """2000 new pixels from a posterior: the plain loop over posterior draws, the sampled
    path, and the prepared fast path (first order in the identifiable parameters)."""
    import warnings

    ds = bc.simulate_room(range_mm=2500, n_points=300, n_walls=6, sigma_px=0.2,
                          approx_error=0.03, approx_model="gaussian", rng=0)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        post = bc.sample_posterior(ds.pixels, ds.approx_points, sigma_px=0.2,
                                   sigma_scene=ds.sigma_scene, rng=1, progress=False)
    pix = bc.simulate_room(range_mm=2500, n_points=2000, n_walls=6, sigma_px=0.2,
                           rng=5).pixels
    rng = np.random.default_rng(0)
    draws = post.param_samples[np.linspace(0, post.n_samples - 1, 400).astype(int)]

    def plain_loop():
        pts = np.stack([bc.triangulate(bc.SensorParams.from_array(a),
                                       pix + 0.2 * rng.standard_normal(pix.shape))
                        for a in draws])
        return np.nanmean(pts, axis=0), np.nanstd(pts, axis=0)

    t0 = time.perf_counter()
    rc = post.reconstructor()
    prep = time.perf_counter() - t0
    rows = compare(timer, "reconstruct", "posterior of 300 points, 2500 mm, 2000 pixels",
                   plain_loop,
                   {"sampled path (method='sampled', 1000 draws)":
                    lambda: post.reconstruct(pix, method="sampled", rng=0),
                    "fast path (post.reconstruct, prepared)": lambda: post.reconstruct(pix)},
                   baseline_note="loop over 400 draws through bc.triangulate + pixel noise",
                   notes={"fast path (post.reconstruct, prepared)":
                          f"one-time preparation {prep * 1e3:.0f} ms (check against 2000 "
                          f"draws: sd ratio median {rc.agreement['sd_ratio_median']:.3f}, "
                          f"90 % within {rc.agreement['sd_deviation_p90']:.1%})"})
    # a frame end to end: a rendered 800x600 image of the same room -> extractor -> points
    image, _ = bc.render_image(ds.params, ds.walls, rng=2)
    u0v0 = (post.params.u0, post.params.v0)

    def frame(method):
        lp = bc.extract_laser(image, center=u0v0)
        keep = ~lp.flagged
        return post.reconstruct(lp.pixels[keep], pixel_cov=lp.covariance[keep], method=method,
                                rng=0)

    rows += compare(timer, "frame", "800x600 image -> extract_laser -> points with covariances",
                    lambda: frame("sampled"), {"fast path": lambda: frame("auto")},
                    baseline_note="sampled path (1000 draws)")
    return rows


def _large_room_580():
    """The setting of fact 3 (docs/model.md): 580 points, 5000 mm, 0.1 px, 5 % approximate."""
    ds = bc.simulate_room(range_mm=5000, n_points=580, sigma_px=0.1, approx_error=0.05,
                          approx_model="gaussian", rng=3)
    return ds, np.maximum(ds.sigma_scene, 1.0)


def _dense_joint_lsq(ds, sigma_scene, *, max_nfev):
    """Baseline for the simultaneous fit: the same whitened residuals (pixel, scene and
    prior rows of bayescal.likelihood.points.LaserLikelihood and
    bayescal.likelihood.priors.Prior) handed to
    scipy.optimize.least_squares over all 8 + 2N unknowns at once, with a dense '2-point'
    finite-difference Jacobian and no Schur complement (internal API on purpose: the
    baseline must share the model to be a fair comparison)."""
    from scipy.optimize import least_squares

    from bayescal.likelihood.points import LaserLikelihood
    from bayescal.sensor.parameters import from_identifiable, to_identifiable

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


@benchmark("sampler")
def bench_sampler(timer):
    """Collapsed sampler until every parameter has an honest ESS >= 1000 (default settings),
    beside the naive full-joint emcee at N = 10 and N = 40 (the same-run baseline) and the
    NumPyro NUTS reference; rows and settings in ``studies/bench_sampler.py``. Rows give the
    median over seeds of the time per 1000 effective samples (lower is better) and the
    median wall time; the target is <= 10 s at N = 580, <= 60 s at N = 5000, <= 5 min at
    N = 20 000."""
    from bench_sampler import sampler_rows

    return [Row(*r) for r in sampler_rows(quick=timer.repeats < 7)]


@benchmark("misaligned")
def bench_misaligned(timer):
    """The misaligned model's posterior (laser cone tilt and offset sampled too) at N = 580,
    against the aligned model on the same data in the same run; rows in
    ``studies/bench_sampler.py`` (:func:`misaligned_rows`). Target <= 10 s per 1000 ESS."""
    from bench_sampler import misaligned_rows

    return [Row(*r) for r in misaligned_rows(quick=timer.repeats < 7)]


@benchmark("targets")
def bench_targets(timer):
    """The speed targets as same-run ratios, each marked PASS or FAIL: the aligned
    posterior per 1000 ESS <= 15x the least squares of the same data (two rooms), and with
    ``--large-n`` the sampler at that N (120 s, 0.5 GiB at 20 000); rows in
    ``studies/bench_targets.py``."""
    from bench_targets import target_rows

    return [Row(*r) for r in target_rows(quick=timer.repeats < 7, plans=False,
                                         large_n=LARGE_N)]


@benchmark("targets_plan")
def bench_targets_plan(timer):
    """The misaligned floor-plan posterior per 1000 ESS <= 5x the aligned plan posterior on
    the same pixels for every sampler seed, six plans (three not tuned on), PASS or FAIL
    (minutes per seed)."""
    from bench_targets import plan_rows

    return [Row(*r) for r in plan_rows((0,) if timer.repeats < 7 else (0, 1, 2))]


@benchmark("targets_camera")
def bench_targets_camera(timer):
    """The camera posterior on 10 simulated views at most 5 s (CPU) per 1000 ESS, beside
    the least squares of the same views, PASS or FAIL (three sampler seeds)."""
    from bench_targets import camera_rows

    return [Row(*r) for r in camera_rows((0,) if timer.repeats < 7 else (0, 1, 2))]


#: N of the one large-N sampler row (set by --large-n; 0 = skipped)
LARGE_N = 0


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
    if not np.isfinite(s):
        return "-"
    for unit, scale in (("s", 1.0), ("ms", 1e-3), ("us", 1e-6)):
        if s >= scale:
            return f"{s / scale:.3g} {unit}"
    return f"{s / 1e-9:.3g} ns"


def _row_line(r):
    ratio = "-" if not np.isfinite(r.ratio) else (
        f"{r.ratio:.1f}x" if r.ratio >= 0.1 else f"{r.ratio:.2g}x")      # 0.038x, not 0.0x
    return f"| {r.name} | {r.setting} | {_fmt_seconds(r.seconds)} | {ratio} | {r.notes} |"


TABLE_HEAD = ["| benchmark | setting | median time / call | speed-up vs baseline | notes |",
              "|---|---|---:|---:|---|"]
#: the line of docs/performance.md that names the run of the carried-over rows
CARRIED_PREFIX = "Rows not produced by the run above are carried over from"


def table(rows):
    """Markdown table of ``rows``."""
    return "\n".join(TABLE_HEAD + [_row_line(r) for r in rows])


def carry_over(path, rows):
    """Merge ``rows`` into the table of an earlier ``path`` (a partial ``--only`` run).

    Rows of the old table whose benchmark name this run produced are replaced by
    the new rows (at the place of the first of them); the others are kept verbatim.
    Returns the table's lines and the provenance sentence of the kept rows ("" when
    none were kept).
    """
    path = pathlib.Path(path)
    new = [_row_line(r) for r in rows]
    if not path.exists():
        return new, ""
    old_text = path.read_text().splitlines()
    names = {r.name for r in rows}
    lines, kept, placed = [], 0, False
    for line in _first_table(old_text):
        if line in TABLE_HEAD or line.startswith("|---"):
            continue
        if line.split(" | ")[0][2:] in names:
            if not placed:
                lines += new
                placed = True
        else:
            lines.append(line)
            kept += 1
    if not placed:
        lines += new
    if not kept:
        return lines, ""
    source = _paragraph(old_text, (CARRIED_PREFIX, "Rows other than"))
    if source is None:
        date = next((t.split(": ", 1)[1] for t in old_text if t.startswith("- date")), "?")
        run = next((t.split(": ", 1)[1] for t in old_text if t.startswith("- run:")), "?")
        source = f"{CARRIED_PREFIX} the run of {date} ({run}, same file)."
    return lines, source


def _first_table(lines):
    """The lines of the first table after the "## Results" heading."""
    start = next((i for i, t in enumerate(lines) if t.strip() == "## Results"), len(lines))
    out = []
    for t in lines[start + 1:]:
        if t.startswith("|"):
            out.append(t)
        elif out or t.startswith("#"):
            break
    return out


def _paragraph(lines, prefixes):
    """The paragraph (joined lines up to a blank one) starting with one of ``prefixes``."""
    for i, t in enumerate(lines):
        if t.startswith(prefixes):
            end = next((j for j in range(i, len(lines)) if not lines[j].strip()), len(lines))
            return " ".join(lines[i:end])
    return None


LOAD_NOTE = [
    "The machine is shared: other jobs on its 2 cores slow every row, the sampler rows",
    "(seconds to minutes of numpy work) most. A load average of 2 at the end can mean up",
    "to ~2x longer wall times than on a quiet machine; the ratios of rows timed one after",
    "the other in the same run move much less. Read the load line below before comparing",
    "a wall time with its target.",
]


#: heading of the hand-written profile section, carried over verbatim by every run
PROFILE_HEADING = "## Where the time goes"


def hand_written(path, heading=PROFILE_HEADING):
    """The lines of ``heading``'s section of an earlier ``path`` (up to the next ``## ``
    heading), or [] : a section written by hand (profiles) that the writer keeps."""
    path = pathlib.Path(path)
    if not path.exists():
        return []
    lines = path.read_text().splitlines()
    if heading not in lines:
        return []
    start = lines.index(heading)
    end = next((i for i in range(start + 1, len(lines)) if lines[i].startswith("## ")),
               len(lines))
    return lines[start:end]


def write_markdown(path, rows, facts, args, *, carried=False):
    """Write docs/performance.md; ``carried`` keeps the other benchmarks' rows of the
    earlier file (for an ``--only`` run). The hand-written profile section
    (:data:`PROFILE_HEADING`) of the earlier file is always kept."""
    profile = hand_written(path)
    lines, source = carry_over(path, rows) if carried else ([_row_line(r) for r in rows], "")
    text = [
        "# Performance",
        "",
        "Written by `studies/benchmark.py` (`make bench`); do not edit by hand, except the",
        f"section \"{PROFILE_HEADING[3:]}\", which the script keeps. Each time is the",
        "median over repeats of one call. The speed-up is measured against a baseline timed in",
        "the same run (a plain Python loop doing the same work, or the naive method the package",
        "replaces), so it is comparable across runs",
        "on this shared, noisy machine; the absolute times are not. The two timings of a pair",
        "are still taken one after the other, so ratios move between runs (by up to ~2x for",
        "the sub-millisecond rows): read them as orders of magnitude. Rows whose notes say",
        "\"one run\" or give a wall time were timed once (they take seconds to minutes); the",
        "sampler rows give the time per 1000 effective samples (min over parameters), the",
        "median over sampler seeds 0, 1, 2 (one seed at N >= 5000).",
        "",
        *LOAD_NOTE,
        "",
        "## Machine",
        "",
        *[f"- {k}: {v}" for k, v in facts.items()],
        f"- run: `{' '.join(['python studies/benchmark.py'] + args)}`",
        "",
        "## Results",
        "",
        *([source, ""] if source else []),
        *TABLE_HEAD,
        *lines,
        "",
        *profile,
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
                        help="also time the sampler once at this N in a child process, "
                        "a row of the targets benchmark (make bench: 20000, minutes; "
                        "0 = skipped)")
    args = parser.parse_args(argv)
    global LARGE_N
    LARGE_N = args.large_n
    timer = Timer(repeats=3, min_time=0.01) if args.quick else Timer()
    rows = []
    for name in args.only or BENCHMARKS:
        rows += BENCHMARKS[name](timer)
    print(table(rows))
    write_markdown(args.out, rows, machine_facts(), argv, carried=bool(args.only))
    print(f"wrote {args.out}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
