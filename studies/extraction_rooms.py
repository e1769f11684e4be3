"""Extraction study on hard rooms, from two renderers: ours and an independent one.

Renders each scenario with ``bc.render_image`` (ours) and with ``render2`` from
``tests/image/renderer2.py`` (written apart from ours: its own textures with rails and
posters, beam profile, lamps, vignetting and sensor noise), with and without the laser-off
image, extracts the laser with ``bc.extract_laser`` and scores the unflagged points along the
true ring's normal. Scenarios: textured walls at 2500 mm, a faint ring at 4000 mm, 5000 mm,
lamps on and off the ring, a red laser in a colour image, a 1280x1024 camera, a tilted laser,
a near room (1200 mm), and no ring at all (an ExtractionError is the right answer).

Writes ``extraction_rooms.json`` into ``--out``: per scenario and renderer, over seeds (and
per image, ``trials``), the kept fraction of the azimuths (degrees, away from lamps), robust
sd, bias, gross errors (> 1 px), z rms (error over the given sd, non-gross points), the
seconds per extraction, and how many images raised ExtractionError.

Usage::

    python studies/extraction_rooms.py --out out/extraction_rooms [--quick]
"""

from __future__ import annotations

import pathlib
import sys
import time

import numpy as np

HERE = pathlib.Path(__file__).resolve().parent
sys.path.insert(0, str(HERE))
sys.path.insert(0, str(HERE.parent / "tests" / "image"))       # renderer2.py, score.py

from _common import run_trials, study_main, write_json  # noqa: E402

import bayescal as bc  # noqa: E402

__all__ = ["main", "room_trial", "SCENARIOS"]

FILES = ("extraction_rooms.json",)
P = bc.SensorParams.paper()
CAM1280 = dict(alpha_u=90.0, alpha_v=-90.0, u0=640.0, v0=512.0)
TILT = dict(tilt_x=np.deg2rad(2.0), tilt_y=np.deg2rad(-1.5), offset_x=10.0, offset_y=-5.0)
#: name: (range mm, ours' options, renderer2's options, colour, camera 1280x1024, tilted)
SCENARIOS = {
    "textured_2500": (2500, {"n_lamps": 0}, {}, False, False, False),
    "faint_4000": (4000, {"laser_power": 2.5}, {"laser_peak": 45.0}, False, False, False),
    "far_5000": (5000, {}, {}, False, False, False),
    "lamps_2500": (2500, {"n_lamps": 4, "ghost": 0.3}, {"lamps": dict(on_ring=2, off_ring=2)},
                   False, False, False),
    "red_colour": (2500, {}, {"colour": "red"}, True, False, False),
    "cam1280": (2500, {}, {}, False, True, False),
    "tilted": (2500, {}, {}, False, False, True),
    "near_1200": (1200, {}, {}, False, False, False),
    "no_ring": (2500, {"laser_power": 0.0}, {"laser": False}, False, False, False),
}


def _render(spec, rng):
    """(image, laser-off image, truth, renderer) of one scenario."""
    range_mm, ours, other, colour, big, tilt = SCENARIOS[spec["scenario"]]
    p = bc.SensorParams(**{**P.as_dict(), **CAM1280}) if big else P
    pose = bc.LaserPose(**TILT) if tilt else None
    if spec["renderer"] == "renderer2":
        from renderer2 import render2

        return render2(p, range_mm=range_mm, image_size=(1280, 1024) if big else (800, 600),
                       laser_pose=pose, rng=rng, **other)
    img, truth = bc.render_image(p, bc.room_walls(range_mm), shape=(1024, 1280) if big else
                                 (600, 800), with_background=True, laser=pose, rng=rng, **ours)
    bg = truth.background
    if colour:                      # the laser in red; green and blue see the room only
        img, bg = np.stack([img, bg, bg], axis=-1), np.stack([bg, bg, bg], axis=-1)
    return img, bg, truth


def _errors(lp, truth, renderer):
    """Errors along the true ring's normal of the unflagged points (px), their given sds and
    the kept fraction of the degrees of azimuth (away from lamps)."""
    ok = ~lp.flagged
    if renderer == "renderer2":
        from score import score_extraction

        e = score_extraction(lp.pixels, truth, flagged=lp.flagged)["errors"]
        center, ring = truth.center, truth.pixels[truth.visible & ~truth.near_lamp]
    else:
        T = truth.pixels
        t = np.roll(T, -1, 0) - np.roll(T, 1, 0)
        t /= np.linalg.norm(t, axis=1)[:, None]
        k = np.argmin(np.sum((lp.pixels[ok][:, None, :] - T[None]) ** 2, -1), 1)
        e = np.sum((lp.pixels[ok] - T[k]) * np.stack([t[k, 1], -t[k, 0]], -1), 1)
        center, ring = lp.center, T
    deg = lambda xy: np.unique(np.floor(np.degrees(np.arctan2(  # noqa: E731
        xy[:, 1] - center[1], xy[:, 0] - center[0])) + 180).astype(int) % 360)
    kept = float(np.isin(deg(ring), deg(lp.pixels[ok])).mean())
    return e, lp.sd_normal[ok], kept


def room_trial(spec, rng):
    """Render one image of ``spec``'s scenario, extract it, return the statistics."""
    img, bg, truth = _render(spec, rng)
    t0 = time.perf_counter()
    try:
        lp = bc.extract_laser(img, background=bg if spec["background"] else None)
    except bc.ExtractionError as exc:
        return {**spec, "error": exc.reason, "seconds": time.perf_counter() - t0}
    sec = time.perf_counter() - t0
    e, sd, kept = _errors(lp, truth, spec["renderer"])
    on = np.isfinite(e)
    good = on & (np.abs(e) <= 1.0)
    med = float(np.median(e[on])) if on.any() else np.nan
    return {**spec, "error": None, "seconds": sec, "kept": kept,
            "robust_sd": float(1.4826 * np.median(np.abs(e[on] - med))) if on.any() else np.nan,
            "bias": float(np.mean(e[good])) if good.any() else np.nan,
            "gross": float(np.mean(~good)) if len(e) else np.nan,
            "z_rms": float(np.sqrt(np.mean((e[good] / sd[good]) ** 2))) if good.any() else np.nan}


def _specs(mode):
    n_seeds = {"full": 3, "quick": 1, "smoke": 1}[mode]
    names = ["faint_4000", "no_ring"] if mode == "smoke" else list(SCENARIOS)
    renderers = ["ours"] if mode == "smoke" else ["ours", "renderer2"]
    return [{"scenario": s, "renderer": r, "background": b, "seed_index": i}
            for s in names for r in renderers for b in (True, False) for i in range(n_seeds)]


def summarize(trials):
    """Mean over seeds per (scenario, renderer, laser-off image); errors counted."""
    keys = ("kept", "robust_sd", "bias", "gross", "z_rms", "seconds")
    groups = {}
    for t in trials:
        groups.setdefault((t["scenario"], t["renderer"], t["background"]), []).append(t)
    rows = []
    for (s, r, b), ts in groups.items():
        ok = [t for t in ts if t["error"] is None]
        row = {"scenario": s, "renderer": r, "background": b, "n_images": len(ts),
               "n_errors": len(ts) - len(ok), "errors": sorted({t["error"] for t in ts
                                                               if t["error"]})}
        row |= {k: float(np.nanmean([t[k] for t in ok])) if ok else None for k in keys}
        row["seconds"] = float(np.mean([t["seconds"] for t in ts]))
        rows.append(row)
    return rows


def run(args, out):
    trials = run_trials(room_trial, _specs(args.mode), seed=args.seed, workers=args.workers,
                        scheduler=args.scheduler)
    rows = summarize(trials)
    write_json(out / FILES[0], {"study": "extraction_rooms", "mode": args.mode,
                                "seed": args.seed, "rows": rows, "trials": trials})
    print("| scenario | renderer | laser-off | kept | robust sd | bias | gross | z rms | s |")
    for r in rows:
        bg = "yes" if r["background"] else "no"
        if r["kept"] is None:
            print(f"| {r['scenario']} | {r['renderer']} | {bg} | ExtractionError "
                  f"({r['n_errors']}/{r['n_images']}) | | | | | {r['seconds']:.2f} |")
            continue
        err = f" ({r['n_errors']} raised)" if r["n_errors"] else ""
        print(f"| {r['scenario']} | {r['renderer']} | {bg} | {r['kept']:.2f}{err} | "
              f"{r['robust_sd']:.2f} | {r['bias']:+.3f} | {100 * r['gross']:.1f} % | "
              f"{r['z_rms']:.2f} | {r['seconds']:.2f} |")


def main(argv=None):
    """Run the study; returns the exit code."""
    return study_main(run, "extraction_rooms: the extractor on hard rooms, two renderers",
                      argv, FILES)


if __name__ == "__main__":
    raise SystemExit(main())
