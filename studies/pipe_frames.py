"""Real ring-laser frames: the extractor on the shared frames of a pipe-inspection sensor.

Reads every PNG of ``FOLDER`` (the shared ``pipe`` frames: a red ring laser in a 12-inch
pipe seen by a fisheye camera; README there), extracts the laser with ``bc.extract_laser``
(the lit frame with the ring's centre and radius range a user would give, ``--hint``) and
checks each result two ways, with no truth: the scatter of the unflagged points about a
smooth curve r(theta) (a Fourier series of order 12 about the ring's own centre, fitted
with Tukey's biweight: the independent check of the data's README) and the package's own
cross-validation (``bc.ring_cross_validation``: held-out blocks of azimuths predicted from
their neighbours, z rms 1 when the covariances are honest). A frame the extractor refuses
is listed with its reason (the laser-off frame must be refused).

With ``--composites`` it also extracts frames with a known truth: a thin red elliptical ring
with the real frames' width, colour leakage and brightness composited onto the second
sensor's 1232 x 1028 laser-off frame (lit, and dimmed to a dark frame), directly and through
a Bayer mosaic and a JPEG round trip (``tests/image/composite.py``), scored against it.

Writes into ``--out`` (default ``out/pipe_frames``):

* ``pipe_frames.json``: every number;
* ``pipe_frames.md``: the tables (Markdown), as in docs/images.md;
* ``pipe_frames.png``: each frame's residuals about its smooth curve against azimuth;
* ``overlay_<frame>.png``: each frame with its points (the frames' licence is unknown:
  these stay in the output folder, never in the repository).

Usage::

    python studies/pipe_frames.py ../shared/data/pipe [--out DIR] [--composites] [--repeat 3]

Imports only the public API of bayescal (and ``bayescal.plotting``).
"""

from __future__ import annotations

import argparse
import fnmatch
import json
import pathlib
import sys
import time

import numpy as np

import bayescal as bc

__all__ = ["main", "smooth_curve_residuals", "frame_row", "composite_rows", "HINTS"]

HERE = pathlib.Path(__file__).resolve().parent
#: the ring's centre (u, v) and radius range (px) a user gives for a frame (file pattern):
#: the lit frame's, from the data's README
HINTS = {"lit_*": ((430.0, 295.0), (170.0, 260.0))}
#: order of the smooth curve the points are judged against (orders 8-30 give the same
#: scatter on these frames, the README says)
ORDER = 12


def smooth_curve_residuals(pixels, *, order=ORDER, iters=12):
    """Residuals (px, across the ring) of points about a robust Fourier curve r(theta) of
    ``order`` about their own centre, and the angles (rad) of the points about it."""
    p = np.asarray(pixels, float)
    c = p.mean(axis=0)
    for _ in range(3):                       # the centre of the curve's own mean radius
        d = p - c
        th = np.arctan2(d[:, 1], d[:, 0])
        A = np.column_stack([np.ones_like(th)] + [f(m * th) for m in range(1, 2) for f in
                                                  (np.cos, np.sin)])
        coef = np.linalg.lstsq(A, np.hypot(*d.T), rcond=None)[0]
        c = c + coef[1:3]
    d = p - c
    th, r = np.arctan2(d[:, 1], d[:, 0]), np.hypot(d[:, 0], d[:, 1])
    A = np.column_stack([np.ones_like(th)] + [f(m * th) for m in range(1, order + 1)
                                              for f in (np.cos, np.sin)])
    w = np.ones_like(r)
    for _ in range(iters):
        coef = np.linalg.lstsq(A * w[:, None], r * w, rcond=None)[0]
        res = r - A @ coef
        s = max(1.4826 * float(np.median(np.abs(res))), 0.02)
        u = res / (4.685 * s)
        w = np.where(np.abs(u) < 1, 1 - u ** 2, 0.0)
    drdt = np.column_stack([np.zeros_like(th)] + [
        g for m in range(1, order + 1) for g in (-m * np.sin(m * th), m * np.cos(m * th))]) @ coef
    return res * (r / np.hypot(r, drdt)), th


def _hint(name):
    for pattern, hint in HINTS.items():
        if fnmatch.fnmatch(name, pattern):
            return hint
    return None


def frame_row(path, *, repeat=1, out=None):
    """Extract one frame and check it; the row of the table (a dict)."""
    img = bc.read_image(path, raw=True)
    hint = _hint(path.name)
    kw = {} if hint is None else {"center": hint[0], "radius": hint[1]}
    row = {"frame": path.name, "size": f"{img.shape[1]}x{img.shape[0]}",
           "hints": None if hint is None else [list(hint[0]), list(hint[1])]}
    times = []
    for _ in range(repeat):
        t0 = time.process_time()
        try:
            lp = bc.extract_laser(img, **kw)
        except bc.ExtractionError as exc:
            times.append(time.process_time() - t0)
            return {**row, "refused": exc.reason, "cpu_s": float(np.median(times))}
        times.append(time.process_time() - t0)
    ok = ~lp.flagged
    res, th = smooth_curve_residuals(lp.pixels[ok])
    deg = np.unique(np.floor(np.degrees(th)).astype(int) % 360)
    cv = bc.ring_cross_validation(lp)
    med = float(np.median(res))
    row |= {"refused": None, "points": len(lp), "flagged": int((~ok).sum()),
            "kept_deg": len(deg) / 360.0,
            "robust_sd": float(1.4826 * np.median(np.abs(res - med))),
            "gross": float(np.mean(np.abs(res) > 1.0)), "mean_res": float(np.mean(res)),
            "sd_median": float(np.median(lp.sd_normal[ok])),
            "cv_z_rms": cv.z_rms, "cv_held_out": cv.n_held_out, "cv_gross": cv.gross,
            "cpu_s": float(np.median(times)), "_res": res, "_th": th}
    if out is not None:
        _overlay(img, lp, out / f"overlay_{path.stem}.png")
    return row


def _overlay(img, lp, path):
    import matplotlib.pyplot as plt

    from bayescal.plotting.basic import savefig

    fig, ax = plt.subplots(figsize=(9.6, 7.2))
    ax.imshow(np.asarray(img)[..., :3] if np.asarray(img).ndim == 3 else img, cmap="gray")
    ok = ~lp.flagged
    ax.plot(*lp.pixels[ok].T, ",", color="cyan")
    ax.plot(*lp.pixels[~ok].T, "x", color="red", ms=3)
    ax.set_title(f"{len(lp)} points, {int((~ok).sum())} flagged (red)")
    ax.set_axis_off()
    savefig(fig, path)


def composite_rows(folder, *, seeds=(0, 1, 2)):
    """Composited rings with a known truth on the second sensor's laser-off frame."""
    sys.path.insert(0, str(HERE.parent / "tests" / "image"))
    import imageio.v3 as iio
    from composite import composite_ring, score_composite

    base = iio.imread(pathlib.Path(folder) / "noring_v2_001.png")
    kinds = {"lit": {}, "dark": {"gain": 0.05}, "lit, Bayer": {"bayer": True},
             "lit, JPEG 90": {"jpeg": 90}, "dark, Bayer + JPEG 90": {"gain": 0.05,
                                                                   "bayer": True, "jpeg": 90}}
    rows = []
    for seed in seeds:
        rng = np.random.default_rng(seed)
        c = (611 + rng.uniform(-60, 60), 522 + rng.uniform(-50, 50))
        geo = dict(center=c, axes=(rng.uniform(240, 300), rng.uniform(220, 280)),
                   angle=rng.uniform(0, np.pi), bright_deg=rng.uniform(0, 360))
        for kind, kw in kinds.items():
            img, truth = composite_ring(base, rng=seed, **geo, **kw)
            t0 = time.process_time()
            try:
                lp = bc.extract_laser(img)
            except bc.ExtractionError as exc:
                rows.append({"kind": kind, "seed": seed, "refused": exc.reason})
                continue
            sec = time.process_time() - t0
            s = score_composite(lp, truth)
            rows.append({"kind": kind, "seed": seed, "refused": None, **s,
                         "cv_z_rms": bc.ring_cross_validation(lp).z_rms, "cpu_s": sec})
    return rows


def _table(rows):
    out = ["| frame | size | points | flagged | kept (deg) | robust sd (px) | gross > 1 px | "
           "CV z rms (held out) | CPU s |", "|---|---|---|---|---|---|---|---|---|"]
    for r in rows:
        name = r["frame"] + (" (with hints)" if r["hints"] else "")
        if r["refused"]:
            out.append(f"| {name} | {r['size']} | refused: {r['refused']} | | | | | | "
                       f"{r['cpu_s']:.2f} |")
            continue
        out.append(f"| {name} | {r['size']} | {r['points']} | {r['flagged']} | "
                   f"{r['kept_deg']:.3f} | {r['robust_sd']:.3f} | {100 * r['gross']:.1f} % | "
                   f"{r['cv_z_rms']:.2f} ({r['cv_held_out']}) | {r['cpu_s']:.2f} |")
    return "\n".join(out)


def _composite_table(rows):
    out = ["| composite | seed | kept | robust sd (px) | bias (px) | gross | z rms (truth) | "
           "CV z rms | CPU s |", "|---|---|---|---|---|---|---|---|---|"]
    for r in rows:
        if r["refused"]:
            out.append(f"| {r['kind']} | {r['seed']} | refused: {r['refused']} | | | | | | |")
            continue
        out.append(f"| {r['kind']} | {r['seed']} | {r['kept']:.3f} | {r['robust_sd']:.3f} | "
                   f"{r['bias']:+.3f} | {100 * r['gross']:.1f} % | {r['z_rms']:.2f} | "
                   f"{r['cv_z_rms']:.2f} | {r['cpu_s']:.2f} |")
    return "\n".join(out)


def _plot(rows, path):
    import matplotlib.pyplot as plt

    from bayescal.plotting.basic import savefig

    good = [r for r in rows if not r["refused"]]
    fig, axes = plt.subplots(len(good), 1, figsize=(9, 1.4 * len(good) + 0.6), sharex=True,
                             squeeze=False)
    for ax, r in zip(axes[:, 0], good, strict=True):
        ax.plot(np.degrees(r["_th"]), r["_res"], ".", ms=1.5)
        ax.set_ylim(-1.0, 1.0)
        ax.set_ylabel(r["frame"].split(".")[0], fontsize=8)
    axes[-1, 0].set_xlabel("azimuth about the ring's centre (deg)")
    fig.suptitle("residuals about a smooth curve r(theta) (px)")
    savefig(fig, path)


def main(argv=None):
    """Run the study; returns the exit code (2: no such folder, or output exists)."""
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("folder", type=pathlib.Path, help="the frames (e.g. ../shared/data/pipe)")
    p.add_argument("--out", type=pathlib.Path, default=pathlib.Path("out/pipe_frames"))
    p.add_argument("--composites", action="store_true",
                   help="also frames with a known ring composited onto the laser-off frame")
    p.add_argument("--repeat", type=int, default=1, help="extractions per frame timed")
    p.add_argument("--force", action="store_true", help="overwrite the output files")
    args = p.parse_args(argv)
    if not args.folder.is_dir():
        print(f"error: {args.folder} is not a folder", file=sys.stderr)
        return 2
    if (args.out / "pipe_frames.json").exists() and not args.force:
        print(f"error: {args.out} already holds pipe_frames.json (--force)", file=sys.stderr)
        return 2
    args.out.mkdir(parents=True, exist_ok=True)
    rows = [frame_row(f, repeat=args.repeat, out=args.out)
            for f in sorted(args.folder.glob("*.png"))]
    comp = composite_rows(args.folder) if args.composites else []
    text = _table(rows) + ("\n\n" + _composite_table(comp) if comp else "")
    (args.out / "pipe_frames.md").write_text(text + "\n")
    _plot(rows, args.out / "pipe_frames.png")
    clean = [{k: v for k, v in r.items() if not k.startswith("_")} for r in rows]
    (args.out / "pipe_frames.json").write_text(json.dumps(
        {"frames": clean, "composites": comp}, indent=1, default=float))
    print(text)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
