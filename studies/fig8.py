"""Fig. 8 of the paper: reconstruction error of the three calibrations, large room (5000 mm).

Eight trials, each with its own pixel noise, 3D-point noise and sensor (the
paper's parameters perturbed by half the default prior's sd); in a trial every
method sees the same data. The measured 3D points carry Gaussian noise on every
axis (``approx_model="gaussian"``, ``approx_error=0``, ``sigma_3d`` = 0.2 % or
0.5 % of the range). Errors: ``bc.reconstruction_error`` against the true
points of

* sequential: its parameters triangulating the room pixels;
* simultaneous: its jointly estimated points (and, for comparison, its
  parameters triangulating the pixels);
* Bayes: the posterior mean of the points.

Writes ``fig8.json`` and ``fig8.png`` (grouped bars per trial) into ``--out``.
See ``docs/studies.md``.

Usage::

    python studies/fig8.py --out out/fig8 [--quick] [--workers 2] [--scheduler ADDRESS]
"""

from __future__ import annotations

import pathlib
import sys

sys.path.insert(0, str(pathlib.Path(__file__).resolve().parent))

from _common import run_room_study  # noqa: E402

__all__ = ["main", "RANGE_MM"]

RANGE_MM = 5000.0


def main(argv=None):
    """Run the study; returns the exit code."""
    return run_room_study("fig8", RANGE_MM, argv)


if __name__ == "__main__":
    raise SystemExit(main())
