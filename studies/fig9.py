"""Fig. 9 of the paper: reconstruction error against the approximation error of the 3D points.

The large room (5000 mm, 580 laser points). The 3D points are not measured but
approximated from the scene structure (``approx_model="fig9"``): x and y each
carry a relative error ``approx_error`` (0 to 5 %), z follows from them and
the *nominal* cone. The sequential method's calibration patterns carry the same
relative error (``simulate_room`` does that). Each trial draws its own sensor
(the paper's perturbed by half the default prior's sd) and noise; the pixel
noise is ``--sigma-px`` (default 0.1 px) for every trial.

Writes ``fig9.json`` (keys ``approx_error_percent``, ``sequential_mm``,
``simultaneous_mm``, ``bayes_mm``: means over the trials of each level, plus
their standard deviations, the triangulated-simultaneous and approximate-point
errors, and every trial) and ``fig9.png`` into ``--out``. See
``docs/studies.md``.

Usage::

    python studies/fig9.py --out out/fig9 [--quick] [--workers 2] [--scheduler ADDRESS]
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
    run_trials,
    sensor_for_trial,
    study_main,
    three_methods,
    write_json,
)

import bayescal as bc  # noqa: E402

__all__ = ["main", "fig9_trial", "LEVELS", "RANGE_MM"]

RANGE_MM = 5000.0
FILES = ("fig9.json", "fig9.png")
#: approximation error levels (%) and trials per level, per mode
LEVELS = {"full": (np.arange(0.0, 5.01, 1.0), 4),
          "quick": (np.array([0.0, 2.5, 5.0]), 1),
          "smoke": (np.array([0.0, 5.0]), 1)}
KEYS = ("sequential_mm", "simultaneous_mm", "bayes_mm", "simultaneous_triangulated_mm",
        "approx_mm")


def fig9_trial(spec, rng):
    """One trial: perturbed sensor, approximate points at one error level, three methods."""
    r_par, r_sim, r_bay = (np.random.default_rng(s)
                           for s in np.random.SeedSequence(rng.integers(2**63)).spawn(3))
    params = sensor_for_trial(r_par)
    ds = bc.simulate_room(params, range_mm=RANGE_MM, n_points=spec["n_points"],
                          sigma_px=spec["sigma_px"], approx_error=spec["approx_error"],
                          approx_model="fig9", rng=r_sim)
    out = {"level": spec["level"], "approx_error_percent": 100 * spec["approx_error"],
           "true_params": params.to_array()}
    out.update(three_methods(ds, r_bay, bayes=spec["bayes"]))
    return out


def _specs(mode, sigma_px):
    levels, n_rep = LEVELS[mode]
    n_points = 60 if mode == "smoke" else 580
    return [{"level": i, "approx_error": float(lv) / 100, "n_points": n_points,
             "sigma_px": sigma_px, "bayes": bayes_settings(mode)}
            for i, lv in enumerate(levels) for _ in range(n_rep)]


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
              ("approx_mm", "approximate points themselves", "grey", "x--"))
    for key, label, color, fmt in styles:
        ax.errorbar(levels, table[key], yerr=table[key.replace("_mm", "_sd_mm")], fmt=fmt,
                    color=color, label=label, capsize=3)
    ax.set_xlabel("approximation error of the 3D points (%)")
    ax.set_ylabel("mean reconstruction error (mm)")
    ax.grid(True, alpha=0.3)
    ax.legend(fontsize="small")
    ax.set_title(title)
    savefig(fig, path)


def _add_arguments(parser):
    parser.add_argument("--sigma-px", type=float, default=0.1,
                        help="pixel noise of every trial, px (default: 0.1)")


def run(args, out):
    specs = _specs(args.mode, args.sigma_px)
    levels = LEVELS[args.mode][0]
    trials = run_trials(fig9_trial, specs, seed=args.seed, workers=args.workers,
                        scheduler=args.scheduler)
    table = _table(trials, len(levels))
    result = {"study": "fig9", "mode": args.mode, "seed": args.seed, "range_mm": RANGE_MM,
              "n_points": specs[0]["n_points"], "sigma_px": args.sigma_px,
              "trials_per_level": LEVELS[args.mode][1], "bayes_settings": specs[0]["bayes"],
              "perturb_scale_prior_sd": PERTURB_SCALE, "scene_floor_mm": SCENE_FLOOR_MM,
              "approx_error_percent": levels, **table,
              "bayes_unconverged": [sum(not t.get("bayes_converged", False) for t in trials
                                        if t["level"] == lv) for lv in range(len(levels))],
              "trials": trials}
    write_json(out / FILES[0], result)
    plot(levels, table, f"fig9: {RANGE_MM:.0f} mm room, {specs[0]['n_points']} points, "
                        f"{args.sigma_px:g} px ({args.mode})", out / FILES[1])
    print(f"{'approx %':>8} {'seq':>9} {'sim':>8} {'bayes':>8} {'sim-tri':>8} {'approx':>8}")
    for i, lv in enumerate(levels):
        print(f"{lv:8.1f} " + " ".join(f"{table[k][i]:8.1f}" for k in KEYS))


def main(argv=None):
    """Run the study; returns the exit code."""
    return study_main(run, "fig9: reconstruction error against approximation error", argv,
                      FILES, add_arguments=_add_arguments)


if __name__ == "__main__":
    raise SystemExit(main())
