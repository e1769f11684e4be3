"""The ``bayescal`` command line: simulate, calibrate, reconstruct, report, study, demo.

Run ``bayescal --help`` or ``bayescal COMMAND --help``; ``docs/cli.md`` has a
worked example and the file formats.

Exit codes: 0 success; 2 bad usage or bad input (nothing is written); 1 failure,
such as a calibration that did not converge (outputs written for diagnosis).

Output folders: a command refuses a non-empty ``--out`` unless ``--force`` is
given, and even then it only replaces files that bayescal wrote there itself
(listed in ``.bayescal-output.json``); it never writes into a folder that holds
one of its input files.
"""

from __future__ import annotations

import argparse
import os
import pathlib
import re
import shlex
import subprocess
import sys

import numpy as np

__all__ = ["main", "build_parser", "UsageError", "Failure"]

MANIFEST = ".bayescal-output.json"
METHODS = ("sequential", "simultaneous", "bayes")


class UsageError(Exception):
    """Bad usage or bad input: exit code 2."""


class Failure(Exception):
    """The job ran but failed (e.g. no convergence): exit code 1."""


# -- output folders ------------------------------------------------------------

def _is_inside(path, folder):
    try:
        pathlib.Path(path).resolve().relative_to(pathlib.Path(folder).resolve())
        return True
    except ValueError:
        return False


def check_out(out, *, force, inputs=()):
    """Check that ``out`` may be written (nothing is created here).

    Raises
    ------
    UsageError
        ``out`` is a file; it holds an input file; it is not empty and
        ``force`` is False; or it is not empty, ``force`` is True but it was not
        written by bayescal (no manifest).
    """
    out = pathlib.Path(out)
    if out.exists() and not out.is_dir():
        raise UsageError(f"--out {out} is a file; expected a folder")
    for p in inputs:
        if p is not None and _is_inside(p, out):
            raise UsageError(f"refusing to write into {out}: it holds the input file {p}; "
                             "choose another --out (bayescal never writes next to your data)")
    if out.is_dir() and any(out.iterdir()):
        if not force:
            raise UsageError(f"output folder {out} exists and is not empty; pass --force to "
                             "replace what bayescal wrote there, or choose another --out")
        if not (out / MANIFEST).is_file():
            raise UsageError(f"output folder {out} is not empty and was not written by bayescal "
                             f"(no {MANIFEST}); --force only replaces bayescal's own outputs: "
                             "choose an empty or new folder")
    return out


class OutputFolder:
    """A folder bayescal writes into; remembers its files in a manifest.

    Opening it with ``force`` deletes the files listed in the previous
    manifest (and only those).
    """

    def __init__(self, out):
        from .io import read_json

        self.path = pathlib.Path(out)
        old = self.path / MANIFEST
        if old.is_file():
            for name in read_json(old).get("files", []):
                f = self.path / name
                if _is_inside(f, self.path) and f.is_file():
                    f.unlink()
            for d in sorted((p for p in self.path.rglob("*") if p.is_dir()), reverse=True):
                if not any(d.iterdir()):
                    d.rmdir()
        self.path.mkdir(parents=True, exist_ok=True)
        self.files = []
        self.save()

    def add(self, *paths):
        """Record written files (paths inside the folder); returns the first one."""
        for p in paths:
            self.files.append(str(pathlib.Path(p).resolve().relative_to(self.path.resolve())))
        self.save()
        return paths[0] if paths else None

    def save(self):
        from .io import write_json

        write_json(self.path / MANIFEST, {"written_by": "bayescal", "files": self.files})


# -- argument helpers ------------------------------------------------------------

def _image_size(args):
    from .io import parse_image_size

    try:
        size = parse_image_size(args.image_size)
    except ValueError as exc:
        raise UsageError(f"--image-size: {exc}") from None
    if not (np.isfinite(args.image_margin) and args.image_margin >= 0):
        raise UsageError(f"--image-margin must be a non-negative number of px, "
                         f"got {args.image_margin}")
    return size


def _positive(text, option):
    try:
        v = float(text)
    except ValueError:
        raise UsageError(f"{option}: could not read {text!r} as a number") from None
    if not (np.isfinite(v) and v > 0):
        raise UsageError(f"{option} must be a finite positive number, got {text!r}")
    return v


def _sigma_px(args, data):
    """--sigma-px: a number, 'infer', or (default) the file's sigma_px, else 'infer'."""
    text = args.sigma_px
    if text is None:
        return data.sigma_px, ("from the file" if data.sigma_px is not None else "inferred")
    if text.lower() == "infer":
        return None, "inferred"
    return _positive(text, "--sigma-px"), "given"


def _sigma_scene(args, data):
    """--sigma-scene: mm, 'sx,sy,sz', 'P%' (of the horizontal range), 'infer', or the file."""
    text = args.sigma_scene
    if text is None:
        if data.sigma_scene is not None:
            return data.sigma_scene, "per point and axis, from the file's sigma_x/y/z columns"
        return None, "inferred (relative to each point's horizontal range)"
    t = text.strip().lower()
    if t == "infer":
        return None, "inferred (relative to each point's horizontal range)"
    if t.endswith("%"):
        frac = _positive(t[:-1], "--sigma-scene") / 100.0
        rho = np.hypot(data.approx_points[:, 0], data.approx_points[:, 1])
        return np.repeat((frac * rho)[:, None], 3, axis=1), f"{text} of each point's range"
    parts = t.split(",")
    if len(parts) not in (1, 3):
        raise UsageError(f"--sigma-scene must be 'infer', a number of mm, 'sx,sy,sz' or a "
                         f"percentage like '5%', got {text!r}")
    vals = []
    for p in parts:
        vals.append(np.inf if p.strip() == "inf" else _positive(p, "--sigma-scene"))
    if not np.any(np.isfinite(vals)):
        raise UsageError(f"--sigma-scene {text!r} gives no information on any axis")
    return np.broadcast_to(np.array(vals), (data.n_points, 3)).copy(), f"{text} mm"


_PRIOR_RE = re.compile(r"^\s*(\w+)\s*=\s*(\w+)\s*\((.*)\)\s*$")


def _priors(args):
    """Parse --nominal and --prior NAME=DIST(args) into (nominal, prior dict or None)."""
    from scipy import stats

    from .io import read_json
    from .parameters import PARAM_NAMES, SensorParams

    nominal = SensorParams.paper()
    if args.nominal:
        raw = read_json(args.nominal)
        raw = raw.get("params", raw)
        missing = [n for n in PARAM_NAMES if n not in raw]
        if missing:
            raise UsageError(f"--nominal {args.nominal}: missing parameter(s) "
                             f"{', '.join(missing)}; expected all of {', '.join(PARAM_NAMES)}")
        try:
            nominal = SensorParams(**{n: raw[n] for n in PARAM_NAMES})
        except (TypeError, ValueError) as exc:
            raise UsageError(f"--nominal {args.nominal}: {exc}") from None
    overrides = {}
    for spec in args.prior or []:
        m = _PRIOR_RE.match(spec)
        if not m:
            raise UsageError(f"--prior {spec!r}: expected NAME=DIST(ARGS), e.g. "
                             "'h=norm(200, 20)' or 'beta=uniform(0.9, 0.3)'")
        name, dist, argtext = m.groups()
        if name not in PARAM_NAMES:
            raise UsageError(f"--prior {spec!r}: unknown parameter {name!r}; expected one of "
                             f"{', '.join(PARAM_NAMES)}")
        family = getattr(stats, dist, None)
        if not isinstance(family, stats.rv_continuous):
            raise UsageError(f"--prior {spec!r}: {dist!r} is not a scipy.stats continuous "
                             "distribution (e.g. norm, uniform, truncnorm, lognorm)")
        try:
            vals = [float(a) for a in argtext.split(",") if a.strip()]
            overrides[name] = family(*vals)
            overrides[name].std()
        except (TypeError, ValueError) as exc:
            raise UsageError(f"--prior {spec!r}: bad arguments for {dist} ({exc})") from None
    if not args.nominal and not overrides:
        return nominal, None
    from .priors import default_prior

    prior = default_prior(nominal)
    prior.update(overrides)
    return nominal, prior


def _load_truth(path):
    if path is None:
        return None
    from .io import read_json

    truth = read_json(path)
    if "params" not in truth:
        raise UsageError(f"--truth {path}: expected a JSON object with 'params' (as written by "
                         "bayescal simulate)")
    return truth


# -- simulate --------------------------------------------------------------------

def _simulate_dataset(args):
    import bayescal as bc

    try:
        return bc.simulate_room(range_mm=args.range_mm, n_points=args.n_points,
                                n_walls=args.n_walls, sigma_px=args.sigma_px,
                                approx_error=args.approx_error, sigma_3d=args.sigma_3d,
                                approx_model=args.approx_model, rng=args.seed)
    except (TypeError, ValueError) as exc:
        raise UsageError(str(exc)) from None


def write_simulation(folder, ds, *, seed):
    """Write a simulated dataset as the files the other commands read.

    Files: ``laser.csv`` and ``laser.npz`` (u, v, x, y, z, sigma_x/y/z, sigma_px),
    ``calibration.npz`` (CalibrationData fields), ``grid.csv`` and
    ``calib_laser.csv`` (the same in CSV), ``truth.json`` (true parameters,
    points and walls, settings).
    """
    from dataclasses import asdict

    from .io import _write_csv, write_calibration_npz, write_json, write_laser_csv, write_laser_npz

    p = folder.path
    note = (f"bayescal simulate: range {ds.range_mm:g} mm, {ds.n_points} points, sigma_px "
            f"{ds.sigma_px:g}, approx_error {ds.approx_error:g} ({ds.approx_model}), seed {seed}\n"
            "u, v: laser pixel (px); x, y, z: approximate point (mm, frame C); sigma_*: its sd "
            "(mm, inf = no information); sigma_px: pixel noise (px)")
    folder.add(write_laser_csv(p / "laser.csv", ds.pixels, ds.approx_points,
                               sigma_scene=ds.sigma_scene, sigma_px=ds.sigma_px,
                               header_comment=note))
    folder.add(write_laser_npz(p / "laser.npz", ds.pixels, ds.approx_points,
                               sigma_scene=ds.sigma_scene, sigma_px=ds.sigma_px))
    cal = ds.calibration
    folder.add(write_calibration_npz(p / "calibration.npz", cal))
    _write_csv(p / "grid.csv", {"plane": cal.grid_plane, "u": cal.grid_pixels[:, 0],
                                "v": cal.grid_pixels[:, 1], "x": cal.grid_points[:, 0],
                                "y": cal.grid_points[:, 1], "z": cal.grid_points[:, 2]})
    _write_csv(p / "calib_laser.csv", {"plane": cal.laser_plane, "u": cal.laser_pixels[:, 0],
                                       "v": cal.laser_pixels[:, 1]})
    folder.add(p / "grid.csv", p / "calib_laser.csv")
    settings = {k: v for k, v in asdict(ds).items()
                if k in ("sigma_px", "sigma_3d", "approx_error", "range_mm", "approx_model")}
    folder.add(write_json(p / "truth.json", {
        "params": ds.params.as_dict(), "nominal": ds.nominal.as_dict(), "points": ds.points,
        "pixels_true": ds.pixels_true, "walls": ds.walls, "settings": settings, "seed": seed,
        "n_points": ds.n_points}))
    return [p / n for n in ("laser.csv", "laser.npz", "calibration.npz", "grid.csv",
                            "calib_laser.csv", "truth.json")]


def cmd_simulate(args):
    """Simulate a room and write the input files for ``calibrate``."""
    ds = _simulate_dataset(args)
    check_out(args.out, force=args.force)
    folder = OutputFolder(args.out)
    for f in write_simulation(folder, ds, seed=args.seed):
        print(f"wrote {f}")
    return 0


# -- calibrate -------------------------------------------------------------------

def _load_inputs(args):
    """Read and validate every input of ``calibrate`` before anything is written."""
    from .io import (
        check_pixels_in_image,
        check_projection_domain,
        load_calibration_data,
        load_laser_data,
    )

    size = _image_size(args)
    nominal, prior = _priors(args)
    data = calib = None
    if args.method != "sequential" and args.data is None:
        raise UsageError(f"calibrate --method {args.method} needs the laser data file "
                         "(u, v, x, y, z)")
    if args.method == "sequential":
        if args.calibration is None:
            raise UsageError("calibrate --method sequential needs --calibration FILE (NPZ of "
                             "the calibration planes, or grid CSV with --calibration-laser)")
        calib = load_calibration_data(args.calibration, args.calibration_laser)
    if args.data is not None:
        data = load_laser_data(args.data, args.points, need_points=args.method != "sequential")
        check_pixels_in_image(data.pixels, data.pixel_table, image_size=size,
                              margin=args.image_margin)
        if data.approx_points is not None:
            check_projection_domain(data.approx_points, data.point_table, nominal)
    truth = _load_truth(args.truth)
    inputs = [args.data, args.points, args.calibration, args.calibration_laser, args.nominal,
              args.truth]
    check_out(args.out, force=args.force, inputs=inputs)
    return {"data": data, "calib": calib, "nominal": nominal, "prior": prior, "truth": truth,
            "image_size": size,
            "inputs": {k: (str(pathlib.Path(v).resolve()) if v else None) for k, v in
                       zip(("data", "points", "calibration", "calibration_laser", "nominal",
                            "truth"), inputs, strict=True)}}


def _points_csv(path, points, cov):
    from .io import _write_csv

    sd = np.sqrt(np.maximum(np.diagonal(cov, axis1=1, axis2=2), 0))
    _write_csv(path, {"x": points[:, 0], "y": points[:, 1], "z": points[:, 2],
                      "sd_x": sd[:, 0], "sd_y": sd[:, 1], "sd_z": sd[:, 2],
                      "cov_xy": cov[:, 0, 1], "cov_xz": cov[:, 0, 2], "cov_yz": cov[:, 1, 2]})
    return path


def _read_points_csv(path):
    from .io import read_table

    t = read_table(path, required=("x", "y", "z", "sd_x", "sd_y", "sd_z", "cov_xy", "cov_xz",
                                   "cov_yz"))
    c = t.columns
    pts = np.column_stack([c["x"], c["y"], c["z"]])
    cov = np.empty((len(t), 3, 3))
    for i, a in enumerate("xyz"):
        cov[:, i, i] = c[f"sd_{a}"] ** 2
    cov[:, 0, 1] = cov[:, 1, 0] = c["cov_xy"]
    cov[:, 0, 2] = cov[:, 2, 0] = c["cov_xz"]
    cov[:, 1, 2] = cov[:, 2, 1] = c["cov_yz"]
    return pts, cov


def _run_least_squares(method, inp, opts):
    import bayescal as bc

    from .report import result_summary

    data = inp["data"]
    kw = {}
    if inp["prior"] is not None or inp["nominal"] != _paper():
        kw["init"] = inp["nominal"]
    if method == "sequential":
        # only an explicit --sigma-px describes the pattern pixels; the laser file's
        # sigma_px is about the room's laser pixels (the method estimates its own)
        if opts["sigma_px_how"] == "given":
            kw["sigma_px"] = opts["sigma_px"]
        result = bc.calibrate_sequential(inp["calib"], **kw)
    else:
        result = bc.calibrate_simultaneous(data.pixels, data.approx_points,
                                           sigma_px=opts["sigma_px"],
                                           sigma_scene=opts["sigma_scene"],
                                           prior=inp["prior"], **kw)
    prior = None
    if method == "simultaneous":
        from .priors import default_prior

        prior = default_prior(inp["nominal"])
        prior.update(inp["prior"] or {})
    return result, result_summary(result, prior=prior), _result_points(result, data, opts)


def _result_points(result, data, opts):
    """(points for residuals, (recon points, covariances)) of a least-squares result."""
    from .report import linear_reconstruction

    if data is None:
        return None, None
    cov = result.extras.get("point_covariance") if result.points is not None else None
    if cov is not None and np.shape(cov) == (data.n_points, 3, 3):
        return result.points, (result.points, np.asarray(cov))
    spx = opts["sigma_px"] or result.sigma_px_estimated or 0.0
    recon = linear_reconstruction(result.params, result.covariance_identifiable, data.pixels,
                                  spx)
    return (result.points if result.points is not None else recon[0]), recon


def _paper():
    from .parameters import SensorParams

    return SensorParams.paper()


def _run_bayes(inp, opts, args):
    import bayescal as bc

    data = inp["data"]
    kw = {}
    if args.max_steps is not None:
        kw["max_steps"] = args.max_steps
    if inp["nominal"] != _paper():
        kw["init"] = inp["nominal"]
    post = bc.sample_posterior(data.pixels, data.approx_points, sigma_px=opts["sigma_px"],
                               sigma_scene=opts["sigma_scene"], prior=inp["prior"],
                               rng=args.seed, progress=not args.no_progress, **kw)
    return post


def run_calibration(args, inp, folder, *, title=None):
    """Calibrate with ``args.method`` and write summary, points, posterior and the report.

    Returns
    -------
    int
        Exit code: 0, or 1 when the calibration did not converge.
    """
    from .io import write_json
    from .report import posterior_summary, write_report

    data = inp["data"]
    out = folder.path
    spx, spx_how = _sigma_px(args, data) if data is not None else (None, "not used")
    ssc, ssc_how = (_sigma_scene(args, data) if data is not None and data.approx_points
                    is not None else (None, "not used"))
    opts = {"sigma_px": spx, "sigma_px_how": spx_how, "sigma_scene": ssc}
    posterior = None
    failed = None
    from .results import ConvergenceError

    if args.method == "bayes":
        posterior = _run_bayes(inp, opts, args)
        folder.add(posterior.save(out / "posterior.npz", overwrite=True))
        summary = posterior_summary(posterior)
        points, recon = posterior.point_mean, (posterior.point_mean, posterior.point_covariance)
        if not posterior.converged and not args.allow_unconverged:
            failed = ("the posterior sampler did not converge (chains shorter than 50 "
                      "autocorrelation times); outputs written for diagnosis. Run longer "
                      "(--max-steps) or pass --allow-unconverged")
    else:
        try:
            result, summary, (points, recon) = _run_least_squares(args.method, inp, opts)
        except ConvergenceError as exc:
            if exc.result is None:
                raise Failure(f"{args.method} calibration did not converge: {exc}") from None
            from .report import result_summary

            result, summary, points, recon = exc.result, result_summary(exc.result), None, None
            failed = f"{args.method} calibration did not converge: {exc}"
        if not result.converged and failed is None:
            failed = f"{args.method} calibration did not converge: {result.message}"
    summary.update({"inputs": {k: v for k, v in inp["inputs"].items() if v},
                    "sigma_px": spx, "sigma_px_how": spx_how, "sigma_scene": ssc_how,
                    "image_size": list(inp["image_size"]), "seed": args.seed,
                    "command": " ".join(shlex.quote(a) for a in sys.argv),
                    "nominal": inp["nominal"].as_dict()})
    if recon is not None:
        folder.add(_points_csv(out / "points.csv", *recon))
    if data is not None and (points is not None or posterior is not None):
        walls = None if inp["truth"] is None else inp["truth"].get("walls")
        files = write_report(out, summary, pixels=data.pixels, points=points,
                             recon=recon, approx_points=data.approx_points,
                             posterior=posterior, truth=inp["truth"],
                             walls=None if walls is None else np.asarray(walls),
                             image_size=inp["image_size"], title=title)
        folder.add(*files.values())
    folder.add(write_json(out / "summary.json", summary))
    text = summary.get("text") or (result.summary() if args.method != "bayes" else "")
    print(text)
    if "accuracy" in summary:
        print(f"mean 3D error against the truth: {summary['accuracy']['mean_error_mm']:.1f} mm")
    print(f"wrote {out}/summary.json" + (f", {out}/report.html" if (out / "report.html").exists()
                                          else ""))
    if failed:
        raise Failure(failed)
    return 0


def cmd_calibrate(args):
    """Calibrate from files; see ``bayescal calibrate --help``."""
    inp = _load_inputs(args)
    # sigma options are parsed, and the data checked by the model, before anything is written
    data = inp["data"]
    if data is not None:
        spx = _sigma_px(args, data)[0]
        if data.approx_points is not None:
            ssc = _sigma_scene(args, data)[0]
            if args.method != "sequential":
                from .model import LaserLikelihood

                try:
                    LaserLikelihood(data.pixels, data.approx_points, sigma_px=spx,
                                    sigma_scene=ssc)
                except (TypeError, ValueError) as exc:
                    raise UsageError(f"{', '.join(map(str, data.paths))}: {exc}") from None
    if args.max_steps is not None and args.max_steps < 1:
        raise UsageError(f"--max-steps must be a positive integer, got {args.max_steps}")
    folder = OutputFolder(args.out)
    return run_calibration(args, inp, folder)


# -- reconstruct and report -------------------------------------------------------

def _load_run(run):
    from .io import read_json

    run = pathlib.Path(run)
    if not (run / "summary.json").is_file():
        raise UsageError(f"{run} is not a calibration output folder (no summary.json); "
                         "expected the --out folder of 'bayescal calibrate'")
    return run, read_json(run / "summary.json")


def _load_posterior(run):
    import bayescal as bc

    path = run / "posterior.npz"
    if not path.is_file():
        raise UsageError(f"{run}: summary.json says method 'bayes' but {path} is missing")
    return bc.load_posterior(path)


def cmd_reconstruct(args):
    """Reconstruct new laser pixels with error bars from a calibration run."""
    from .io import _write_csv, check_pixels_in_image, load_pixels
    from .parameters import SensorParams
    from .report import linear_reconstruction, plot_reconstruction_ellipses

    size = _image_size(args)
    run, summary = _load_run(args.run)
    pixels, table = load_pixels(args.pixels)
    check_pixels_in_image(pixels, table, image_size=size, margin=args.image_margin)
    if args.sigma_px is not None:
        try:
            spx = float(args.sigma_px)
        except ValueError:
            raise UsageError(f"--sigma-px: could not read {args.sigma_px!r} as a number") from None
        if not (np.isfinite(spx) and spx >= 0):
            raise UsageError(f"--sigma-px must be a finite number >= 0, got {args.sigma_px!r}")
    else:
        spx = summary.get("sigma_px") or summary.get("sigma_px_estimated") or 0.0
    check_out(args.out, force=args.force, inputs=[args.pixels, run / "summary.json"])
    if summary["method"] == "bayes":
        mean, cov = _load_posterior(run).reconstruct(pixels, rng=args.seed)
    else:
        params = SensorParams(**summary["params"])
        cov7 = np.array(summary["covariance_identifiable"], dtype=float)
        mean, cov = linear_reconstruction(params, cov7, pixels, spx)
    folder = OutputFolder(args.out)
    out = folder.path
    sd = np.sqrt(np.maximum(np.diagonal(cov, axis1=1, axis2=2), 0))
    _write_csv(out / "reconstruction.csv",
               {"u": pixels[:, 0], "v": pixels[:, 1], "x": mean[:, 0], "y": mean[:, 1],
                "z": mean[:, 2], "sd_x": sd[:, 0], "sd_y": sd[:, 1], "sd_z": sd[:, 2],
                "cov_xy": cov[:, 0, 1], "cov_xz": cov[:, 0, 2], "cov_yz": cov[:, 1, 2]})
    folder.add(out / "reconstruction.csv")
    from .plotting import savefig

    folder.add(savefig(plot_reconstruction_ellipses(mean, cov),
                       out / "reconstruction.png"))
    miss = int((~np.isfinite(mean).all(axis=1)).sum())
    if miss:
        print(f"bayescal: warning: {miss} pixel(s) have rays that miss the laser cone; their "
              "rows are nan", file=sys.stderr)
    print(f"reconstructed {len(pixels)} pixels with the {summary['method']} calibration of "
          f"{run}; median sd {np.nanmedian(np.linalg.norm(sd, axis=1)):.3g} mm")
    print(f"wrote {out / 'reconstruction.csv'}, {out / 'reconstruction.png'}")
    return 0


def cmd_report(args):
    """Rebuild the Markdown/HTML report of a calibration run."""
    from .io import check_pixels_in_image, load_laser_data, write_json
    from .report import write_report

    run, summary = _load_run(args.run)
    ins = summary.get("inputs", {})
    if not ins.get("data"):
        raise UsageError(f"{run}/summary.json names no laser data file; nothing to report on")
    data = load_laser_data(ins["data"], ins.get("points"),
                           need_points=summary["method"] != "sequential")
    size = tuple(summary.get("image_size", (800, 600)))
    check_pixels_in_image(data.pixels, data.pixel_table, image_size=size, margin=np.inf)
    truth = _load_truth(args.truth or ins.get("truth"))
    check_out(args.out, force=args.force, inputs=[run / "summary.json"] + data.paths)
    posterior = _load_posterior(run) if summary["method"] == "bayes" else None
    recon = _read_points_csv(run / "points.csv") if (run / "points.csv").is_file() else None
    points = recon[0] if recon is not None else None
    folder = OutputFolder(args.out)
    walls = None if truth is None or truth.get("walls") is None else np.asarray(truth["walls"])
    files = write_report(folder.path, summary, pixels=data.pixels, points=points, recon=recon,
                         approx_points=data.approx_points, posterior=posterior, truth=truth,
                         walls=walls, image_size=size)
    folder.add(*files.values())
    folder.add(write_json(folder.path / "summary.json", summary))
    print(f"wrote {files['html']} and {files['markdown']}")
    return 0


# -- study and demo --------------------------------------------------------------

def studies_dir():
    """Folder of study scripts: ``$BAYESCAL_STUDIES_DIR`` or ``studies/`` beside the package."""
    import bayescal

    env = os.environ.get("BAYESCAL_STUDIES_DIR")
    return pathlib.Path(env) if env else pathlib.Path(bayescal.__file__).resolve().parents[1] / \
        "studies"


#: scripts in studies/ that are not studies (benchmark.py writes a file, `make bench`)
NOT_STUDIES = {"benchmark"}


def cmd_study(args):
    """Run ``studies/NAME.py --out OUT [--quick]``."""
    folder = studies_dir()
    available = sorted(p.stem for p in folder.glob("*.py")
                       if not p.stem.startswith("_") and p.stem not in NOT_STUDIES) \
        if folder.is_dir() else []
    name = args.name[:-3] if args.name.endswith(".py") else args.name
    script = folder / f"{name}.py"
    if name.startswith("_") or name in NOT_STUDIES or not script.is_file():
        raise UsageError(f"no study named {args.name!r} in {folder}; available: "
                         + (", ".join(available) if available else "none"))
    out = args.out or f"out/study-{name}"
    check_out(out, force=args.force)
    OutputFolder(out)
    cmd = [sys.executable, str(script), "--out", str(out)] + (["--quick"] if args.quick else [])
    print("running " + " ".join(shlex.quote(c) for c in cmd), flush=True)
    rc = subprocess.run(cmd, check=False).returncode
    if rc != 0:
        raise Failure(f"study {name} exited with code {rc}")
    return 0


class _SubFolder:
    """A sub-folder whose files are recorded in the parent's manifest."""

    def __init__(self, root, name):
        self.path = root.path / name
        self.path.mkdir(exist_ok=True)
        self.add = root.add


def _demo_index(out, rows, ds):
    import html

    md = ["# bayescal demo: the paper's large room", "",
          f"Simulated {ds.n_points} laser points in a {ds.range_mm:.0f} mm room, pixel noise "
          f"{ds.sigma_px:g} px, approximate points {100 * ds.approx_error:g} % "
          f"({ds.approx_model} protocol). Inputs in `data/`.", "",
          "| stage | status | mean 3D error (mm) | report |", "|---|---|---|---|"]
    for r in rows:
        md.append(f"| {r['stage']} | {r['status']} | {r['error']} | "
                  + (f"[{r['report']}]({r['report']})" if r["report"] else "-") + " |")
    md += ["", "Paper (Fig. 9, 5 % approximation, 5000 mm): simultaneous about 90 mm, "
           "sequential about 310 mm mean error."]
    (out / "index.md").write_text("\n".join(md) + "\n", encoding="utf-8")
    body = "".join(f"<tr><td>{html.escape(r['stage'])}</td><td>{html.escape(r['status'])}</td>"
                   f"<td>{r['error']}</td><td>"
                   + (f"<a href='{r['report']}'>{r['report']}</a>" if r["report"] else "-")
                   + "</td></tr>" for r in rows)
    (out / "index.html").write_text(
        "<!DOCTYPE html><html><head><meta charset='utf-8'><title>bayescal demo</title></head>"
        f"<body><h1>bayescal demo</h1><p>{html.escape(md[2])}</p><table border=1>"
        "<tr><th>stage</th><th>status</th><th>mean 3D error (mm)</th><th>report</th></tr>"
        f"{body}</table><p>{html.escape(md[-1])}</p></body></html>\n", encoding="utf-8")
    return [out / "index.md", out / "index.html"]


def cmd_demo(args):
    """The main job end to end: simulate, calibrate (3 methods), report into --out."""
    from .io import load_calibration_data, load_laser_data

    args.range_mm, args.n_walls, args.sigma_3d, args.approx_model = 5000.0, 7, 0.0, "fig9"
    args.sigma_px, args.approx_error = 0.1, 0.05
    ds = _simulate_dataset(args)
    check_out(args.out, force=args.force)
    root = OutputFolder(args.out)
    out = root.path
    print(f"simulated {ds.n_points} laser points, range {ds.range_mm:.0f} mm, sigma_px "
          f"{ds.sigma_px:g}, approx. points 5 %, seed {args.seed}", flush=True)
    data_folder = _SubFolder(root, "data")
    write_simulation(data_folder, ds, seed=args.seed)
    rows = []
    for method in ("sequential", "simultaneous", "bayes"):
        print(f"\n== {method} ==", flush=True)
        sub = _SubFolder(root, method)
        ns = argparse.Namespace(
            method=method, data=str(out / "data" / "laser.csv"), points=None,
            calibration=str(out / "data" / "calibration.npz"), calibration_laser=None,
            nominal=None, prior=None, truth=str(out / "data" / "truth.json"), sigma_px=None,
            sigma_scene=None, image_size="800x600", image_margin=50.0, seed=args.seed,
            max_steps=args.max_steps, no_progress=args.no_progress,
            allow_unconverged=args.allow_unconverged,
            out=str(sub.path), force=True)
        inp = {"data": load_laser_data(ns.data), "nominal": _priors(ns)[0], "prior": None,
               "truth": _load_truth(ns.truth), "image_size": (800, 600),
               "calib": load_calibration_data(ns.calibration),
               "inputs": {"data": ns.data, "calibration": ns.calibration, "truth": ns.truth}}
        status, err, report = "ok", "-", None
        try:
            run_calibration(ns, inp, sub, title=f"bayescal demo: {method}")
        except Failure as exc:
            status = "NOT CONVERGED" if "did not converge" in str(exc) else f"failed: {exc}"
            print(f"bayescal: {exc}", file=sys.stderr)
        summ = sub.path / "summary.json"
        if summ.is_file():
            from .io import read_json

            s = read_json(summ)
            if "accuracy" in s:
                err = f"{s['accuracy']['mean_error_mm']:.1f}"
            if (sub.path / "report.html").is_file():
                report = f"{method}/report.html"
        rows.append({"stage": method, "status": status, "error": err, "report": report})
    root.add(*_demo_index(out, rows, ds))
    print("\n" + "\n".join(f"{r['stage']:>12}: {r['status']}; mean 3D error {r['error']} mm"
                           for r in rows))
    print(f"open {out / 'index.html'}")
    return 0 if all(r["status"] == "ok" for r in rows) else 1


# -- parser ----------------------------------------------------------------------

def _common(p, *, seed=True, out_default="out"):
    p.add_argument("--out", default=out_default,
                   help=f"output folder (default: {out_default}); must be new or empty, "
                        "unless --force")
    p.add_argument("--force", action="store_true",
                   help="replace the files bayescal wrote earlier in --out (never your own)")
    if seed:
        p.add_argument("--seed", type=int, default=0, help="random seed (default: 0)")


def _image_opts(p):
    p.add_argument("--image-size", default="800x600", metavar="WxH",
                   help="image width x height in px (default: 800x600); pixels further than "
                        "--image-margin outside it are rejected as bad input")
    p.add_argument("--image-margin", type=float, default=50.0, metavar="PX",
                   help="tolerance around the image, px (default: 50)")


def _add_simulate(sub):
    p = sub.add_parser("simulate", help="simulate a room and write CSV/NPZ inputs and a truth file",
                       description="Simulate the paper's room (bayescal.simulate_room) and write "
                       "laser.csv/laser.npz (u, v, x, y, z, sigma_x/y/z, sigma_px), "
                       "calibration.npz, grid.csv, calib_laser.csv and truth.json into --out.")
    p.add_argument("--range-mm", type=float, default=5000.0,
                   help="scene size in mm (paper: 1000 small, 5000 large; default 5000)")
    p.add_argument("--n-points", type=int, default=580, help="laser points (default: 580)")
    p.add_argument("--n-walls", type=int, default=7, help="walls (default: 7)")
    p.add_argument("--sigma-px", type=float, default=0.1, help="pixel noise, px (default: 0.1)")
    p.add_argument("--approx-error", type=float, default=0.05,
                   help="relative error of the approximate points (default: 0.05 = 5 %%)")
    p.add_argument("--approx-model", default="fig9", choices=("fig9", "wall", "gaussian"),
                   help="how approximate points are made (default: fig9, the paper's protocol)")
    p.add_argument("--sigma-3d", type=float, default=0.0,
                   help="extra 3D measurement noise, mm (default: 0)")
    _common(p, out_default="sim")
    p.set_defaults(func=cmd_simulate)


def _add_calibrate(sub):
    p = sub.add_parser(
        "calibrate", help="calibrate from laser pixels and approximate points",
        description="Calibrate the sensor. simultaneous: MAP least squares on pixels and "
        "approximate points (the paper's method, with weak priors); bayes: the posterior "
        "(emcee); sequential: the classical two-stage method from calibration planes. Writes "
        "summary.json, points.csv, posterior.npz (bayes), PNG plots, report.md and "
        "report.html into --out. Everything is validated before --out is created.")
    p.add_argument("data", nargs="?",
                   help="CSV or NPZ with u, v (px) and x, y, z (mm); optional sigma_x, sigma_y, "
                        "sigma_z (mm, empty or inf = unknown axis) and sigma_px (px)")
    p.add_argument("--points", help="separate CSV/NPZ with x, y, z (+ sigma columns), same rows")
    p.add_argument("--method", choices=METHODS, default="simultaneous",
                   help="calibration method (default: simultaneous)")
    p.add_argument("--calibration", help="sequential: NPZ with CalibrationData fields, or grid "
                   "CSV (plane, u, v, x, y, z)")
    p.add_argument("--calibration-laser", help="sequential with a grid CSV: CSV of the laser on "
                   "the planes (plane, u, v)")
    p.add_argument("--sigma-px", help="pixel noise in px, or 'infer' (default: the file's "
                   "sigma_px column, else infer)")
    p.add_argument("--sigma-scene", help="sd of the approximate points: mm, 'sx,sy,sz' (inf "
                   "allowed), a percentage of each point's horizontal range like '5%%', or "
                   "'infer' (default: the file's sigma columns, else infer)")
    p.add_argument("--nominal", metavar="JSON", help="design values of the 8 parameters (JSON "
                   "object, or {'params': {...}}); centres the default priors and the domain "
                   "check (default: the paper's sensor)")
    p.add_argument("--prior", action="append", metavar="NAME=DIST(ARGS)",
                   help="override one prior with a scipy.stats distribution, e.g. "
                        "'h=norm(200, 20)'; repeatable")
    p.add_argument("--truth", metavar="JSON", help="truth.json of a simulation: adds truth to "
                   "the report and the mean 3D error")
    p.add_argument("--max-steps", type=int, metavar="N",
                   help="bayes: limit on the chain length in steps (default: the sampler's "
                        "20000); convergence needs 50 autocorrelation times")
    p.add_argument("--no-progress", action="store_true", help="no progress bar")
    p.add_argument("--allow-unconverged", action="store_true",
                   help="bayes: exit 0 even if the chains are too short for convergence")
    _image_opts(p)
    _common(p)
    p.set_defaults(func=cmd_calibrate)


def _add_reconstruct(sub):
    p = sub.add_parser("reconstruct", help="reconstruct new laser pixels with error bars",
                       description="Triangulate laser pixels (CSV/NPZ with u, v) with a "
                       "calibration run's parameters; bayes runs average over the posterior, "
                       "least-squares runs propagate the parameter covariance to first order. "
                       "Writes reconstruction.csv (x, y, z, sd, covariances) and a plot.")
    p.add_argument("pixels", help="CSV or NPZ with columns u, v (px)")
    p.add_argument("--run", required=True, help="output folder of 'bayescal calibrate'")
    p.add_argument("--sigma-px", help="least-squares runs: pixel noise of the new pixels, px, "
                   "0 for the parameter part alone (default: the run's); bayes runs use the "
                   "posterior's pixel noise")
    _image_opts(p)
    _common(p, out_default="reconstruction")
    p.set_defaults(func=cmd_reconstruct)


def _add_report(sub):
    p = sub.add_parser("report", help="rebuild the Markdown/HTML report of a calibration run",
                       description="Rebuild report.md and the self-contained report.html of a "
                       "'bayescal calibrate' output folder into --out.")
    p.add_argument("run", help="output folder of 'bayescal calibrate'")
    p.add_argument("--truth", metavar="JSON", help="truth.json of a simulation")
    _common(p, seed=False, out_default="report")
    p.set_defaults(func=cmd_report)


def _add_study(sub):
    p = sub.add_parser("study", help="run an uncertainty study from studies/NAME.py",
                       description="Run studies/NAME.py (beside the package, or in "
                       "$BAYESCAL_STUDIES_DIR) with --out and --quick.")
    p.add_argument("name", help="study name (file name without .py)")
    p.add_argument("--quick", action="store_true", help="a short version of the study")
    _common(p, seed=False, out_default=None)
    p.set_defaults(func=cmd_study)


def _add_demo(sub):
    p = sub.add_parser("demo", help="the main job: simulate the paper's large room, calibrate "
                       "(sequential, simultaneous, Bayesian), write reports into --out",
                       description="Simulate the paper's large room (5000 mm, 0.1 px, 5 %% "
                       "approximate points), calibrate it three ways and write the data, the "
                       "reports and index.html into --out.")
    p.add_argument("--n-points", type=int, default=580, help="laser points (default: 580)")
    p.add_argument("--max-steps", type=int, metavar="N",
                   help="limit on the sampler's chain length (default: the sampler's)")
    p.add_argument("--allow-unconverged", action="store_true",
                   help="do not count a too-short chain as a failure")
    p.add_argument("--no-progress", action="store_true", help="no progress bar")
    _common(p)
    p.set_defaults(func=cmd_demo)


def build_parser():
    """The argument parser with its six subcommands."""
    parser = argparse.ArgumentParser(prog="bayescal", description=__doc__.split("\n\n")[0],
                                     epilog="Exit codes: 0 success, 2 bad usage or bad input, "
                                            "1 failure (e.g. no convergence).")
    sub = parser.add_subparsers(dest="command", required=True, metavar="COMMAND")
    for add in (_add_simulate, _add_calibrate, _add_reconstruct, _add_report, _add_study,
                _add_demo):
        add(sub)
    return parser


def main(argv=None):
    """Run the command line; returns the exit code (0 ok, 2 bad input, 1 failure)."""
    from .io import InputError

    parser = build_parser()
    try:
        args = parser.parse_args(argv)
    except SystemExit as exc:          # --help (0) or a usage error (2)
        return exc.code if isinstance(exc.code, int) else 2
    import matplotlib

    matplotlib.use("agg")              # files only, never a window
    try:
        return args.func(args)
    except (UsageError, InputError) as exc:
        print(f"bayescal: error: {exc}", file=sys.stderr)
        return 2
    except Failure as exc:
        print(f"bayescal: failed: {exc}", file=sys.stderr)
        return 1
