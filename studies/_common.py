"""Shared machinery of the paper-reproduction studies (fig7, fig8, fig9, identifiability, design).

* the shared study runner of :mod:`bayescal.cli.studyrun` (``parse_args``,
  ``executor``, ``run_trials``, ``study_main``), re-exported;
* :func:`sensor_for_trial`, :func:`three_methods`: one trial of the paper's
  comparison (sequential, simultaneous, Bayesian posterior mean);
* :func:`run_room_study`: fig7 and fig8 are this function with two room sizes.

Imports only the public API of bayescal (and ``bayescal.plotting``).
"""

from __future__ import annotations

import numpy as np

import bayescal as bc
import bayescal.io.data

__all__ = ["parse_args", "executor", "run_trials", "OutputDir", "write_json", "to_jsonable",
           "sensor_for_trial", "three_methods", "bayes_settings", "scene_sigma",
           "run_room_study", "room_trial", "point_errors", "MODES", "SCENE_FLOOR_MM"]

MODES = ("full", "quick", "smoke")
#: floor (mm) of the scene standard deviation given to the calibrations: simulate_room
#: reports 0 where a point carries no error, which a likelihood cannot take
SCENE_FLOOR_MM = 1.0
#: perturbation of the true sensor per trial, in units of the default prior's sd
PERTURB_SCALE = 0.5


# the runner (command line, executors, seeded trials, output folder) is bayescal's own
from bayescal.cli.studyrun import (  # noqa: E402,F401  (re-exported for the study scripts)
    OutputDir,
    executor,
    parse_args,
    run_trials,
    study_main,
    write_json,
)


def to_jsonable(obj):
    """Convert numpy scalars/arrays to JSON types; NaN and infinities become None."""
    return bayescal.io.data.to_jsonable(obj, nonfinite="null")


# --------------------------------------------------------------------------- one trial
def sensor_for_trial(rng, *, scale=PERTURB_SCALE):
    """The paper's sensor perturbed by ``scale`` x the default prior's sd, per parameter.

    Returns
    -------
    SensorParams
    """
    prior = bc.default_prior()
    a = bc.SensorParams.paper().to_array()
    sd = np.array([prior[n].std() for n in bc.PARAM_NAMES])
    return bc.SensorParams.from_array(a + scale * sd * rng.standard_normal(8))


def scene_sigma(dataset):
    """``dataset.sigma_scene`` floored at :data:`SCENE_FLOOR_MM` (``inf`` kept)."""
    return np.maximum(dataset.sigma_scene, SCENE_FLOOR_MM)


def bayes_settings(mode):
    """Sampler targets per mode (keyword arguments of ``bc.sample_posterior``)."""
    return {
        "full": {"min_ess": 400, "n_samples": 500, "max_steps": 8000, "n_tune": 150},
        "quick": {"min_ess": 150, "n_samples": 200, "max_steps": 600, "n_tune": 100},
        "smoke": {"min_ess": 40, "n_samples": 40, "max_steps": 120, "n_tune": 30,
                  "n_walkers": 16},
    }[mode]


def point_errors(points, truth):
    """Mean and median distance (mm) and the number of invalid (NaN) points."""
    if points is None:
        return float("nan"), float("nan"), None
    d = bc.reconstruction_errors(points, truth)
    bad = int(np.isnan(d).sum())
    if bad == d.size:
        return float("nan"), float("nan"), bad
    return float(np.nanmean(d)), float(np.nanmedian(d)), bad


def three_methods(ds, rng, *, bayes):
    """Sequential, simultaneous and Bayesian reconstruction errors on one dataset.

    Parameters
    ----------
    ds : bc.Dataset
    rng : numpy.random.Generator
        Randomness of the sampler.
    bayes : dict or None
        Keyword arguments of ``bc.sample_posterior`` (None skips it).

    Returns
    -------
    dict
        ``sequential_mm`` (its parameters triangulating the room pixels),
        ``simultaneous_mm`` (its jointly estimated points),
        ``simultaneous_triangulated_mm`` (its parameters triangulating the room
        pixels, comparable with the sequential number), ``bayes_mm`` (posterior
        mean points), ``approx_mm`` (the approximate points themselves), the
        medians, invalid counts, failures and sampler diagnostics.
    """
    out = {}
    sig = scene_sigma(ds)
    try:
        seq = bc.calibrate_sequential(ds)
        seq_pts, out["sequential_failed"] = seq.points, None
        out["sequential_params"] = seq.params.to_array()
    except bc.ConvergenceError as exc:
        seq_pts, out["sequential_failed"] = None, str(exc)
    out["sequential_mm"], out["sequential_median_mm"], out["sequential_invalid"] = \
        point_errors(seq_pts, ds.points)
    try:
        sim = bc.calibrate_simultaneous(ds.pixels, ds.approx_points, sigma_px=ds.sigma_px or 0.1,
                                        sigma_scene=sig)
        sim_pts, out["simultaneous_failed"] = sim.points, None
        tri = bc.triangulate(sim.params, ds.pixels)
        out["simultaneous_params"] = sim.params.to_array()
    except bc.ConvergenceError as exc:
        sim_pts, tri, out["simultaneous_failed"] = None, None, str(exc)
    out["simultaneous_mm"], out["simultaneous_median_mm"], _ = point_errors(sim_pts, ds.points)
    (out["simultaneous_triangulated_mm"], out["simultaneous_triangulated_median_mm"],
     out["simultaneous_triangulated_invalid"]) = point_errors(tri, ds.points)
    out["approx_mm"], _, _ = point_errors(ds.approx_points, ds.points)
    out["bayes_mm"] = out["bayes_median_mm"] = float("nan")
    out["bayes_failed"] = None
    if bayes is not None:
        try:
            post = bc.sample_posterior(ds.pixels, ds.approx_points, sigma_px=ds.sigma_px or 0.1,
                                       sigma_scene=sig, rng=rng, progress=False,
                                       **bayes)
            out["bayes_mm"], out["bayes_median_mm"], _ = point_errors(post.point_mean, ds.points)
            out["bayes_converged"] = bool(post.converged)
            out["bayes_tau_max"] = float(np.max(post.tau))
            out["bayes_steps"] = int(post.n_steps)
            out["bayes_map_mm"], _, _ = point_errors(post.map_points, ds.points)
        except Exception as exc:  # noqa: BLE001 (a failed chain is a result, recorded)
            out["bayes_failed"] = f"{type(exc).__name__}: {exc}"
            out["bayes_converged"] = False
    return out


# --------------------------------------------------------------------------- fig7 / fig8
#: the eight trials of Figs. 7 and 8: pixel noise (px), 3D noise (fraction of the range)
ROOM_TRIALS = [(0.1, 0.002), (0.25, 0.002), (0.5, 0.002), (1.0, 0.002),
               (0.1, 0.005), (0.25, 0.005), (0.5, 0.005), (1.0, 0.005)]


def room_trial(spec, rng):
    """One trial of Fig. 7/8: perturbed sensor, noisy pixels and 3D points, three methods."""
    r_par, r_sim, r_bay = (np.random.default_rng(s)
                           for s in np.random.SeedSequence(rng.integers(2**63)).spawn(3))
    params = sensor_for_trial(r_par)
    ds = bc.simulate_room(params, range_mm=spec["range_mm"], n_points=spec["n_points"],
                          sigma_px=spec["sigma_px"], sigma_3d=spec["sigma_3d"],
                          approx_error=0.0, approx_model="gaussian", rng=r_sim)
    out = {"trial": spec["trial"], "sigma_px": spec["sigma_px"], "sigma_3d": spec["sigma_3d"],
           "true_params": params.to_array()}
    out.update(three_methods(ds, r_bay, bayes=spec["bayes"]))
    return out


def room_specs(range_mm, mode):
    """Trial specifications of Fig. 7/8 for a mode."""
    trials = ROOM_TRIALS if mode == "full" else (ROOM_TRIALS[::2] if mode == "quick"
                                                  else ROOM_TRIALS[2:3])
    n_points = 60 if mode == "smoke" else 580
    return [{"trial": k, "range_mm": float(range_mm), "n_points": n_points,
             "sigma_px": spx, "sigma_3d": rel * range_mm, "bayes": bayes_settings(mode)}
            for k, (spx, rel) in enumerate(trials)]


METHODS = (("sequential_mm", "sequential", "tab:orange"),
           ("simultaneous_mm", "simultaneous (joint points)", "tab:blue"),
           ("bayes_mm", "Bayesian posterior mean", "tab:green"),
           ("simultaneous_triangulated_mm", "simultaneous params, triangulated", "lightsteelblue"))


def plot_room_bars(trials, title, path):
    """Grouped bar plot of the reconstruction errors per trial (log scale)."""
    import matplotlib

    matplotlib.use("agg")
    import matplotlib.pyplot as plt

    from bayescal.plotting import savefig

    fig, ax = plt.subplots(figsize=(10, 4.5))
    x = np.arange(len(trials))
    w = 0.8 / len(METHODS)
    for k, (key, label, color) in enumerate(METHODS):
        y = np.array([np.nan if t[key] is None else t[key] for t in trials], dtype=float)
        ax.bar(x + (k - (len(METHODS) - 1) / 2) * w, y, w, label=label, color=color)
    ax.set_xticks(x, [f"{t['trial'] + 1}\n{t['sigma_px']:g} px\n{t['sigma_3d']:.3g} mm"
                      for t in trials])
    ax.set_xlabel("trial (pixel noise, 3D-point noise)")
    ax.set_ylabel("mean reconstruction error (mm)")
    ax.set_yscale("log")
    ax.grid(True, axis="y", which="both", alpha=0.3)
    ax.legend(fontsize="small")
    ax.set_title(title)
    savefig(fig, path)


def summarize(trials, keys):
    """Mean over trials of each key (NaN-aware) and the win counts simultaneous vs others."""
    arr = {k: np.array([np.nan if t.get(k) is None else t[k] for t in trials], float)
           for k in keys}
    out = {f"mean_{k}": float(np.nanmean(a)) if np.isfinite(a).any() else None
           for k, a in arr.items()}
    s, q, b = arr["simultaneous_mm"], arr["sequential_mm"], arr["bayes_mm"]
    out["simultaneous_better_than_sequential"] = int(np.sum(s < q))
    out["bayes_at_least_as_good_as_simultaneous"] = int(np.sum(b <= s * 1.0))
    out["bayes_within_2pct_of_simultaneous"] = int(np.sum(b <= s * 1.02))
    out["n_trials"] = len(trials)
    return out


def run_room_study(name, range_mm, argv):
    """Figs. 7 and 8: eight trials in a room of ``range_mm``; writes NAME.json and NAME.png."""
    files = (f"{name}.json", f"{name}.png")

    def run(args, out):
        specs = room_specs(range_mm, args.mode)
        trials = run_trials(room_trial, specs, seed=args.seed, workers=args.workers,
                            scheduler=args.scheduler)
        keys = ("sequential_mm", "simultaneous_mm", "simultaneous_triangulated_mm", "bayes_mm",
                "approx_mm")
        result = {
            "study": name, "mode": args.mode, "seed": args.seed, "range_mm": range_mm,
            "n_points": specs[0]["n_points"], "bayes_settings": specs[0]["bayes"],
            "perturb_scale_prior_sd": PERTURB_SCALE, "scene_floor_mm": SCENE_FLOOR_MM,
            "trial": [t["trial"] for t in trials],
            "sigma_px": [t["sigma_px"] for t in trials],
            "sigma_3d_mm": [t["sigma_3d"] for t in trials],
            **{k: [t[k] for t in trials] for k in keys},
            "summary": summarize(trials, keys),
            "trials": trials,
        }
        write_json(out / files[0], result)
        plot_room_bars(trials, f"{name}: reconstruction error, {range_mm:.0f} mm room, "
                               f"{specs[0]['n_points']} laser points ({args.mode})",
                       out / files[1])
        print(f"{'trial':>5} {'px':>5} {'3D mm':>6} {'seq':>9} {'sim':>8} {'bayes':>8} "
              f"{'sim-tri':>8}")
        for t in trials:
            print(f"{t['trial'] + 1:5d} {t['sigma_px']:5.2f} {t['sigma_3d']:6.1f} "
                  f"{t['sequential_mm']:9.2f} {t['simultaneous_mm']:8.2f} {t['bayes_mm']:8.2f} "
                  f"{t['simultaneous_triangulated_mm']:8.2f}")

    return study_main(run, f"{name}: sequential vs simultaneous vs Bayes, {range_mm:.0f} mm room",
                      argv, files)
