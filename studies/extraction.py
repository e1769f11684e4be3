"""Extraction study: the error of the laser pixels against range, blur and signal.

Renders 800x600 images of the paper's sensor in ``bc.room_walls(range)`` (textured
walls, two lamps, a ghost) and extracts the laser with ``bc.extract_laser``; the
error of each unflagged point is measured along the true ring's normal. Three
sweeps: range 1000-5000 mm (with and without a laser-off image), PSF sd 0.5-1.5 px
and laser power x0.25-x4 (the SNR) at 2500 mm.

Writes into ``--out``:

* ``extraction.json``: per setting, over seeds: bias, robust sd, median given sd,
  unflagged gross errors (> 1 px), flagged fraction and the z-score rms;
* ``extraction.png``: robust sd and median given sd against each swept quantity.

Usage::

    python studies/extraction.py --out out/extraction [--quick]
"""

from __future__ import annotations

import pathlib
import sys

import numpy as np

sys.path.insert(0, str(pathlib.Path(__file__).resolve().parent))

from _common import run_trials, study_main, write_json  # noqa: E402

import bayescal as bc  # noqa: E402

__all__ = ["main", "extraction_trial", "normal_errors"]

FILES = ("extraction.json", "extraction.png")
BASE = {"range_mm": 2500.0, "psf_px": 0.8, "power": 1.0, "background": True}
SWEEPS = {"range_mm": [1000.0, 2500.0, 5000.0], "psf_px": [0.5, 0.8, 1.5],
          "power": [0.25, 1.0, 4.0]}


def normal_errors(lp, truth):
    """Signed error along the true ring's normal (px) and the sd given to it."""
    T = truth.pixels
    t = np.roll(T, -1, 0) - np.roll(T, 1, 0)
    t /= np.linalg.norm(t, axis=1)[:, None]
    nrm = np.stack([t[:, 1], -t[:, 0]], -1)
    k = np.argmin(np.sum((lp.pixels[:, None, :] - T[None]) ** 2, -1), 1)
    e = np.sum((lp.pixels - T[k]) * nrm[k], 1)
    sd = np.sqrt(np.einsum("ni,nij,nj->n", nrm[k], lp.covariance, nrm[k]))
    return e, sd


def extraction_trial(spec, rng):
    """Render one image with ``spec``'s settings, extract it, return the error statistics."""
    img, truth = bc.render_image(bc.SensorParams.paper(), bc.room_walls(spec["range_mm"]),
                                 psf_px=spec["psf_px"], laser_power=12.0 * spec["power"],
                                 n_lamps=2, ghost=0.3, with_background=spec["background"],
                                 rng=rng)
    try:
        lp = bc.extract_laser(img, background=truth.background)
    except bc.ExtractionError:      # no ring stands out of the texture: counted, no errors
        keys = ("bias", "robust_sd", "given_sd", "gross", "flagged", "z_rms")
        return {**spec, **dict.fromkeys(keys, np.nan), "raised": 1.0}
    e, sd = normal_errors(lp, truth)
    ok = ~lp.flagged
    gross = np.abs(e) > 1.0
    good = ok & ~gross
    med = float(np.median(e[ok])) if ok.any() else np.nan
    return {**spec, "bias": med,
            "robust_sd": float(1.4826 * np.median(np.abs(e[ok] - med))) if ok.any() else np.nan,
            "given_sd": float(np.median(sd[ok])) if ok.any() else np.nan,
            "gross": float(np.mean(gross & ok)), "flagged": float(np.mean(lp.flagged)),
            "z_rms": float(np.sqrt(np.mean((e[good] / sd[good]) ** 2))) if good.any() else np.nan,
            "raised": 0.0}


def _specs(mode):
    n_seeds = {"full": 6, "quick": 2, "smoke": 1}[mode]
    settings = []
    for key, values in SWEEPS.items():
        for v in values:
            settings.append({**BASE, key: v, "sweep": key})
    settings += [{**BASE, "range_mm": r, "background": False, "sweep": "range_mm"}
                 for r in SWEEPS["range_mm"]]
    if mode == "smoke":
        settings = settings[:2]
    return [{**s, "seed_index": i} for s in settings for i in range(n_seeds)]


def summarize(trials):
    """Mean over seeds of every statistic, per setting."""
    keys = ("bias", "robust_sd", "given_sd", "gross", "flagged", "z_rms", "raised")
    groups = {}
    for t in trials:
        groups.setdefault((t["sweep"], t["range_mm"], t["psf_px"], t["power"], t["background"]),
                          []).append(t)
    out = []
    for (sweep, r, psf, power, bg), ts in groups.items():
        row = {"sweep": sweep, "range_mm": r, "psf_px": psf, "power": power, "background": bg,
               "n_images": len(ts)}
        row |= {k: float(np.nanmean([t[k] for t in ts])) for k in keys}
        out.append(row)
    return out


def plot(rows, path):
    import matplotlib

    matplotlib.use("agg")
    import matplotlib.pyplot as plt

    from bayescal.plotting.basic import savefig

    fig, axes = plt.subplots(1, 3, figsize=(13, 4))
    labels = {"range_mm": "range (mm)", "psf_px": "PSF sd (px)", "power": "laser power (x)"}
    for ax, key in zip(axes, SWEEPS, strict=True):
        for bg, style in ((True, "-"), (False, ":")):
            rs = sorted((r for r in rows if r["sweep"] == key and r["background"] == bg),
                        key=lambda r: r[key])
            if not rs:
                continue
            x = [r[key] for r in rs]
            tag = "" if bg else ", no laser-off image"
            ax.plot(x, [r["robust_sd"] for r in rs], "o" + style, c="tab:blue",
                    label="robust sd of the error" + tag)
            ax.plot(x, [r["given_sd"] for r in rs], "s" + style, c="tab:orange",
                    label="median given sd" + tag)
        ax.set_xlabel(labels[key])
        ax.set_ylabel("px, along the ring's normal")
        if key == "range_mm":
            ax.set_yscale("log")
        else:
            ax.set_ylim(0, None)
        if key == "power":
            ax.set_xscale("log")
            ax.set_xticks(SWEEPS["power"], [f"{v:g}" for v in SWEEPS["power"]])
            ax.minorticks_off()
    axes[0].legend(fontsize=7)
    fig.subplots_adjust(wspace=0.35)
    fig.suptitle("Laser extraction from rendered 800x600 images (2 lamps, ghost 0.3)")
    savefig(fig, path)


def run(args, out):
    trials = run_trials(extraction_trial, _specs(args.mode), seed=args.seed,
                        workers=args.workers, scheduler=args.scheduler)
    rows = summarize(trials)
    plot(rows, out / FILES[1])
    write_json(out / FILES[0], {"study": "extraction", "mode": args.mode, "seed": args.seed,
                                "base": BASE, "sweeps": SWEEPS, "rows": rows})
    for r in rows:
        print(f"{r['sweep']:9s} range {r['range_mm']:6.0f} psf {r['psf_px']:.1f} power "
              f"{r['power']:4.2f} bg {r['background']!s:5s}: bias {r['bias']:+.3f} robust sd "
              f"{r['robust_sd']:.3f} given {r['given_sd']:.3f} gross {r['gross']:.3f} flagged "
              f"{r['flagged']:.3f} z_rms {r['z_rms']:.2f} raised {r['raised']:.2f}")


def main(argv=None):
    """Run the study; returns the exit code."""
    return study_main(run, "extraction: laser pixel errors against range, blur and signal",
                      argv, FILES)


if __name__ == "__main__":
    raise SystemExit(main())
