"""Fig. 9 of the paper: reconstruction error against the approximation error of the 3D points.

The large room (5000 mm, 580 laser points). The 3D points are not measured but
approximated from the scene structure (``approx_model="fig9"``): x and y each
carry a relative error ``approx_error`` (0 to 5 %), z follows from them and
the *nominal* cone. The sequential method's calibration patterns carry the same
relative error (``simulate_room`` does that). Each trial draws its own sensor
(the paper's perturbed by half the default prior's sd) and noise; the pixel
noise is ``--sigma-px`` (default 0.1 px) for every trial.

The floor-plan column calibrates the same pixels from the room's rough floor plan
(``ds.floor_plan``) in place of approximate points, by least squares
(``bc.calibrate_simultaneous(pixels, plan, ...)``). The plan is measured with the
same relative error: each wall's distance off by one draw of
``approx_error * d_k`` and its orientation by one draw of ``approx_error`` rad
(both floored at 0.1 %), which moves a wall end at lateral offset ``s`` by about
``approx_error * s``, i.e. the same relative error for ``s`` comparable with ``d_k``.
The floor-plan posterior mean (``bc.sample_posterior(pixels, plan, ...)``) is a column
too (``--skip-plan-bayes`` drops it, ``--skip-bayes`` drops both posteriors).

Writes ``fig9.json`` (keys ``approx_error_percent``, ``sequential_mm``,
``simultaneous_mm``, ``bayes_mm``, ``plan_mm``, ``plan_bayes_mm``: means over
the trials of each level, plus their standard deviations, the
triangulated-simultaneous and approximate-point errors, and every trial) and
``fig9.png`` into ``--out``. See ``docs/studies.md``.

Usage::

    python studies/fig9.py --out out/fig9 [--quick] [--skip-plan-bayes] [--workers 2]
                           [--scheduler ADDRESS]
"""

from __future__ import annotations

import pathlib
import sys

import numpy as np

sys.path.insert(0, str(pathlib.Path(__file__).resolve().parent))

from _common import (  # noqa: E402
    PERTURB_SCALE,
    SCENE_FLOOR_MM,
    bayes_settings,
    point_errors,
    run_trials,
    sensor_for_trial,
    study_main,
    three_methods,
    write_json,
)

import bayescal as bc  # noqa: E402

__all__ = ["main", "fig9_trial", "plan_columns", "plan_angle_sd", "LEVELS", "RANGE_MM"]

RANGE_MM = 5000.0
FILES = ("fig9.json", "fig9.png")
#: approximation error levels (%) and trials per level, per mode
LEVELS = {"full": (np.arange(0.0, 5.01, 1.0), 4),
          "quick": (np.array([0.0, 2.5, 5.0]), 4),
          "smoke": (np.array([0.0, 5.0]), 1)}
KEYS = ("sequential_mm", "simultaneous_mm", "bayes_mm", "simultaneous_triangulated_mm",
        "approx_mm", "plan_mm", "plan_triangulated_mm", "plan_bayes_mm")
#: chain length limit of the floor-plan posterior (per mode; the per-point one's if larger)
PLAN_MAX_STEPS = {"full": 12000, "quick": 12000}
#: floor of the plan's relative distance error and angle sd (rad) at 0 % approximation error
PLAN_FLOOR = 1e-3


def plan_angle_sd(approx_error, fixed=None):
    """The plan's orientation sd (rad): ``fixed`` if given, else the relative error, floored."""
    return float(fixed) if fixed is not None else max(float(approx_error), PLAN_FLOOR)


def fig9_trial(spec, rng):
    """One trial: perturbed sensor, approximate points at one error level, three methods."""
    # spawn(4): the first three children are those of spawn(3), so the per-point columns
    # are unchanged by the floor-plan one
    r_par, r_sim, r_bay, r_plan = (np.random.default_rng(s) for s in
                                   np.random.SeedSequence(rng.integers(2**63)).spawn(4))
    params = sensor_for_trial(r_par)
    ds = bc.simulate_room(params, range_mm=RANGE_MM, n_points=spec["n_points"],
                          sigma_px=spec["sigma_px"], approx_error=spec["approx_error"],
                          approx_model="fig9",
                          plan_angle_sd=plan_angle_sd(spec["approx_error"],
                                                      spec.get("plan_angle_sd")),
                          rng=r_sim)
    out = {"level": spec["level"], "approx_error_percent": 100 * spec["approx_error"],
           "true_params": params.to_array()}
    out.update(three_methods(ds, r_bay, bayes=spec["bayes"]))
    out.update(plan_columns(ds, r_plan, bayes=spec.get("plan_bayes")))
    return out


def plan_columns(ds, rng, *, bayes):
    """Floor-plan reconstruction errors on one dataset (least squares; posterior if asked).

    Parameters
    ----------
    ds : bc.Dataset
        With ``ds.floor_plan`` (None when no plan could be drawn: recorded as a failure).
    rng : numpy.random.Generator
        Randomness of the sampler.
    bayes : dict or None
        Keyword arguments of ``bc.sample_posterior`` for the floor-plan posterior; None
        skips it.

    Returns
    -------
    dict
        ``plan_mm`` (least-squares points), ``plan_triangulated_mm`` (its parameters
        triangulating the pixels), ``plan_bayes_mm`` (posterior mean points; NaN when
        skipped), the medians, failures and sampler diagnostics.
    """
    out = {"plan_failed": None, "plan_bayes_failed": None}
    pts = tri = None
    sigma_px = ds.sigma_px or 0.1
    if ds.floor_plan is None:
        out["plan_failed"] = "simulate_room could not draw a valid rough plan"
    else:
        try:
            res = bc.calibrate_simultaneous(ds.pixels, ds.floor_plan, sigma_px=sigma_px)
            pts, tri = res.points, bc.triangulate(res.params, ds.pixels)
            out["plan_params"] = res.params.to_array()
        except bc.ConvergenceError as exc:
            out["plan_failed"] = str(exc)
    out["plan_mm"], out["plan_median_mm"], _ = point_errors(pts, ds.points)
    out["plan_triangulated_mm"], _, _ = point_errors(tri, ds.points)
    out["plan_bayes_mm"] = out["plan_bayes_median_mm"] = float("nan")
    if bayes is not None and ds.floor_plan is not None:
        try:
            post = bc.sample_posterior(ds.pixels, ds.floor_plan, sigma_px=sigma_px, rng=rng,
                                       progress=False, **bayes)
            out["plan_bayes_mm"], out["plan_bayes_median_mm"], _ = point_errors(post.point_mean,
                                                                        ds.points)
            out["plan_bayes_converged"] = bool(post.converged)
            out["plan_bayes_tau_max"] = float(np.max(post.tau))
            out["plan_bayes_steps"] = int(post.n_steps)
            out["plan_bayes_map_mm"], _, _ = point_errors(post.map_points, ds.points)
        except Exception as exc:  # noqa: BLE001 (a failed chain is a result, recorded)
            out["plan_bayes_failed"] = f"{type(exc).__name__}: {exc}"
            out["plan_bayes_converged"] = False
    return out


def _specs(mode, sigma_px, *, plan_bayes=False, skip_bayes=False, plan_angle=None):
    levels, n_rep = LEVELS[mode]
    n_points = 60 if mode == "smoke" else 580
    bayes = None if skip_bayes else bayes_settings(mode)
    # the floor-plan posterior has 2 more dimensions per wall (its default ensemble size) and
    # mixes slower (max tau 7-40 steps at 0-2.5 %, ~100 at 5 %: docs/studies.md), so longer
    # chains than the per-point one outside the smoke mode
    plan = {k: v for k, v in bayes_settings(mode).items() if k != "n_walkers"}
    plan["max_steps"] = max(plan["max_steps"], PLAN_MAX_STEPS.get(mode, 0))
    return [{"level": i, "approx_error": float(lv) / 100, "n_points": n_points,
             "sigma_px": sigma_px, "bayes": bayes,
             "plan_bayes": plan if plan_bayes and not skip_bayes else None,
             "plan_angle_sd": plan_angle}
            for i, lv in enumerate(levels) for _ in range(n_rep)]


def _unconverged(trials, prefix, n_levels):
    """Per level: chains of ``prefix`` ("bayes" or "plan_bayes") run and not converged."""
    return [sum(f"{prefix}_converged" in t and not t[f"{prefix}_converged"] for t in trials
                if t["level"] == lv) for lv in range(n_levels)]


def _table(trials, n_levels):
    """Per level: mean and sd over trials of each error (NaN-aware)."""
    out = {}
    for key in KEYS:
        m, s, n = [], [], []
        for lv in range(n_levels):
            a = np.array([np.nan if t[key] is None else t[key] for t in trials
                          if t["level"] == lv], float)
            ok = a[np.isfinite(a)]
            m.append(float(ok.mean()) if ok.size else float("nan"))
            s.append(float(ok.std(ddof=1)) if ok.size > 1 else float("nan"))
            n.append(int(ok.size))
        out[key], out[key.replace("_mm", "_sd_mm")], out[key.replace("_mm", "_n")] = m, s, n
    return out


def plot(levels, table, title, path):
    import matplotlib

    matplotlib.use("agg")
    import matplotlib.pyplot as plt

    from bayescal.plotting import savefig

    fig, ax = plt.subplots(figsize=(7.5, 4.8))
    styles = (("sequential_mm", "sequential", "tab:orange", "o-"),
              ("simultaneous_mm", "simultaneous (joint points)", "tab:blue", "s-"),
              ("bayes_mm", "Bayesian posterior mean", "tab:green", "^-"),
              ("simultaneous_triangulated_mm", "simultaneous params, triangulated",
               "steelblue", "s:"),
              ("approx_mm", "approximate points themselves", "grey", "x--"),
              ("plan_mm", "floor plan, least squares", "tab:purple", "D-"),
              ("plan_bayes_mm", "floor plan, posterior mean", "tab:red", "v-"))
    for key, label, color, fmt in styles:
        if not np.any(np.isfinite(table[key])):
            continue                                  # a column not run (--skip-bayes)
        ax.errorbar(levels, table[key], yerr=table[key.replace("_mm", "_sd_mm")], fmt=fmt,
                    color=color, label=label, capsize=3)
    ax.set_xlabel("approximation error of the 3D points / of the floor plan (%)")
    ax.set_ylabel("mean reconstruction error (mm)")
    ax.grid(True, alpha=0.3)
    ax.legend(fontsize="small")
    ax.set_title(title)
    savefig(fig, path)


def _add_arguments(parser):
    parser.add_argument("--sigma-px", type=float, default=0.1,
                        help="pixel noise of every trial, px (default: 0.1)")
    parser.add_argument("--skip-plan-bayes", action="store_true",
                        help="skip the floor-plan posterior (sampled by default)")
    parser.add_argument("--skip-bayes", action="store_true",
                        help="skip both posteriors (least-squares columns only)")
    parser.add_argument("--plan-angle-sd", type=float, default=None, metavar="RAD",
                        help="sd of the plan's wall orientations, rad (default: the relative "
                             "approximation error of the level, floored at 0.001)")


def run(args, out):
    if args.plan_angle_sd is not None and not args.plan_angle_sd > 0:
        raise SystemExit(f"error: --plan-angle-sd must be > 0, got {args.plan_angle_sd}")
    specs = _specs(args.mode, args.sigma_px,
                   plan_bayes=not (args.skip_plan_bayes or args.skip_bayes),
                   skip_bayes=args.skip_bayes, plan_angle=args.plan_angle_sd)
    levels = LEVELS[args.mode][0]
    trials = run_trials(fig9_trial, specs, seed=args.seed, workers=args.workers,
                        scheduler=args.scheduler)
    table = _table(trials, len(levels))
    result = {"study": "fig9", "mode": args.mode, "seed": args.seed, "range_mm": RANGE_MM,
              "n_points": specs[0]["n_points"], "sigma_px": args.sigma_px,
              "trials_per_level": LEVELS[args.mode][1], "bayes_settings": specs[0]["bayes"],
              "plan_bayes_settings": specs[0]["plan_bayes"],
              "perturb_scale_prior_sd": PERTURB_SCALE, "scene_floor_mm": SCENE_FLOOR_MM,
              "plan_error": "distance sd approx_error * d_k, angle sd "
                            + (f"{args.plan_angle_sd:g} rad" if args.plan_angle_sd else
                               "approx_error rad") + f", floored at {PLAN_FLOOR:g}",
              "plan_bayes": specs[0]["plan_bayes"] is not None,
              "skip_bayes": bool(args.skip_bayes),
              "approx_error_percent": levels, **table,
              "bayes_unconverged": _unconverged(trials, "bayes", len(levels)),
              "plan_bayes_unconverged": _unconverged(trials, "plan_bayes", len(levels)),
              "trials": trials}
    write_json(out / FILES[0], result)
    plot(levels, table, f"fig9: {RANGE_MM:.0f} mm room, {specs[0]['n_points']} points, "
                        f"{args.sigma_px:g} px ({args.mode})", out / FILES[1])
    print(f"{'approx %':>8} {'seq':>8} {'sim':>8} {'bayes':>8} {'sim-tri':>8} {'approx':>8} "
          f"{'plan':>8} {'plan-tri':>8} {'plan-bay':>8}  unconverged (bayes, plan-bayes)")
    for i, lv in enumerate(levels):
        print(f"{lv:8.1f} " + " ".join(f"{table[k][i]:8.1f}" for k in KEYS)
              + f"  {result['bayes_unconverged'][i]}, {result['plan_bayes_unconverged'][i]}")
    failed = [t["plan_bayes_failed"] for t in trials if t.get("plan_bayes_failed")]
    if failed:
        print(f"floor-plan posterior failed in {len(failed)} of {len(trials)} trials: "
              f"{failed[0]}")


def main(argv=None):
    """Run the study; returns the exit code."""
    return study_main(run, "fig9: reconstruction error against approximation error", argv,
                      FILES, add_arguments=_add_arguments)


if __name__ == "__main__":
    raise SystemExit(main())
