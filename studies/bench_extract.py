"""Seconds per laser extraction of an 800x600 image (``bc.extract_laser``), on one core.

Renders one textured 2500-mm room with ours (``bc.render_image``, two lamps and a ghost) and
one with ``tests/image/renderer2.py``, then times the extraction ``--repeats`` times with and
without the laser-off image; prints the minimum and the median, and the machine's load.

Usage::

    python studies/bench_extract.py [--repeats 5]
"""

from __future__ import annotations

import argparse
import os
import pathlib
import sys
import time

import numpy as np

sys.path.insert(0, str(pathlib.Path(__file__).resolve().parents[1] / "tests" / "image"))

import bayescal as bc  # noqa: E402

__all__ = ["main"]


def _time(img, bg, repeats):
    out = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        bc.extract_laser(img, background=bg)
        out.append(time.perf_counter() - t0)
    return float(np.min(out)), float(np.median(out))


def main(argv=None):
    """Run the benchmark; returns 0."""
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--repeats", type=int, default=5)
    args = ap.parse_args(argv)
    from renderer2 import render2

    p = bc.SensorParams.paper()
    img, truth = bc.render_image(p, bc.room_walls(2500), n_lamps=2, ghost=0.3,
                                 with_background=True, rng=0)
    img2, bg2, _ = render2(p, range_mm=2500, rng=0)
    load = os.getloadavg()[0] if hasattr(os, "getloadavg") else float("nan")
    print(f"load average (1 min) at the start: {load:.1f}")
    for name, im, bg in (("ours", img, truth.background), ("renderer2", img2, bg2)):
        for label, b in (("laser-off image", bg), ("no laser-off image", None)):
            lo, med = _time(im, b, args.repeats)
            print(f"{name:9s} 800x600, {label:18s}: min {lo:.2f} s, median {med:.2f} s")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
