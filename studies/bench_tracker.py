"""The ring tracker at video rate: ms per frame on one core, the full extractor timed in
the same run (issue 40).

Sequences: a rendered sensor moving through a textured 2500-mm room
(``bc.render_sequence``) at 960x720 and 1232x1028, and, when the folder is given, the real
ring-laser frames of ``pipe/`` (``ring_*.png`` in the order of their names). Every frame is
written as PNG and read back, so that decoding is timed apart. Per frame, CPU time
(``time.process_time``, BLAS on one thread): the full extractor (``bc.extract_laser``), the
tracker (``bc.LaserTracker``, the minimum over ``--passes`` passes over the sequence), and
the reconstruction of its unflagged pixels with error bars by a calibration of that image
size (``bc.calibrate_simultaneous`` on a simulated room, then its prepared
``Reconstructor``). Targets: the tracker <= 33 ms per 960x720 frame and <= 50 ms per
1232x1028 frame, extraction + reconstruction <= 40 ms, the full extractor <= 1 s. The
agreement of each tracked frame with the full extractor's extraction of it
(``agreement`` of ``tests/image/score.py``) and, for rendered frames, both against the true centre
line, are printed too. Writes its section of docs/performance.md (inside "Where the time
goes", which ``studies/benchmark.py`` keeps).

Usage::

    OPENBLAS_NUM_THREADS=1 python studies/bench_tracker.py [../shared/data/pipe]
        [--frames 30] [--passes 3] [--out docs/performance.md] [--no-write]
"""

from __future__ import annotations

import argparse
import datetime
import os
import pathlib
import sys
import tempfile
import time

import numpy as np

import bayescal as bc

sys.path.insert(0, str(pathlib.Path(__file__).resolve().parents[1] / "tests" / "image"))
from score import agreement  # noqa: E402

__all__ = ["main"]

#: ms per tracked frame, by image size; extraction + reconstruction; the full extractor
TARGETS = {(960, 720): 33.0, (1232, 1028): 50.0}
RECON_TARGET_MS = 40.0
FULL_TARGET_MS = 1000.0
BEGIN, END = "<!-- bench_tracker: begin -->", "<!-- bench_tracker: end -->"


def _sensor(width, height):
    """A sensor whose ring spans about 60 % of the image's half-height (the real pipe
    frames' rings: radius 170-260 px in 960x720)."""
    alpha = 140.0 * width / 960.0
    return bc.SensorParams(**{**bc.SensorParams.paper().as_dict(), "alpha_u": alpha,
                              "alpha_v": -alpha, "u0": width / 2.0, "v0": height / 2.0})


def _cpu(f, *a, **k):
    t = time.process_time()
    out = f(*a, **k)
    return out, time.process_time() - t


def _truth_error(lp, truth):
    """Distance (px) of each unflagged point to the true centre line (a dense polyline)."""
    p = lp.pixels[~lp.flagged]
    j = np.argmin(np.linalg.norm(p[:, None] - truth[None], axis=-1), axis=1)
    best = np.full(len(p), np.inf)
    for k in (j - 1, j + 1):
        a, b = truth[j], truth[k % len(truth)]
        t = np.clip(np.sum((p - a) * (b - a), 1) / np.maximum(np.sum((b - a) ** 2, 1), 1e-12),
                    0, 1)
        best = np.minimum(best, np.linalg.norm(p - a - t[:, None] * (b - a), axis=1))
    return best


def _reconstructor(width, height):
    """A calibration's fast reconstructor for a sensor of this image size."""
    p = _sensor(width, height)
    ds = bc.simulate_room(p, range_mm=2500, n_points=580, sigma_px=0.2, approx_error=0.05,
                          rng=0)
    res = bc.calibrate_simultaneous(ds.pixels, ds.approx_points, sigma_px=0.2,
                                    sigma_scene=ds.sigma_scene, prior=bc.default_prior(p),
                                    init=p)
    return res.reconstructor()


def _run(paths, passes, recon, truths=None):
    """Time one sequence of PNG files; returns the per-frame records."""
    frames, decode = [], []
    for path in paths:
        img, t = _cpu(bc.read_image, path, raw=True)
        frames.append(img)
        decode.append(t)
    recs = []
    for i, img in enumerate(frames):
        try:
            full, t = _cpu(bc.extract_laser, img)
        except bc.ExtractionError as exc:
            full, t = exc, np.nan
        recs.append(dict(name=pathlib.Path(paths[i]).stem, decode=decode[i], full=full,
                         full_s=t, track_s=np.inf, recon_s=np.inf))
    for k in range(passes):
        tracker = bc.LaserTracker()
        for rec, img in zip(recs, frames, strict=True):
            lp, t = _cpu(tracker, img, name=rec["name"])
            rec["track_s"] = min(rec["track_s"], t)
            if k == 0:
                rec["lp"] = lp
            if lp.tracked and recon is not None:
                ok = ~lp.flagged
                _, tr = _cpu(recon, lp.pixels[ok], pixel_cov=lp.covariance[ok])
                rec["recon_s"] = min(rec["recon_s"], tr)
    for i, rec in enumerate(recs):
        lp, full = rec["lp"], rec["full"]
        if lp.tracked and not isinstance(full, Exception):
            rec["agree"] = agreement(lp, full)
            rec["same_grid"] = len(lp) == len(full) and np.hypot(*(lp.center - full.center)) < 0.25
            if truths is not None:
                rec["err"] = (_truth_error(lp, truths[i]), _truth_error(full, truths[i]))
    return recs


def _ms(x):
    return f"{1e3 * x:.1f}" if np.isfinite(x) else "-"


def _summary(name, size, recs):
    """Table rows (list of str) and notes for one sequence."""
    tracked = [r for r in recs if r["lp"].tracked]
    refused = [r for r in recs if isinstance(r["full"], Exception)]
    full_s = np.array([r["full_s"] for r in recs if np.isfinite(r["full_s"])])
    dec = np.median([r["decode"] for r in recs])
    w, h = size
    rows, notes = [], []
    n_note = (f"{len(tracked)} of {len(recs)} frames followed, {len(refused)} refused by the "
              "full extractor")
    if len(full_s):
        ok = np.median(full_s) * 1e3 <= FULL_TARGET_MS
        rows.append(f"| {name} | {w}x{h} | full extractor (`extract_laser`) | "
                    f"{_ms(np.median(full_s))} | {_ms(np.max(full_s))} | <= {FULL_TARGET_MS:g} "
                    f"| {'PASS' if ok else 'FAIL'} | {len(full_s)} frames |")
    if not tracked:
        why = "; ".join(sorted({r['full'].reason.split(":")[0] for r in refused}))
        rows.append(f"| {name} | {w}x{h} | tracker | - | - | <= {TARGETS.get(size, 50):g} | "
                    f"not timed | {n_note}: nothing to follow ({why}) |")
        return rows, notes
    ts = np.array([r["track_s"] for r in tracked])
    target = TARGETS.get(size, TARGETS[(1232, 1028)])
    verdict = "PASS" if np.median(ts) * 1e3 <= target else "FAIL"
    rows.append(f"| {name} | {w}x{h} | tracker, decoded frame | {_ms(np.median(ts))} | "
                f"{_ms(np.percentile(ts, 90))} | <= {target:g} | {verdict} | {n_note} |")
    rows.append(f"| {name} | {w}x{h} | tracker + PNG decoding | {_ms(np.median(ts) + dec)} | "
                f"{_ms(np.percentile(ts, 90) + dec)} | - | - | decoding {_ms(dec)} ms |")
    rc = np.array([r["recon_s"] for r in tracked])
    if np.all(np.isfinite(rc)):
        both = ts + rc
        verdict = "PASS" if np.median(both) * 1e3 <= RECON_TARGET_MS else "FAIL"
        rows.append(f"| {name} | {w}x{h} | tracker + reconstruction with error bars | "
                    f"{_ms(np.median(both))} | {_ms(np.percentile(both, 90))} | "
                    f"<= {RECON_TARGET_MS:g} | {verdict} | reconstruction {_ms(np.median(rc))} "
                    "ms (`Reconstructor`, first order) |")
    everything = np.array([r["track_s"] for r in recs if np.isfinite(r["track_s"])])
    notes.append(f"{name} {w}x{h}: mean over every frame, fallbacks included, "
                 f"{_ms(np.mean(everything))} ms; {n_note}")
    notes += _agreement_notes(f"{name} {w}x{h}", tracked)
    return rows, notes


def _agreement_notes(name, tracked):
    agreed = [r for r in tracked if "agree" in r]
    if not agreed:
        return []
    d = np.concatenate([r["agree"]["diff_px"] for r in agreed])
    s = np.concatenate([r["agree"]["sd_ratio"] for r in agreed])
    same = [r for r in agreed if r["same_grid"]]
    ds = np.concatenate([r["agree"]["diff_px"] for r in same]) if same else np.zeros(0)
    out = [f"{name}: agreement with the full extractor over {len(agreed)} followed frames, "
           f"{len(d)} points kept by both: within 0.1 px {100 * np.mean(d <= 0.1):.1f} %, "
           f"95th percentile {np.percentile(d, 95):.3f} px, largest {d.max():.2f} px; "
           f"sd ratio median {np.median(s):.3f}, 1-99 % {np.percentile(s, 1):.2f}-"
           f"{np.percentile(s, 99):.2f}; kept only by the tracker "
           f"{sum(r['agree']['only_a'] for r in agreed)}, only by the full extractor "
           f"{sum(r['agree']['only_b'] for r in agreed)}"]
    if len(ds):
        out.append(f"{name}: on the {len(same)} frames where both read the same profiles "
                   f"(same number, centres within 0.25 px): within 0.1 px "
                   f"{100 * np.mean(ds <= 0.1):.1f} %, 95th percentile "
                   f"{np.percentile(ds, 95):.3f} px")
    if "err" in agreed[0]:
        et = np.concatenate([r["err"][0] for r in agreed])
        ef = np.concatenate([r["err"][1] for r in agreed])
        out.append(f"{name}: error against the true centre line (unflagged points): tracker "
                   f"median {np.median(et):.3f} px, gross (> 1 px) {100 * np.mean(et > 1):.2f} "
                   f"%; full extractor median {np.median(ef):.3f} px, gross "
                   f"{100 * np.mean(ef > 1):.2f} %")
    return out


def _followed_from_itself(paths, center, radius, passes):
    """Development rows for frames the full extractor refuses: each real frame followed
    from its own unchecked full extraction with the user's hints (zero motion), without the
    plausibility checks; the CPU time of the followed call (minimum over passes)."""
    out = []
    for path in paths:
        img = bc.read_image(path, raw=True)
        best, lp, kept0 = np.inf, None, np.nan
        for _ in range(passes):
            tracker = bc.LaserTracker(check=False, center=center, radius=radius)
            kept0 = float(np.mean(~tracker(img).flagged))
            lp, t = _cpu(tracker, img)
            best = min(best, t)
        out.append((pathlib.Path(path).stem, lp.tracked, kept0, float(np.mean(~lp.flagged)),
                    best, lp.note))
    return out


def _rendered(size, n, tmp):
    w, h = size
    paths, truths = [], []
    for i, (img, truth) in enumerate(bc.render_sequence(_sensor(w, h), bc.room_walls(2500), n,
                                                        shape=(h, w), rng=1)):
        path = tmp / f"render_{w}_{i:03d}.png"
        import imageio.v3 as iio

        iio.imwrite(path, img)
        paths.append(path)
        truths.append(truth.pixels)
    return paths, truths


def _write(path, lines):
    """Put ``lines`` between the markers in docs/performance.md's hand-kept section."""
    path = pathlib.Path(path)
    text = path.read_text().splitlines() if path.exists() else ["# Performance", ""]
    block = [BEGIN, *lines, END]
    if BEGIN in text and END in text:
        a, b = text.index(BEGIN), text.index(END)
        text[a:b + 1] = block
    else:
        head = "## Where the time goes"
        if head not in text:
            text += ["", head, ""]
        start = text.index(head)
        end = next((i for i in range(start + 1, len(text)) if text[i].startswith("## ")),
                   len(text))
        text[end:end] = [*block, ""]
    path.write_text("\n".join(text) + "\n")


def main(argv=None):
    """Run the benchmark; returns 0."""
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("pipe", nargs="?", help="folder of the real frames (ring_*.png)")
    ap.add_argument("--frames", type=int, default=30, help="rendered frames per size")
    ap.add_argument("--passes", type=int, default=3, help="tracker passes (min per frame)")
    ap.add_argument("--out", default="docs/performance.md")
    ap.add_argument("--no-write", action="store_true")
    ap.add_argument("--pipe-center", type=float, nargs=2, metavar=("U", "V"),
                    help="the real frames' ring centre, px (with --pipe-radius: development "
                    "rows while the full extractor refuses them; the folder's README: 430 295)")
    ap.add_argument("--pipe-radius", type=float, nargs=2, metavar=("LOW", "HIGH"),
                    help="the real frames' ring radius range, px (README: 170-260)")
    args = ap.parse_args(argv)
    load0 = os.getloadavg()[0]
    rows = ["| sequence | size | what | median ms / frame | p90 ms | target ms | verdict | notes |",
            "|---|---|---|---:|---:|---:|---|---|"]
    notes = []
    with tempfile.TemporaryDirectory() as tmp:
        tmp = pathlib.Path(tmp)
        for size in ((960, 720), (1232, 1028)):
            paths, truths = _rendered(size, args.frames, tmp)
            recs = _run(paths, args.passes, _reconstructor(*size), truths)
            r, n = _summary("rendered, moving sensor", size, recs)
            rows += r
            notes += n
        pipe = pathlib.Path(args.pipe) if args.pipe else None
        if pipe is not None and pipe.is_dir():
            paths = sorted(pipe.glob("ring_*.png"))
            if paths:
                recs = _run(paths, args.passes, _reconstructor(960, 720))
                r, n = _summary(f"real, {pipe.name}/ring_*.png", (960, 720), recs)
                rows += r
                notes += n
                if args.pipe_center and args.pipe_radius:
                    dev = _followed_from_itself(paths, args.pipe_center, args.pipe_radius,
                                                args.passes)
                    ts = [d[4] for d in dev if d[1]]
                    rows.append(
                        f"| real, each frame followed from itself (development) | 960x720 | "
                        f"tracker, check=False | {_ms(np.median(ts) if ts else np.nan)} | "
                        f"{_ms(np.max(ts) if ts else np.nan)} | <= 33 | not a target row | "
                        f"{len(ts)} of {len(dev)} followed; seeded by the unchecked full "
                        f"extraction with --center {args.pipe_center} --radius "
                        f"{args.pipe_radius} |")
                    notes.append("real frames followed from themselves (kept: the full "
                                 "extraction's -> the tracker's): " + ", ".join(
                                     f"{d[0]} {d[2]:.2f} -> {d[3]:.2f}"
                                     + ("" if d[1] else f" ({d[5]})") for d in dev))
                notes.append("real frames refused by the full extractor: " + (", ".join(
                    f"{r['name']} ({r['full'].reason.split(':')[0]})" for r in recs
                    if isinstance(r["full"], Exception)) or "none"))
        else:
            notes.append("real frames: no folder given (or not found); rows skipped")
    load1 = os.getloadavg()[0]
    print("\n".join(rows))
    print("\n".join(f"- {n}" for n in notes))
    print(f"load average (1 min): {load0:.1f} at the start, {load1:.1f} at the end, "
          f"{os.cpu_count()} cores")
    if not args.no_write:
        date = datetime.datetime.now(datetime.timezone.utc).strftime("%Y-%m-%d %H:%M")
        _write(args.out, [
            "**The ring tracker at video rate (issue 40)**: written by "
            f"`studies/bench_tracker.py` ({date} UTC, `{' '.join(sys.argv[1:]) or 'no args'}`, "
            f"load average {load0:.1f} -> {load1:.1f} on {os.cpu_count()} cores; CPU time "
            "per frame, one BLAS thread; the tracker's time is the minimum over "
            f"{args.passes} passes, the full extractor's one pass; PNG decoding timed apart).",
            "", *rows, "", *[f"- {n}" for n in notes], ""])
        print(f"wrote its section of {args.out}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
