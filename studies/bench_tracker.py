"""The ring tracker at video rate: ms per frame on one core, the full extractor timed in
the same run (issue 40).

Sequences:

* a rendered sensor moving through a textured 2500-mm room (``bc.render_sequence``) at
  960x720 and 1232x1028, ``--frames`` frames each;
* with the folder of the real frames (``pipe/``): its ``ring_*.png`` as one sequence in the
  order of their names (the sensor moved between them, mostly by 20-90 px: the tracker must
  lose the ring and fall back), and real-like sequences: each real frame moved by small
  shifts and turns (:func:`real_like`: up to ``--step`` px and 0.3 degrees a frame, cubic
  interpolation, fresh noise of 1 grey level, back to 8 bit), ``--real-like`` frames each.

Every frame is written as PNG and read back, so that decoding is timed apart. Per frame, CPU
time (``time.process_time``, BLAS on one thread): decoding (``bc.read_image``), the full
extractor (``bc.extract_laser``, one pass), the tracker (``bc.LaserTracker``, the minimum
over ``--passes`` passes over the sequence), and the reconstruction of its unflagged pixels
with error bars by a calibration of that image size (``bc.calibrate_simultaneous`` on a
simulated room, then its prepared ``Reconstructor``). Targets: the tracker <= 33 ms per
960x720 frame and <= 50 ms per 1232x1028 frame, extraction + reconstruction <= 40 ms, the
full extractor <= 1 s. Each followed frame is compared with the full extractor's
extraction of it, point by point (``agreement`` of ``tests/image/score.py``): the fraction
of the points both keep within 0.1 px along the normal, of their sds within 20 %, of the
flags that agree; rendered frames are also scored against the true centre line. Writes its
section of docs/performance.md (inside "Where the time goes", which ``studies/benchmark.py``
keeps).

Usage::

    OPENBLAS_NUM_THREADS=1 python studies/bench_tracker.py [../shared/data/pipe]
        [--frames 30] [--passes 3] [--real-like 8] [--out docs/performance.md] [--no-write]
"""

from __future__ import annotations

import argparse
import datetime
import os
import pathlib
import sys
import tempfile
import time

import imageio.v3 as iio
import numpy as np
from scipy.ndimage import affine_transform

import bayescal as bc

sys.path.insert(0, str(pathlib.Path(__file__).resolve().parents[1] / "tests" / "image"))
from score import agreement  # noqa: E402

__all__ = ["main", "real_like"]

#: ms per tracked frame, by image size; extraction + reconstruction; the full extractor
TARGETS = {(960, 720): 33.0, (1232, 1028): 50.0}
RECON_TARGET_MS = 40.0
FULL_TARGET_MS = 1000.0
BEGIN, END = "<!-- bench_tracker: begin -->", "<!-- bench_tracker: end -->"


def real_like(image, n, *, rng=None, step_px=1.5, turn_deg=0.3, noise=1.0):
    """``n`` frames of a real frame moved as a sensor at video rate moves its ring: smooth
    shifts of up to ``step_px`` px a frame and turns of up to ``turn_deg`` degrees about the
    image's centre (cubic interpolation), fresh noise of ``noise`` grey levels sd, back to
    8 bit (the first frame too, unmoved: a dark frame's black is noiseless, and the ring's
    SNR would drop tenfold at the second)."""
    rng = np.random.default_rng(rng)
    img = np.asarray(image)[..., :3].astype(float)
    H, W = img.shape[:2]
    ph = rng.uniform(0, 2 * np.pi, 3)
    t = np.arange(n)
    dx = step_px * 20 / (2 * np.pi) * (np.sin(2 * np.pi * t / 20 + ph[0]) - np.sin(ph[0]))
    dy = step_px * 26 / (2 * np.pi) * (np.sin(2 * np.pi * t / 26 + ph[1]) - np.sin(ph[1]))
    th = np.radians(turn_deg) * 30 / (2 * np.pi) * (np.sin(2 * np.pi * t / 30 + ph[2])
                                                     - np.sin(ph[2]))
    mid = np.array([(H - 1) / 2, (W - 1) / 2])
    out = []
    for k in range(n):
        rot = np.array([[np.cos(th[k]), -np.sin(th[k])], [np.sin(th[k]), np.cos(th[k])]])
        off = mid - rot @ (mid + np.array([dy[k], dx[k]]))
        moved = np.stack([affine_transform(img[..., ch], rot, offset=off, order=3,
                                           mode="nearest") for ch in range(3)], -1)
        moved += rng.normal(0.0, noise, moved.shape)
        out.append(np.clip(np.rint(moved), 0, 255).astype(np.uint8))
    return out


def _sensor(width, height):
    """A sensor whose ring spans about 60 % of the image's half-height (the real pipe
    frames' rings: radius 210-250 px in 960x720)."""
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


def _agree(lp, full):
    """Per frame: points kept by both, the fractions within 0.1 px, sds within 20 %, flags
    the same (over the paired points), and the differences."""
    a = agreement(lp, full)
    paired = a["pairs"] + a["only_a"] + a["only_b"]
    return dict(pairs=a["pairs"], diff=a["diff_px"], ratio=a["sd_ratio"],
                within=float(np.mean(a["diff_px"] <= 0.1)) if a["pairs"] else np.nan,
                sd20=float(np.mean(np.abs(np.log(a["sd_ratio"])) <= np.log(1.2)))
                if a["pairs"] else np.nan,
                flags=1.0 - (a["only_a"] + a["only_b"]) / max(paired, 1),
                same_rays=len(lp) == len(full) and np.array_equal(lp.center, full.center))


def _run(paths, passes, recon, truths=None):
    """Time one sequence of PNG files; returns the per-frame records."""
    frames, recs = [], []
    for path in paths:
        img, t = _cpu(bc.read_image, path, raw=True)
        frames.append(img)
        try:
            full, tf = _cpu(bc.extract_laser, img)
        except bc.ExtractionError as exc:
            full, tf = exc, np.nan
        recs.append(dict(name=pathlib.Path(path).stem, decode=t, full=full, full_s=tf,
                         track_s=np.inf, recon_s=np.inf))
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
            rec["agree"] = _agree(lp, full)
            if truths is not None:
                rec["err"] = (_truth_error(lp, truths[i]), _truth_error(full, truths[i]))
    return recs


def _ms(x):
    return f"{1e3 * x:.1f}" if np.isfinite(x) else "-"


def _verdict(value_s, target_ms):
    return "PASS" if value_s * 1e3 <= target_ms else "FAIL"


def _summary(name, size, recs):
    """Table rows (list of str) and notes for one sequence."""
    tracked = [r for r in recs if r["lp"].tracked]
    refused = [r for r in recs if isinstance(r["full"], Exception)]
    full_s = np.array([r["full_s"] for r in recs if np.isfinite(r["full_s"])])
    dec = np.array([r["decode"] for r in recs])
    w, h = size
    target = TARGETS.get(size, TARGETS[(1232, 1028)])
    n_note = f"{len(tracked)} of {len(recs)} frames followed"
    rows = [f"| {name} | {w}x{h} | full extractor (`extract_laser`) | "
            f"{_ms(np.median(full_s))} | {_ms(np.max(full_s))} | <= {FULL_TARGET_MS:g} | "
            f"{_verdict(np.median(full_s), FULL_TARGET_MS)} | {len(full_s)} frames, "
            f"{len(refused)} refused |"]
    if not tracked:
        return rows + [f"| {name} | {w}x{h} | tracker | - | - | <= {target:g} | not timed | "
                       f"{n_note} |"], []
    ts = np.array([r["track_s"] for r in tracked])
    rows.append(f"| {name} | {w}x{h} | tracker, decoded frame | {_ms(np.median(ts))} | "
                f"{_ms(np.percentile(ts, 90))} | <= {target:g} | "
                f"{_verdict(np.median(ts), target)} | {n_note} |")
    both = ts + np.array([r["decode"] for r in tracked])
    rows.append(f"| {name} | {w}x{h} | tracker + PNG decoding (`read_image`) | "
                f"{_ms(np.median(both))} | {_ms(np.percentile(both, 90))} | <= {target:g} | "
                f"{_verdict(np.median(both), target)} | decoding {_ms(np.median(dec))} ms |")
    rc = np.array([r["recon_s"] for r in tracked])
    if np.all(np.isfinite(rc)):
        tot = ts + rc
        rows.append(f"| {name} | {w}x{h} | tracker + reconstruction with error bars | "
                    f"{_ms(np.median(tot))} | {_ms(np.percentile(tot, 90))} | "
                    f"<= {RECON_TARGET_MS:g} | {_verdict(np.median(tot), RECON_TARGET_MS)} | "
                    f"reconstruction {_ms(np.median(rc))} ms (`Reconstructor`, first order) |")
    every = np.array([r["track_s"] for r in recs])
    notes = [f"{name} {w}x{h}: {n_note}; mean over every frame, fallbacks included, "
             f"{_ms(np.mean(every))} ms"]
    lost = [f"{r['name']} ({r['lp'].note})" for r in recs if not r["lp"].tracked]
    if lost and len(lost) <= 10:
        notes.append(f"{name}: extracted afresh: " + "; ".join(lost))
    return rows, notes + _agreement_notes(f"{name} {w}x{h}", tracked)


def _agreement_notes(name, tracked):
    agreed = [r["agree"] for r in tracked if "agree" in r]
    if not agreed:
        return []
    d = np.concatenate([a["diff"] for a in agreed])
    s = np.concatenate([a["ratio"] for a in agreed])
    sd20 = 100 * np.mean(np.abs(np.log(s)) <= np.log(1.2))
    worst = {k: 100 * min(a[k] for a in agreed) for k in ("within", "sd20", "flags")}
    flags = 100 * np.mean([a["flags"] for a in agreed])
    out = [f"{name}: agreement with the full extractor over {len(agreed)} followed frames, "
           f"{len(d)} points kept by both: within 0.1 px {100 * np.mean(d <= 0.1):.2f} % "
           f"(worst frame {worst['within']:.1f} %), largest {d.max():.3f} px; sds within "
           f"20 % {sd20:.2f} % (worst frame {worst['sd20']:.1f} %), sd ratio median "
           f"{np.median(s):.3f}; flags the same {flags:.2f} % (worst frame "
           f"{worst['flags']:.1f} %); the same profiles on "
           f"{sum(a['same_rays'] for a in agreed)} of {len(agreed)} frames"]
    errs = [r["err"] for r in tracked if "err" in r]
    if errs:
        et = np.concatenate([e[0] for e in errs])
        ef = np.concatenate([e[1] for e in errs])
        out.append(f"{name}: error against the true centre line (unflagged points): tracker "
                   f"median {np.median(et):.3f} px, gross (> 1 px) {100 * np.mean(et > 1):.2f} "
                   f"%; full extractor median {np.median(ef):.3f} px, gross "
                   f"{100 * np.mean(ef > 1):.2f} %")
    return out


def _rendered(size, n, tmp):
    w, h = size
    paths, truths = [], []
    for i, (img, truth) in enumerate(bc.render_sequence(_sensor(w, h), bc.room_walls(2500), n,
                                                        shape=(h, w), rng=1)):
        path = tmp / f"render_{w}_{i:03d}.png"
        iio.imwrite(path, img)
        paths.append(path)
        truths.append(truth.pixels)
    return paths, truths


def _real_like_paths(pipe, n, step, tmp):
    """Real-like sequences of every ring_*.png, written as PNG; one list per frame."""
    out = []
    for j, src in enumerate(sorted(pipe.glob("ring_*.png"))):
        seq = []
        for i, img in enumerate(real_like(bc.read_image(src, raw=True), n, rng=j,
                                          step_px=step)):
            path = tmp / f"{src.stem}_like_{i:03d}.png"
            iio.imwrite(path, img)
            seq.append(path)
        out.append(seq)
    return out


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


def _real(pipe, args, tmp):
    """Rows and notes of the real frames: the named sequence, then the real-like ones."""
    rows, notes = [], []
    paths = sorted(pipe.glob("ring_*.png"))
    if not paths:
        return rows, [f"real frames: no ring_*.png in {pipe}"]
    recon = _reconstructor(960, 720)
    recs = _run(paths, args.passes, recon)
    r, n = _summary(f"real, {pipe.name}/ring_*.png in name order", (960, 720), recs)
    rows += r
    notes += n
    if args.real_like > 1:
        recs = []
        for seq in _real_like_paths(pipe, args.real_like, args.step, tmp):
            recs += _run(seq, args.passes, recon)
        r, n = _summary(f"real-like: each ring_*.png moved {args.step:g} px, 0.3 deg a frame "
                        f"({args.real_like} frames)", (960, 720), recs)
        rows += r
        notes += n
    return rows, notes


def main(argv=None):
    """Run the benchmark; returns 0."""
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("pipe", nargs="?", help="folder of the real frames (ring_*.png)")
    ap.add_argument("--frames", type=int, default=30, help="rendered frames per size")
    ap.add_argument("--passes", type=int, default=3, help="tracker passes (min per frame)")
    ap.add_argument("--real-like", type=int, default=8,
                    help="frames of each real-like sequence (0: none)")
    ap.add_argument("--step", type=float, default=1.5, help="real-like motion, px a frame")
    ap.add_argument("--out", default="docs/performance.md")
    ap.add_argument("--no-write", action="store_true")
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
            r, n = _real(pipe, args, tmp)
            rows += r
            notes += n
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
