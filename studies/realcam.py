"""Real-camera study: the shared chessboard views of a paracatadioptric camera, calibrated.

Reads the images of ``--data`` (default ``../shared/data/para`` beside the repository;
the study skips, exit 0, when the folder is absent), finds the boards with
``bc.find_chessboard`` and calibrates the camera with each noise model of
``bc.calibrate_camera`` (plain least squares, per-view noise, per-view noise with a
per-view systematic field). For each: the intrinsics with their standard errors, the rms
and per-view noise, the cross-validation chi-square between disjoint halves of the views
(2 expected per direction when the covariance is honest) and, outside quick mode, the
held-out chi-square per coordinate (1 expected). Beside them, OpenCV's
``cv2.omnidir.calibrate`` on the same corners (zero distortion and skew: the same model),
with the views it keeps, and the sector-based detector (``method="sb"``) under plain
least squares.

Writes into ``--out``:

* ``realcam.json``: every number below;
* ``realcam.md``: the table (Markdown);
* ``realcam.png``: per-view noise by model and the cross-validation chi-square per split.

Usage::

    python studies/realcam.py --out docs/img/studies [--data ../shared/data/para] [--quick]
"""

from __future__ import annotations

import pathlib
import sys
import time

import numpy as np

sys.path.insert(0, str(pathlib.Path(__file__).resolve().parent))

from _common import study_main, write_json  # noqa: E402

import bayescal as bc  # noqa: E402
from bayescal.validation.camera_cv import all_splits, halves_chi2, heldout_chi2  # noqa: E402

__all__ = ["main", "find_views", "opencv_omnidir", "model_row"]

FILES = ("realcam.json", "realcam.md", "realcam.png")
DEFAULT_DATA = pathlib.Path(__file__).resolve().parents[1] / ".." / "shared" / "data" / "para"
NAMES = ("xi", "gamma_u", "gamma_v", "u0", "v0")
MODELS = ("plain", "per-view", "view-systematic")


def find_views(folder, *, method="classic"):
    """Board views of every image in ``folder`` (PGM, PNG, TIFF, JPEG), sorted by name."""
    paths = sorted(p for p in pathlib.Path(folder).iterdir()
                   if p.suffix.lower() in (".pgm", ".png", ".tif", ".tiff", ".jpg", ".jpeg"))
    views, missed = [], []
    for p in paths:
        v = bc.find_chessboard(p, board=(8, 6), square=42.0, method=method)
        (views if v is not None else missed).append(v if v is not None else p.name)
    return views, missed


def opencv_omnidir(views):
    """``cv2.omnidir.calibrate`` with zero distortion and skew; the views it keeps."""
    import cv2

    obj = [v.points[None].astype(np.float64) for v in views]
    img = [v.pixels[None].astype(np.float64) for v in views]
    om = cv2.omnidir
    flags = (om.CALIB_FIX_SKEW + om.CALIB_FIX_K1 + om.CALIB_FIX_K2 + om.CALIB_FIX_P1
             + om.CALIB_FIX_P2)
    crit = (cv2.TERM_CRITERIA_COUNT + cv2.TERM_CRITERIA_EPS, 300, 1e-10)
    rms, K, xi, D, rvecs, tvecs, idx = om.calibrate(obj, img, views[0].image_size, np.eye(3),
                                                    np.zeros((1, 1)), np.zeros((1, 4)), flags,
                                                    crit)
    kept = [int(i) for i in np.ravel(idx)]
    res = []
    for j, i in enumerate(kept):
        uv, _ = om.projectPoints(obj[i], rvecs[j], tvecs[j], K, float(xi.ravel()[0]), D)
        res.append(uv.reshape(-1, 2) - views[i].pixels)
    r = np.concatenate(res)
    return {"xi": float(xi.ravel()[0]), "gamma_u": float(K[0, 0]), "gamma_v": float(K[1, 1]),
            "u0": float(K[0, 2]), "v0": float(K[1, 2]), "rms_opencv": float(rms),
            "rms": float(np.sqrt(np.mean(r ** 2))),
            "kept": [views[i].name for i in kept],
            "dropped": [v.name for i, v in enumerate(views) if i not in kept]}


def model_row(views, noise, *, splits, heldout):
    """One noise model: the fit on every view and its cross-validation."""
    t0 = time.perf_counter()
    cam = bc.calibrate_camera(views, noise=noise)
    sd = cam.std()
    mc = cam.model_check()
    cv = halves_chi2(views, splits, noise=noise)
    row = {"noise": noise, "intrinsics": cam.intrinsics, "sd": {n: float(sd[n]) for n in NAMES},
           "rms": mc["rms"], "bartlett_p": mc["bartlett_p"], "tau": cam.tau,
           "view_sigma": [float(s) for s in cam.sigma],
           "view_rms": [v["rms"] for v in mc["views"]], "lag1": [v["lag1"] for v in mc["views"]],
           "cv_chi2": cv["chi2"].tolist(), "cv_shift": cv["mean_shift"].tolist()}
    if heldout:
        for how in ("interleaved", "extrapolating"):
            row[f"heldout_{how}"] = float(heldout_chi2(views, how=how, noise=noise)["pooled"])
    row["seconds"] = time.perf_counter() - t0
    return row


def _fmt_k(k, sd=None):
    cells = [f"{k['xi']:.4f}", f"{k['gamma_u']:.1f}", f"{abs(k['gamma_v']):.1f}",
             f"{k['u0']:.1f}", f"{k['v0']:.1f}"]
    if sd is not None:
        cells = [f"{c} ± {sd[n]:.2g}" for c, n in zip(cells, NAMES, strict=True)]
    return cells


def table(res):
    """The Markdown table of the study's results."""
    head = ("| fit | views used | xi | gamma_u | abs(gamma_v) | u0 | v0 | rms (px) | "
            "per-view sd (px) | CV chi2 / direction (2) | held-out chi2 / dof (1) |")
    lines = [head, "|" + "---|" * 11]
    n = len(res["views"])
    for r in res["models"]:
        sig = f"{min(r['view_sigma']):.2f}-{max(r['view_sigma']):.2f}"
        ho = ("-" if "heldout_interleaved" not in r else
              f"{r['heldout_interleaved']:.2f} / {r['heldout_extrapolating']:.2f}")
        lines.append(f"| bayescal, noise {r['noise']} | {n} of {n} | "
                     + " | ".join(_fmt_k(r["intrinsics"], r["sd"]))
                     + f" | {r['rms']:.3f} | {sig} | {np.mean(r['cv_chi2']):.2f} | {ho} |")
    if res.get("sb"):
        s = res["sb"]
        lines.append(f"| bayescal plain, corners by findChessboardCornersSB | {n} of {n} | "
                     + " | ".join(_fmt_k(s["intrinsics"], s["sd"])) + f" | {s['rms']:.3f} "
                     "| - | - | - |")
    o = res.get("opencv")
    if o:
        lines.append(f"| OpenCV omnidir.calibrate | {len(o['kept'])} of {n} | "
                     + " | ".join(_fmt_k(o)) + f" | {o['rms']:.3f} | - | none | none |")
        lines.append(f"| bayescal plain on OpenCV's views | {len(o['kept'])} of {n} | "
                     + " | ".join(_fmt_k(o["bayescal_same_views"]))
                     + f" | {o['bayescal_same_views_rms']:.3f} | - | - | - |")
    return "\n".join(lines) + "\n"


def plot(res, path):
    import matplotlib

    matplotlib.use("agg")
    import matplotlib.pyplot as plt

    fig, (a, b) = plt.subplots(1, 2, figsize=(11, 4))
    names = [v.replace(".pgm", "") for v in res["views"]]
    x = np.arange(len(names))
    for j, r in enumerate(res["models"]):
        a.bar(x + (j - 1) * 0.27, r["view_rms"], 0.27, label=f"rms, noise {r['noise']}")
    a.plot(x, res["models"][-1]["view_sigma"], "k_", ms=18, mew=2,
           label="inferred sd (view-systematic)")
    a.set_xticks(x, names, rotation=30, fontsize=8)
    a.set_ylabel("residual per coordinate, px")
    a.legend(fontsize=7)
    for j, r in enumerate(res["models"]):
        c = np.asarray(r["cv_chi2"])
        b.plot(np.full(len(c), j) + np.linspace(-0.15, 0.15, len(c)), c, "o", alpha=0.7)
        b.plot([j - 0.25, j + 0.25], [c.mean()] * 2, "k-", lw=2)
    b.axhline(2.0, color="gray", ls="--", label="2: honest covariance")
    b.set_yscale("log")
    b.set_xticks(range(len(res["models"])), [r["noise"] for r in res["models"]])
    b.set_ylabel("chi-square per direction, halves of the views")
    b.legend(fontsize=7)
    fig.suptitle(f"{len(names)} real views, 8 x 6 corners of 42 mm: residuals and "
                 "cross-validation")
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def run(args, out):
    views, missed = find_views(args.data)
    quick = args.mode != "full"
    smoke = args.mode == "smoke"
    splits = all_splits(len(views), max_splits={"full": None, "quick": 3, "smoke": 1}[args.mode])
    res = {"data": str(args.data), "views": [v.name for v in views], "missed": missed,
           "corners": [v.n_corners for v in views], "splits": splits, "models": []}
    for noise in MODELS[:1] if smoke else MODELS:
        res["models"].append(model_row(views, noise, splits=splits, heldout=not quick))
    sb, _ = ([], None) if smoke else find_views(args.data, method="sb")
    if sb and len(sb) == len(views):
        cam = bc.calibrate_camera(sb, noise="plain")
        res["sb"] = {"intrinsics": cam.intrinsics, "rms": cam.model_check()["rms"],
                     "sd": {n: float(v) for n, v in cam.std().items()}}
    o = opencv_omnidir(views)
    same = [v for v in views if v.name in o["kept"]]
    cam = bc.calibrate_camera(same, noise="plain")
    o["bayescal_same_views"] = cam.intrinsics
    o["bayescal_same_views_rms"] = cam.model_check()["rms"]
    res["opencv"] = o
    write_json(out / "realcam.json", res)
    (out / "realcam.md").write_text(table(res))
    plot(res, out / "realcam.png")
    print(table(res))


def _add(parser):
    parser.add_argument("--data", type=pathlib.Path, default=DEFAULT_DATA,
                        help="folder of chessboard images (default: ../shared/data/para)")


def main(argv=None):
    from _common import parse_args

    args = parse_args("real-camera study", argv, add_arguments=_add)
    if not args.data.is_dir():
        print(f"realcam: {args.data} is absent; nothing to do (skipped)")
        return 0
    return study_main(run, "real-camera study: noise models, cross-validation, OpenCV",
                      argv, FILES, add_arguments=_add)


if __name__ == "__main__":
    sys.exit(main())
