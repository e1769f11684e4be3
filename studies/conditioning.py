"""Conditioning study: how much 3D error does one pixel of noise cause, against range?

(docs/model.md, "Conditioning".) With the paper's sensor the laser points image on a thin ring
(radius ~70-95 px) whose radial width shrinks as the room grows, so a fixed
pixel error turns into a depth error that grows roughly with range squared.

For each room size ``range_mm`` (walls 0.7-1.0 x range from the axis, the
paper's 7-wall room, 580 points) the script measures

* the mean 3D triangulation error (mm) for 1 px of isotropic Gaussian pixel
  noise, triangulating with the *true* parameters, to first order
  (central-difference Jacobian of ``triangulate`` w.r.t. the pixel, error
  ``|J e|`` averaged over ``e ~ N(0, I)`` and the points) and by Monte Carlo
  (mean and median over noise draws and points; rays that miss the cone are
  counted separately). The Monte-Carlo *mean* is heavy-tailed at large range:
  the distance along the ray is ``h tan(beta) / g`` with ``g`` the ray's
  margin from the cone's direction, and a noisy ray close to that direction
  lands arbitrarily far (``E[1/g]`` diverges), so that column jumps from seed
  to seed; the first-order mean and the median are the stable summaries;
* the radial pixel span of the laser ring, ``max - min`` of the pixel distance
  from the principal point (and the ring's inner/outer radius);
* the same first-order error for a single point at horizontal distance ``rho``
  (the error of one laser point, not a room average).

Writes ``conditioning.png`` and ``conditioning.json`` into ``--out``.
Imports only the public API of bayescal.

Usage::

    python studies/conditioning.py --out docs/img --seed 0 --force
"""

from __future__ import annotations

import json

import numpy as np

import bayescal as bc
from bayescal.cli.studyrun import study_main

SIGMA_PX = 1.0


def pixel_jacobian(params, pixels, *, step=1e-4):
    """d triangulate / d (u, v) by central differences, shape (N, 3, 2) in mm/px."""
    cols = []
    for k in range(2):
        d = np.zeros(2)
        d[k] = step
        cols.append((bc.triangulate(params, pixels + d) - bc.triangulate(params, pixels - d))
                    / (2 * step))
    return np.stack(cols, axis=-1)


def linear_error(jac, rng, *, n_draws=4000):
    """Mean of ``|J e|`` over ``e ~ N(0, SIGMA_PX^2 I)`` and over the points, mm."""
    e = rng.normal(0.0, SIGMA_PX, (n_draws, 1, 2))
    return float(np.linalg.norm(np.einsum("nij,snj->sni", jac, e), axis=-1).mean())


def room_row(params, range_mm, rng, *, n_rep):
    """All measurements for one room size."""
    ds = bc.simulate_room(params, range_mm=range_mm, sigma_px=0.0, rng=rng)
    pix = ds.pixels_true
    noisy = pix + rng.normal(0.0, SIGMA_PX, (n_rep,) + pix.shape)
    pts, valid = bc.triangulate(params, noisy, return_valid=True)
    err = np.linalg.norm(pts - ds.points, axis=-1)[valid]
    radius = np.linalg.norm(pix - [params.u0, params.v0], axis=-1)
    rho = np.hypot(ds.points[:, 0], ds.points[:, 1])
    return {
        "range_mm": float(range_mm),
        "rho_min_mm": float(rho.min()),
        "rho_max_mm": float(rho.max()),
        "mc_mean_error_mm": float(err.mean()),
        "mc_median_error_mm": float(np.median(err)),
        "mc_missed_fraction": float(1.0 - valid.mean()),
        "linear_mean_error_mm": linear_error(pixel_jacobian(params, pix), rng),
        "ring_radius_min_px": float(radius.min()),
        "ring_radius_max_px": float(radius.max()),
        "ring_radial_span_px": float(radius.max() - radius.min()),
    }


def point_curve(params, rhos, rng):
    """First-order mean error of single laser points at horizontal distance ``rho``."""
    out = []
    for rho in rhos:
        az = np.linspace(0.0, 2 * np.pi, 16, endpoint=False)
        pts = bc.cone_point(params, rho * np.column_stack([np.cos(az), np.sin(az)]))
        out.append(linear_error(pixel_jacobian(params, bc.project(params, pts)), rng))
    return out


def plot(rows, rhos, point_err, path):
    import matplotlib

    matplotlib.use("agg")
    import matplotlib.pyplot as plt

    r = np.array([row["range_mm"] for row in rows])
    fig, (ax1, ax2) = plt.subplots(1, 2, figsize=(11, 4.2))
    ax1.plot(r, [row["linear_mean_error_mm"] for row in rows], "s-",
             label="room mean, first order")
    ax1.plot(r, [row["mc_mean_error_mm"] for row in rows], "o", mfc="none",
             label="room mean, Monte Carlo (heavy-tailed)")
    ax1.plot(r, [row["mc_median_error_mm"] for row in rows], "^--",
             label="room median, Monte Carlo")
    ax1.plot(rhos, point_err, "k:", label="single point at distance rho, first order")
    ax1.set_xlabel("room range (mm)  /  point distance rho (mm)")
    ax1.set_ylabel("mean 3D error per 1 px noise (mm)")
    ax1.set_yscale("log")
    ax1.grid(True, which="both", alpha=0.3)
    ax1.legend(fontsize="small")
    ax1.set_title("Triangulation error per pixel of noise")
    ax2.plot(r, [row["ring_radial_span_px"] for row in rows], "o-", c="tab:green")
    ax2.set_xlabel("room range (mm)")
    ax2.set_ylabel("radial span of the laser ring (px)")
    ax2.set_yscale("log")
    ax2.set_yticks([1, 1.5, 2, 3, 4, 6, 8, 10], labels=["1", "1.5", "2", "3", "4", "6", "8", "10"])
    ax2.minorticks_off()
    ax2.grid(True, which="both", alpha=0.3)
    ax2.set_title("How much of the image a room uses")
    fig.suptitle("Paper's sensor (xi=1, 55 px, h=200 mm, beta=60 deg), 7-wall room, 580 points")
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


FILES = ("conditioning.png", "conditioning.json")


def _options(parser):
    parser.add_argument("--n-rep", type=int, default=None,
                        help="Monte-Carlo noise draws per room (default: 200, quick: 40)")


def run(args, out):
    """Measure the conditioning rows and the single-point curve; write the figure and JSON."""
    quick = args.mode != "full"
    n_rep = args.n_rep or (40 if quick else 200)
    params = bc.SensorParams.paper()
    ranges = np.arange(500.0, 6001.0, 1000.0 if quick else 250.0)
    seeds = np.random.SeedSequence(args.seed).spawn(len(ranges) + 1)
    rows = [room_row(params, r, np.random.default_rng(s), n_rep=n_rep)
            for r, s in zip(ranges, seeds[:-1], strict=True)]
    rhos = np.linspace(300.0, 6000.0, 20 if quick else 58)
    point_err = point_curve(params, rhos, np.random.default_rng(seeds[-1]))
    print(f"{'range':>6} {'1st ord':>9} {'MC mean':>9} {'MC med':>8} {'missed':>7} "
          f"{'ring (px)':>15} {'span':>6}")
    for row in rows:
        print(f"{row['range_mm']:6.0f} {row['linear_mean_error_mm']:9.1f} "
              f"{row['mc_mean_error_mm']:9.1f} {row['mc_median_error_mm']:8.1f} "
              f"{row['mc_missed_fraction']:7.1e} "
              f"{row['ring_radius_min_px']:7.2f}-{row['ring_radius_max_px']:6.2f} "
              f"{row['ring_radial_span_px']:6.2f}")
    plot(rows, rhos, point_err, out / "conditioning.png")
    result = {
        "description": "mean 3D triangulation error (mm) per 1 px of Gaussian pixel noise, "
                       "paper's sensor, true parameters; ring = pixel distance from (u0, v0)",
        "params": params.as_dict(), "sigma_px": SIGMA_PX, "seed": args.seed,
        "n_rep": n_rep, "mode": args.mode, "rooms": rows,
        "single_point": {"rho_mm": rhos.tolist(), "linear_mean_error_mm": point_err},
    }
    (out / "conditioning.json").write_text(json.dumps(result, indent=1))


def main(argv=None):
    """Command line entry point (the shared study runner's options plus ``--n-rep``)."""
    return study_main(run, __doc__.splitlines()[0], argv, FILES, add_arguments=_options)


if __name__ == "__main__":
    raise SystemExit(main())
