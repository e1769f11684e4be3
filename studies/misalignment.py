"""Misalignment study: a tilted or offset laser cone fitted with both laser models.

Sensors whose laser cone is tilted 0, 0.25, 0.5, 1 and 2 degrees (in a direction drawn
per replication), tilted (2, 1) deg with the apex 10 mm off the axis, and offset 5 or
10 mm alone, each in a 2500 mm room of 6 walls (300 laser points, 0.2 px, approximate
x, y +-3 %, z unknown: ``approx_model="fig9"``), the true sensor drawn 0.5 prior sd off
the design values per replication. Every data set is fitted by least squares with the
aligned and the misaligned model (noise levels given), and judged on:

* the z-scores ``(estimate - truth) / sd`` of the 7 identifiable parameters (and of the
  4 pose numbers for the misaligned model): their rms per parameter (1 for honest
  error bars) and the coverage of the 90 % intervals;
* the held-out 3D error: a second room drawn with the same sensor (new walls, new
  noise), its pixels triangulated with each fit (``laser=`` its pose), mean distance to
  the true points; the same with the true sensor is the floor pixel noise leaves;
* the model check of the aligned fit (``result.model_check()``): how often it fails
  (all statistics) and how often its ring-harmonic statistic alone does;
* ``bc.compare_models``: how often it prefers the misaligned model, and the held-out
  error of the model it prefers (what ``bayescal calibrate --model auto`` would use).

Writes into ``--out``:

* ``misalignment.json``: settings, per-scenario summary and every replication;
* ``misalignment.png``: z-score rms of u0, v0 and held-out error against the tilt,
  both models, and the detection / preference rates;
* ``misalignment.md``: the summary tables in Markdown.

Usage::

    python studies/misalignment.py --out out/misalignment [--quick]
"""

from __future__ import annotations

import pathlib
import sys

import numpy as np

sys.path.insert(0, str(pathlib.Path(__file__).resolve().parent))

from _common import (  # noqa: E402
    run_trials,
    scene_sigma,
    sensor_for_trial,
    study_main,
    write_json,
)

import bayescal as bc  # noqa: E402

__all__ = ["main", "misalignment_trial", "SCENARIOS", "summarize", "markdown_tables"]

FILES = ("misalignment.json", "misalignment.png", "misalignment.md")
MODELS = ("aligned", "misaligned")
#: name, tilt magnitude (deg; its direction drawn per replication, or fixed by
#: ``tilt_deg``), fixed tilt (deg) or None, offset (mm)
SCENARIOS = (
    {"name": "aligned", "tilt": 0.0, "tilt_deg": None, "offset": (0.0, 0.0)},
    {"name": "tilt 0.25 deg", "tilt": 0.25, "tilt_deg": None, "offset": (0.0, 0.0)},
    {"name": "tilt 0.5 deg", "tilt": 0.5, "tilt_deg": None, "offset": (0.0, 0.0)},
    {"name": "tilt 1 deg", "tilt": 1.0, "tilt_deg": None, "offset": (0.0, 0.0)},
    {"name": "tilt 2 deg", "tilt": 2.0, "tilt_deg": None, "offset": (0.0, 0.0)},
    {"name": "tilt (2, 1) deg + offset (10, 0) mm", "tilt": float(np.hypot(2, 1)),
     "tilt_deg": (2.0, 1.0), "offset": (10.0, 0.0)},
    {"name": "offset (5, 0) mm", "tilt": 0.0, "tilt_deg": None, "offset": (5.0, 0.0)},
    {"name": "offset (0, 10) mm", "tilt": 0.0, "tilt_deg": None, "offset": (0.0, 10.0)},
)
#: the tilt series of the figure (scenario names, in order of tilt)
TILT_SERIES = ("aligned", "tilt 0.25 deg", "tilt 0.5 deg", "tilt 1 deg", "tilt 2 deg")
ROOM = {"range_mm": 2500.0, "n_walls": 6, "sigma_px": 0.2, "approx_error": 0.03,
        "approx_model": "fig9"}
REPLICATIONS = {"full": 30, "quick": 5, "smoke": 1}
N_POINTS = {"full": 300, "quick": 300, "smoke": 100}
Z90 = 1.6448536269514722


def _room(params, spec, rng, tilt):
    return bc.simulate_room(params, n_points=spec["n_points"], tilt=tilt,
                            offset=spec["offset"], rng=rng, **ROOM)


def _tilt(spec, rng):
    """The tilt (tilt_x, tilt_y) in rad: fixed, or ``spec['tilt']`` deg in a random direction."""
    if spec["tilt_deg"] is not None:
        return tuple(np.radians(spec["tilt_deg"]))
    az = rng.uniform(0.0, 2 * np.pi)
    return tuple(np.radians(spec["tilt"]) * np.array([np.cos(az), np.sin(az)]))


def _fit(ds, model):
    """Least squares of one model: ``(result, None)``, or ``(flagged result or None, message)``
    when it is not converged (a misfit the fit's own trust checks refuse: a detection)."""
    try:
        return bc.calibrate_simultaneous(ds.pixels, ds.approx_points, sigma_px=ROOM["sigma_px"],
                                         sigma_scene=scene_sigma(ds), model=model), None
    except bc.ConvergenceError as exc:
        return exc.result, str(exc)


def _judge(res, ds, held):
    """z-scores (11, NaN for the aligned model's pose) and the held-out error (mm)."""
    truth = np.concatenate([ds.params.to_identifiable(), ds.laser.to_array()])
    cov = res.covariance(identifiable=True)
    est = np.full(11, np.nan)
    sd = np.full(11, np.nan)
    est[:cov.shape[0]] = res.geometry()
    sd[:cov.shape[0]] = np.sqrt(np.diag(cov))
    laser = res.laser if res.model == "misaligned" else None
    rec = bc.triangulate(res.params, held.pixels, laser=laser)
    err = np.linalg.norm(rec - held.points, axis=1)
    return (est - truth) / sd, float(np.nanmean(err)), int(np.isnan(err).sum())


def misalignment_trial(spec, rng):
    """One replication: simulate, fit both models, check, compare, reconstruct held out."""
    r_par, r_tilt, r_sim, r_held = (np.random.default_rng(s) for s in
                                    np.random.SeedSequence(rng.integers(2**63)).spawn(4))
    params = sensor_for_trial(r_par)
    tilt = _tilt(spec, r_tilt)
    ds, held = _room(params, spec, r_sim, tilt), _room(params, spec, r_held, tilt)
    true_rec = bc.triangulate(params, held.pixels, laser=held.laser)
    out = {"scenario": spec["name"], "rep": spec["rep"], "true_pose": ds.laser.to_array(),
           "true_params": params.to_array(),
           "truth_heldout_mm": float(np.nanmean(np.linalg.norm(true_rec - held.points, axis=1)))}
    fits = {}
    for m in MODELS:
        fits[m], out[f"{m}_failed"] = _fit(ds, m)
        out[f"{m}_converged"] = out[f"{m}_failed"] is None
        if fits[m] is None:
            continue
        z, err, bad = _judge(fits[m], ds, held)
        out[f"{m}_z"], out[f"{m}_heldout_mm"], out[f"{m}_heldout_invalid"] = z, err, bad
        out[f"{m}_log_evidence"] = float(fits[m].extras["log_evidence"])
        check = fits[m].model_check()
        out[f"{m}_check_fits"] = bool(check.fits)
        out[f"{m}_ring_p"] = float(check.p_values.get("ring_harmonic", np.nan))
    if all(fits[m] is not None for m in MODELS):      # as compare_models sees them
        cmp = bc.compare_models([fits[m] for m in MODELS])
        out["preferred"], out["decisive"] = cmp.preferred_model, bool(cmp.decisive)
        out["delta_log_evidence"] = out["misaligned_log_evidence"] - out["aligned_log_evidence"]
        # what `bayescal calibrate --model auto` uses: the preferred of the converged fits
        conv = [m for m in MODELS if out[f"{m}_converged"]]
        out["auto"] = cmp.preferred_model if len(conv) != 1 else conv[0]
        out["auto_heldout_mm"] = out[f"{out['auto']}_heldout_mm"]
    return out


def _rms(a):
    """rms over replications (axis 0), NaN where a column is all NaN (a fixed pose)."""
    import warnings

    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)
        return np.sqrt(np.nanmean(np.asarray(a, float) ** 2, axis=0))


def _scenario_summary(trials):
    """Aggregates of one scenario's replications (see the module docstring)."""
    names = list(bc.IDENTIFIABLE_NAMES) + list(bc.POSE_NAMES)
    s = {"n": len(trials), "truth_heldout_mm": float(np.mean([t["truth_heldout_mm"]
                                                               for t in trials]))}
    for m in MODELS:
        ok = [t for t in trials if f"{m}_z" in t]
        s[f"{m}_not_converged"] = int(sum(not t[f"{m}_converged"] for t in trials))
        s[f"{m}_no_result"] = len(trials) - len(ok)
        if not ok:
            continue
        z = np.array([t[f"{m}_z"] for t in ok], float)
        with np.errstate(invalid="ignore"):
            s[f"{m}_z_rms"] = dict(zip(names, _rms(z).tolist(), strict=True))
            inside = np.abs(z) < Z90
            s[f"{m}_coverage"] = dict(zip(names, np.where(np.isnan(z), np.nan, inside)
                                          .mean(axis=0).tolist(), strict=True))
        s[f"{m}_coverage_identifiable"] = float(inside[:, :7].mean())
        s[f"{m}_heldout_mm"] = float(np.mean([t[f"{m}_heldout_mm"] for t in ok]))
        s[f"{m}_check_fails"] = int(sum(not t[f"{m}_check_fits"] for t in ok))
        s[f"{m}_detected"] = int(sum(not (t[f"{m}_check_fits"] and t[f"{m}_converged"])
                                     for t in ok))
        s[f"{m}_ring_flags"] = int(sum(t[f"{m}_ring_p"] < 0.01 for t in ok))
    both = [t for t in trials if "preferred" in t]
    s["compared"] = len(both)
    s["prefers_misaligned"] = int(sum(t["preferred"] == "misaligned" for t in both))
    s["decisive"] = int(sum(t["decisive"] for t in both))
    if both:
        d = np.array([t["delta_log_evidence"] for t in both])
        s["delta_log_evidence_median"] = float(np.median(d))
        s["delta_log_evidence_range"] = [float(d.min()), float(d.max())]
        s["auto_heldout_mm"] = float(np.mean([t["auto_heldout_mm"] for t in both]))
        s["auto_misaligned"] = int(sum(t["auto"] == "misaligned" for t in both))
    return s


def summarize(trials):
    """``{scenario name: summary}`` in the order of :data:`SCENARIOS`."""
    return {sc["name"]: _scenario_summary([t for t in trials if t["scenario"] == sc["name"]])
            for sc in SCENARIOS if any(t["scenario"] == sc["name"] for t in trials)}


def _f(v, fmt=".1f"):
    return "-" if v is None or not np.isfinite(v) else format(v, fmt)


def markdown_tables(summary):
    """Two Markdown tables: z-score rms per parameter, and errors, coverage, detection."""
    par = list(bc.IDENTIFIABLE_NAMES) + list(bc.POSE_NAMES)
    head = ("| laser cone | model | " + " | ".join(par) + " |\n|---|---|"
            + "---:|" * len(par) + "\n")
    rows1, rows2 = [], []
    for name, s in summary.items():
        for m in MODELS:
            zr = s.get(f"{m}_z_rms")
            if zr is None:
                continue
            rows1.append(f"| {name} | {m} | " + " | ".join(_f(zr[p]) for p in par) + " |")
        rows2.append(_row2(name, s))
    t1 = head + "\n".join(rows1) + "\n"
    t2 = ("| laser cone | held-out error, true sensor (mm) | aligned (mm) | misaligned (mm) | "
          "auto (mm) | 90 % coverage, aligned | misaligned | aligned fit not converged | "
          "aligned check fails (ring) | aligned flagged (either) | misaligned check fails | "
          "compare_models prefers misaligned (median delta, nats) |\n"
          "|---|" + "---:|" * 11 + "\n" + "\n".join(rows2) + "\n")
    return t1, t2


def _row2(name, s):
    n = s["n"]
    return (f"| {name} | {_f(s['truth_heldout_mm'], '.0f')} | "
            f"{_f(s.get('aligned_heldout_mm'), '.0f')} | "
            f"{_f(s.get('misaligned_heldout_mm'), '.0f')} | {_f(s.get('auto_heldout_mm'), '.0f')}"
            f" | {_pct(s.get('aligned_coverage_identifiable'))} | "
            f"{_pct(s.get('misaligned_coverage_identifiable'))} | "
            f"{s['aligned_not_converged']}/{n} | "
            f"{s.get('aligned_check_fails', '-')}/{n} ({s.get('aligned_ring_flags', '-')}/{n}) | "
            f"{s.get('aligned_detected', '-')}/{n} | {s.get('misaligned_check_fails', '-')}/{n} | "
            f"{s['prefers_misaligned']}/{s['compared']} "
            f"({_f(s.get('delta_log_evidence_median'), '.0f')}) |")


def _pct(v):
    return "-" if v is None else f"{100 * v:.0f} %"


def plot(summary, path):
    """z-score rms of u0, v0 and held-out error against the tilt; detection rates."""
    import matplotlib

    matplotlib.use("agg")
    import matplotlib.pyplot as plt

    from bayescal.plotting import savefig

    tilt = {sc["name"]: sc["tilt"] for sc in SCENARIOS}
    names = [n for n in TILT_SERIES if n in summary]
    x = np.array([tilt[n] for n in names])
    fig, axes = plt.subplots(1, 3, figsize=(15, 4.5))
    style = {"aligned": ("tab:red", "o"), "misaligned": ("tab:blue", "s")}
    for m, (c, mk) in style.items():
        for p, ls in (("u0", "-"), ("v0", "--")):
            y = [summary[n].get(f"{m}_z_rms", {}).get(p, np.nan) for n in names]
            axes[0].plot(x, y, ls, color=c, marker=mk, label=f"{m}: {p}")
        axes[1].plot(x, [summary[n].get(f"{m}_heldout_mm", np.nan) for n in names], "-",
                     color=c, marker=mk, label=m)
    axes[0].axhline(1.0, color="k", lw=0.8, ls=":")
    axes[0].set_yscale("log")
    axes[0].set_ylabel("rms of (estimate - truth) / sd")
    axes[0].set_title("z-scores of the principal point (1 = honest)", fontsize="medium")
    axes[1].plot(x, [summary[n]["truth_heldout_mm"] for n in names], ":", color="k",
                 label="true sensor")
    axes[1].set_ylabel("mean held-out 3D error (mm)")
    axes[1].set_title("reconstruction of a second room, same sensor", fontsize="medium")
    nrep = np.array([summary[n]["n"] for n in names], float)
    axes[2].plot(x, [summary[n].get("aligned_check_fails", np.nan) for n in names] / nrep,
                 ":o", color="tab:red", label="aligned fit: model check fails")
    axes[2].plot(x, [summary[n].get("aligned_detected", np.nan) for n in names] / nrep,
                 "-o", color="tab:red", label="aligned fit: check fails or not converged")
    axes[2].plot(x, [summary[n]["prefers_misaligned"] for n in names] / nrep, "-s",
                 color="tab:blue", label="compare_models prefers misaligned")
    axes[2].set_ylim(-0.05, 1.05)
    axes[2].set_ylabel("fraction of replications")
    axes[2].set_title("detection", fontsize="medium")
    for ax in axes:
        ax.set_xlabel("tilt of the laser cone (deg)")
        ax.legend(fontsize="small")
        ax.grid(True, alpha=0.3)
    fig.suptitle("A tilted laser cone, 2500 mm room, 300 points, 0.2 px, approximate x, y "
                 "+-3 %, z unknown", fontsize="medium")
    fig.tight_layout()
    savefig(fig, path)


def run(args, out):
    reps, n_points = REPLICATIONS[args.mode], N_POINTS[args.mode]
    scenarios = SCENARIOS if args.mode != "smoke" else (SCENARIOS[0], SCENARIOS[3])
    specs = [{**sc, "rep": k, "n_points": n_points} for sc in scenarios for k in range(reps)]
    trials = run_trials(misalignment_trial, specs, seed=args.seed, workers=args.workers,
                        scheduler=args.scheduler, progress=False)
    summary = summarize(trials)
    t1, t2 = markdown_tables(summary)
    write_json(out / FILES[0], {"study": "misalignment", "mode": args.mode, "seed": args.seed,
                                "room": ROOM, "n_points": n_points, "replications": reps,
                                "scenarios": list(scenarios), "summary": summary,
                                "trials": trials})
    plot(summary, out / FILES[1])
    text = (f"Misalignment study ({args.mode}, seed {args.seed}, {reps} replications, "
            f"{n_points} points)\n\nrms of the z-scores:\n\n{t1}\n"
            f"held-out error, coverage, detection:\n\n{t2}")
    (out / FILES[2]).write_text(text)
    print(text)


def main(argv=None):
    """Run the study; returns the exit code."""
    return study_main(run, "misalignment: a tilted or offset laser cone, both laser models",
                      argv, FILES)


if __name__ == "__main__":
    raise SystemExit(main())
