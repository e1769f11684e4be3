"""Identifiability study: the phi/alpha ridge and what the priors do to it.

``phi``, ``alpha_u`` and ``alpha_v`` enter the model only through
``gamma_u = alpha_u (xi + phi)`` and ``gamma_v = alpha_v (xi + phi)`` (docs/model.md,
fact 1): the data fix the gammas, and the posterior slides along the ridge
``alpha_u (xi + phi) = const`` as far as the priors let it. This study samples
the posterior of one small room twice -- with the default prior
(``phi ~ N(0, 0.1)``) and with a tight prior ``phi ~ N(0, 0.01)`` -- and
overlays the two corner plots of ``(xi, phi, alpha_u, alpha_v, h)``.

Writes into ``--out``:

* ``identifiability.png``: the overlaid corner plots;
* ``identifiability.json``: per prior, posterior mean/sd of every parameter,
  prior sd, sd ratio and the prior-dominated flags, the ridge correlation
  ``corr(phi, alpha_u)``, and the identifiability report of the least squares;
* ``identifiability.txt``: the identifiability report and both posterior
  summaries as text.

Usage::

    python studies/identifiability.py --out out/ident [--quick]
"""

from __future__ import annotations

import pathlib
import sys

import numpy as np
from scipy import stats

sys.path.insert(0, str(pathlib.Path(__file__).resolve().parent))

from _common import bayes_settings, run_trials, study_main, write_json  # noqa: E402

import bayescal as bc  # noqa: E402

__all__ = ["main", "posterior_trial", "PRIORS", "CORNER_PARAMS"]

FILES = ("identifiability.json", "identifiability.png", "identifiability.txt")
PRIORS = {"default": None, "tight_phi": {"phi": ("norm", 0.0, 0.01)}}
CORNER_PARAMS = ("xi", "phi", "alpha_u", "alpha_v", "h")
COLORS = {"default": "tab:blue", "tight_phi": "tab:red"}


def _prior(spec):
    if spec is None:
        return None
    return {k: getattr(stats, d)(loc, sd) for k, (d, loc, sd) in spec.items()}


def posterior_trial(spec, rng):
    """Sample one room's posterior under one prior; returns samples and summaries."""
    r_sim, r_bay = (np.random.default_rng(s)
                    for s in np.random.SeedSequence(spec["data_seed"]).spawn(2))
    ds = bc.simulate_room(range_mm=1000.0, n_points=spec["n_points"], sigma_px=0.5,
                          approx_error=0.02, approx_model="gaussian", rng=r_sim)
    sig = np.maximum(ds.sigma_scene, 1.0)
    post = bc.sample_posterior(ds.pixels, ds.approx_points, sigma_px=0.5, sigma_scene=sig,
                               prior=_prior(spec["prior"]), rng=rng, progress=False,
                               **spec["bayes"])
    sim = bc.calibrate_simultaneous(ds.pixels, ds.approx_points, sigma_px=0.5,
                                    sigma_scene=sig, prior=_prior(spec["prior"]))
    x = post.param_samples
    i_phi, i_au = bc.PARAM_NAMES.index("phi"), bc.PARAM_NAMES.index("alpha_u")
    return {"prior": spec["name"], "samples": x, "summary": post.summary_rows(),
            "summary_text": post.summary_text(), "converged": bool(post.converged),
            "corr_phi_alpha_u": float(np.corrcoef(x[:, i_phi], x[:, i_au])[0, 1]),
            "identifiability_text": str(sim.identifiability),
            "null_directions": sim.identifiability.null_directions,
            "condition_number": sim.identifiability.condition_number,
            "true_params": ds.params.to_array()}


def plot(results, path):
    import matplotlib

    matplotlib.use("agg")
    import matplotlib.lines as mlines

    from bayescal.plotting import savefig

    idx = [bc.PARAM_NAMES.index(p) for p in CORNER_PARAMS]
    import corner

    fig = None
    handles = []
    for r in results:
        c = COLORS[r["prior"]]
        fig = corner.corner(np.asarray(r["samples"])[:, idx], labels=list(CORNER_PARAMS),
                            color=c, fig=fig, plot_datapoints=False, fill_contours=False,
                            levels=(0.39, 0.86), smooth=1.0, hist_kwargs={"density": True},
                            truths=np.asarray(r["true_params"])[idx], truth_color="k")
        label = ("default prior, phi ~ N(0, 0.1)" if r["prior"] == "default"
                 else "tight prior, phi ~ N(0, 0.01)")
        handles.append(mlines.Line2D([], [], color=c, label=label))
    fig.legend(handles=handles, loc="upper right", fontsize="large")
    fig.suptitle("phi / alpha ridge: alpha_u (xi + phi) is fixed by the data, "
                 "the prior of phi picks the point on it", y=1.02)
    savefig(fig, path)


def run(args, out):
    n_points = {"full": 580, "quick": 580, "smoke": 60}[args.mode]
    bayes = bayes_settings(args.mode)
    if args.mode == "full":
        bayes = {**bayes, "min_ess": 1000, "n_samples": 4000, "max_steps": 20000}
    specs = [{"name": k, "prior": v, "n_points": n_points, "bayes": bayes,
              "data_seed": args.seed} for k, v in PRIORS.items()]
    results = run_trials(posterior_trial, specs, seed=args.seed, workers=args.workers,
                         scheduler=args.scheduler)
    plot(results, out / FILES[1])
    report = {"study": "identifiability", "mode": args.mode, "seed": args.seed,
              "range_mm": 1000.0, "n_points": n_points, "sigma_px": 0.5,
              "approx_error": 0.02, "bayes_settings": bayes, "priors": PRIORS,
              "identifiability_report": results[0]["identifiability_text"],
              "null_directions": results[0]["null_directions"],
              "condition_number": results[0]["condition_number"],
              "posteriors": {r["prior"]: {"summary": r["summary"], "converged": r["converged"],
                                          "corr_phi_alpha_u": r["corr_phi_alpha_u"]}
                             for r in results}}
    write_json(out / FILES[0], report)
    text = ["Identifiability report of the simultaneous least squares (default prior):",
            results[0]["identifiability_text"], ""]
    for r in results:
        text += [f"Posterior summary, prior = {r['prior']} "
                 f"(corr(phi, alpha_u) = {r['corr_phi_alpha_u']:+.3f}):", r["summary_text"], ""]
    (out / FILES[2]).write_text("\n".join(text))
    print("\n".join(text))


def main(argv=None):
    """Run the study; returns the exit code."""
    return study_main(run, "identifiability: the phi/alpha ridge and the priors", argv, FILES)


if __name__ == "__main__":
    raise SystemExit(main())
