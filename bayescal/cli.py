"""The ``bayescal`` command line.

Exit codes: 0 success, 2 bad usage or bad input, 1 failure (e.g. no convergence).
"""

from __future__ import annotations

import argparse
import pathlib
import sys

__all__ = ["main"]


class UsageError(Exception):
    """Bad usage or bad input: exit code 2."""


def _prepare_out(out, force):
    out = pathlib.Path(out)
    if out.exists() and any(out.iterdir()) and not force:
        raise UsageError(f"output folder {out} exists and is not empty; pass --force to overwrite")
    out.mkdir(parents=True, exist_ok=True)
    return out


def cmd_demo(args):
    """Simulate the paper's large room and write the figures."""
    import matplotlib

    matplotlib.use("agg")
    import bayescal as bc
    from bayescal.plotting import plot_image, plot_room, savefig

    out = _prepare_out(args.out, args.force)
    ds = bc.simulate_room(range_mm=5000, sigma_px=0.1, approx_error=0.05, rng=args.seed)
    print(f"simulated {ds.n_points} laser points, range {ds.range_mm:.0f} mm, seed {args.seed}")
    paths = [
        savefig(plot_image(ds.pixels, params=ds.params), out / "image.png"),
        savefig(plot_room(ds.points, walls=ds.walls, approx_points=ds.approx_points),
                out / "room_top.png"),
        savefig(plot_room(ds.points, walls=ds.walls, view="3d"), out / "room_3d.png"),
    ]
    for p in paths:
        print(f"wrote {p}")
    return 0


def build_parser():
    parser = argparse.ArgumentParser(prog="bayescal", description=__doc__.splitlines()[0])
    sub = parser.add_subparsers(dest="command", required=True)
    p = sub.add_parser("demo", help="simulate the paper's large room and write plots into --out")
    p.add_argument("--out", default="out", help="output folder (default: out)")
    p.add_argument("--seed", type=int, default=0, help="random seed (default: 0)")
    p.add_argument("--force", action="store_true", help="overwrite a non-empty output folder")
    p.set_defaults(func=cmd_demo)
    return parser


def main(argv=None):
    """Run the command line; returns the exit code."""
    parser = build_parser()
    args = parser.parse_args(argv)
    try:
        return args.func(args)
    except UsageError as exc:
        print(f"bayescal: error: {exc}", file=sys.stderr)
        return 2
