"""Design study: predicted reconstruction uncertainty against range, baseline h and cone angle.

The question a sensor designer asks before building: with a given pixel noise
and a roughly known room, how well will the sensor reconstruct? For each design
(the paper's sensor with one of range, ``h`` or ``beta`` changed; the design
values are also the prior's centre) one room is simulated (``approx_model=
"fig9"`` at ``--approx`` relative error, ``--sigma-px`` pixel noise) and
calibrated with ``bc.calibrate_simultaneous``. From its *Laplace* covariance
(fast; the posterior spot-check below says how far to trust it) two numbers:

* ``joint_sd_mm``: median over the laser points of ``sqrt(trace)`` of the
  3x3 covariance of the jointly estimated points (the calibration scene itself);
* ``new_point_sd_mm``: median ``sqrt(trace)`` of the covariance of a *new*
  laser pixel triangulated with the calibrated sensor, first order: the
  8x8 parameter covariance and the pixel noise pushed through
  ``bc.triangulate`` by central differences (what a later scan gets);

beside the actual mean error of both on that simulation. A posterior
spot-check (``bc.sample_posterior`` and ``Posterior.reconstruct`` on the
same pixels) is run for the paper's design at 1000 mm and 5000 mm.

Writes ``design.json`` and ``design.png`` into ``--out``.

Usage::

    python studies/design.py --out out/design [--quick]
"""

from __future__ import annotations

import pathlib
import sys

import numpy as np

sys.path.insert(0, str(pathlib.Path(__file__).resolve().parent))

from _common import bayes_settings, run_trials, study_main, write_json  # noqa: E402

import bayescal as bc  # noqa: E402

__all__ = ["main", "design_trial", "GRIDS", "predicted_new_point_sd"]

FILES = ("design.json", "design.png")
GRIDS = {
    "full": {"range_mm": [1000, 2000, 3000, 4000, 5000, 6000],
             "h": [100, 150, 200, 300, 400], "beta": [0.8, 0.9, 1.0, np.pi / 3, 1.15, 1.25]},
    "quick": {"range_mm": [1000, 3000, 5000], "h": [100, 200, 400], "beta": [0.9, np.pi / 3,
                                                                            1.2]},
    "smoke": {"range_mm": [1000, 5000], "h": [200], "beta": [np.pi / 3]},
}
BASE_RANGE_MM = 5000.0


def predicted_new_point_sd(params, cov8, pixels, sigma_px, *, step=1e-6):
    """First-order sd (sqrt trace, mm) of triangulating ``pixels`` with uncertain parameters.

    Parameters
    ----------
    params : SensorParams
    cov8 : ndarray, shape (8, 8)
        Parameter covariance (order ``bc.PARAM_NAMES``).
    pixels : ndarray, shape (M, 2)
    sigma_px : float
        Pixel noise of the new pixels, px.

    Returns
    -------
    ndarray, shape (M,)
    """
    a = params.to_array()
    J = []
    for k in range(8):
        d = np.zeros(8)
        d[k] = step * max(abs(a[k]), 1.0)
        hi = bc.triangulate(bc.SensorParams.from_array(a + d), pixels)
        lo = bc.triangulate(bc.SensorParams.from_array(a - d), pixels)
        J.append((hi - lo) / (2 * d[k]))
    Ja = np.stack(J, axis=-1)                                   # (M, 3, 8)
    Ju = np.stack([(bc.triangulate(params, pixels + e) - bc.triangulate(params, pixels - e))
                   / 2e-4 for e in (np.array([1e-4, 0.0]), np.array([0.0, 1e-4]))], axis=-1)
    cov = np.einsum("mik,kl,mjl->mij", Ja, cov8, Ja) + sigma_px**2 * Ju @ np.swapaxes(Ju, 1, 2)
    return np.sqrt(np.trace(cov, axis1=1, axis2=2))


def design_trial(spec, rng):
    """Simulate and calibrate one design; Laplace-predicted and actual errors."""
    p0 = bc.SensorParams.paper().as_dict()
    if spec["vary"] != "range_mm":
        p0[spec["vary"]] = spec["value"]
    params = bc.SensorParams(**p0)
    range_mm = spec["value"] if spec["vary"] == "range_mm" else BASE_RANGE_MM
    prior = bc.default_prior(params)
    r_sim, r_bay = (np.random.default_rng(s)
                    for s in np.random.SeedSequence(rng.integers(2**63)).spawn(2))
    ds = bc.simulate_room(params, range_mm=range_mm, n_points=spec["n_points"],
                          sigma_px=spec["sigma_px"], approx_error=spec["approx"],
                          approx_model="fig9", nominal=params, rng=r_sim)
    sig = np.maximum(ds.sigma_scene, 1.0)
    res = bc.calibrate_simultaneous(ds.pixels, ds.approx_points, sigma_px=spec["sigma_px"],
                                    sigma_scene=sig, prior=prior)
    pc = res.point_covariance()
    new_sd = predicted_new_point_sd(res.params, res.covariance(), ds.pixels, spec["sigma_px"])
    # actual error of a new scan: fresh pixel noise on the same points, triangulated
    new_pix = ds.pixels_true + r_sim.normal(0.0, spec["sigma_px"], ds.pixels.shape)
    out = {"vary": spec["vary"], "value": spec["value"], "range_mm": range_mm,
           "h": params.h, "beta": params.beta,
           "joint_sd_mm": float(np.median(np.sqrt(np.trace(pc, axis1=1, axis2=2)))),
           "new_point_sd_mm": float(np.nanmedian(new_sd)),
           "joint_error_mm": bc.reconstruction_error(res.points, ds.points),
           "new_point_error_mm": bc.reconstruction_error(bc.triangulate(res.params, new_pix),
                                                         ds.points, invalid="ignore"),
           "new_point_median_error_mm": float(np.nanmedian(bc.reconstruction_errors(
               bc.triangulate(res.params, new_pix), ds.points)))}
    if spec.get("bayes") is not None:
        try:
            post = bc.sample_posterior(ds.pixels, ds.approx_points, sigma_px=spec["sigma_px"],
                                       sigma_scene=sig, prior=prior, rng=r_bay,
                                       progress=False, **spec["bayes"])
        except Exception as exc:  # noqa: BLE001 (a failed chain is a result, recorded)
            out["posterior_failed"] = f"{type(exc).__name__}: {exc}"
            return out
        rec = post.reconstruct(ds.pixels)
        tr = np.sqrt(np.trace(rec.covariance, axis1=1, axis2=2))
        out["posterior_joint_sd_mm"] = float(np.median(np.sqrt(np.trace(
            post.point_covariance(), axis1=1, axis2=2))))
        out["posterior_new_point_sd_mm"] = float(np.nanmedian(tr[rec.valid]))
        out["posterior_converged"] = bool(post.converged)
    return out


def plot(rows, path):
    import matplotlib

    matplotlib.use("agg")
    import matplotlib.pyplot as plt

    from bayescal.plotting import savefig

    fig, axes = plt.subplots(1, 3, figsize=(14, 4.3), sharey=True)
    for ax, (vary, label) in zip(axes, (("range_mm", "room range (mm)"),
                                        ("h", f"baseline h (mm), {BASE_RANGE_MM:.0f} mm room"),
                                        ("beta", f"cone angle beta (rad), "
                                                 f"{BASE_RANGE_MM:.0f} mm room")), strict=True):
        r = [row for row in rows if row["vary"] == vary]
        x = [row["value"] for row in r]
        ax.plot(x, [row["new_point_sd_mm"] for row in r], "o-", c="tab:red",
                label="new pixel: predicted sd (Laplace)")
        ax.plot(x, [row["new_point_median_error_mm"] for row in r], "o:", c="tab:red",
                mfc="none", label="new pixel: actual median error")
        ax.plot(x, [row["joint_sd_mm"] for row in r], "s-", c="tab:blue",
                label="calibration scene: predicted sd (Laplace)")
        ax.plot(x, [row["joint_error_mm"] for row in r], "s:", c="tab:blue", mfc="none",
                label="calibration scene: actual mean error")
        for row in r:
            if "posterior_new_point_sd_mm" in row:
                ax.plot(row["value"], row["posterior_new_point_sd_mm"], "*", c="k", ms=11)
                ax.plot(row["value"], row["posterior_joint_sd_mm"], "*", c="grey", ms=11)
        ax.set_xlabel(label)
        ax.set_yscale("log")
        ax.grid(True, which="both", alpha=0.3)
    axes[0].set_ylabel("3D uncertainty, sqrt(trace) (mm)")
    axes[0].plot([], [], "*", c="k", label="posterior spot-check, new pixel")
    axes[0].plot([], [], "*", c="grey", label="posterior spot-check, scene")
    axes[0].legend(fontsize="x-small")
    savefig(fig, path)


def _add_arguments(parser):
    parser.add_argument("--sigma-px", type=float, default=0.5, help="pixel noise (default 0.5)")
    parser.add_argument("--approx", type=float, default=0.02,
                        help="relative error of the approximate points (default 0.02)")


def run(args, out):
    grid = GRIDS[args.mode]
    n_points = 60 if args.mode == "smoke" else 580
    spot = bayes_settings(args.mode)
    specs = []
    for vary in ("range_mm", "h", "beta"):
        for v in grid[vary]:
            check = (args.mode != "smoke" and vary == "range_mm" and v in (1000, 5000))
            specs.append({"vary": vary, "value": float(v), "n_points": n_points,
                          "sigma_px": args.sigma_px, "approx": args.approx,
                          "bayes": spot if check else None})
    rows = run_trials(design_trial, specs, seed=args.seed, workers=args.workers,
                      scheduler=args.scheduler)
    write_json(out / FILES[0], {"study": "design", "mode": args.mode, "seed": args.seed,
                                "sigma_px": args.sigma_px, "approx_error": args.approx,
                                "n_points": n_points, "base_range_mm": BASE_RANGE_MM,
                                "covariance": "Laplace (calibrate_simultaneous); posterior "
                                              "spot-checks where posterior_* keys exist",
                                "rows": rows})
    plot(rows, out / FILES[1])
    print(f"{'vary':>8} {'value':>7} {'new sd':>9} {'new err':>9} {'joint sd':>9} "
          f"{'joint err':>9} {'post new':>9} {'post joint':>10}")
    for r in rows:
        print(f"{r['vary']:>8} {r['value']:7.3g} {r['new_point_sd_mm']:9.1f} "
              f"{r['new_point_median_error_mm']:9.1f} {r['joint_sd_mm']:9.1f} "
              f"{r['joint_error_mm']:9.1f} {r.get('posterior_new_point_sd_mm', np.nan):9.1f} "
              f"{r.get('posterior_joint_sd_mm', np.nan):10.1f}")


def main(argv=None):
    """Run the study; returns the exit code."""
    return study_main(run, "design: predicted reconstruction uncertainty of a sensor design",
                      argv, FILES, add_arguments=_add_arguments)


if __name__ == "__main__":
    raise SystemExit(main())
