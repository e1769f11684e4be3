"""Running the jobs of :mod:`bayescal.cli.jobs`: simulate, calibrate, reconstruct, report.

Each ``run_*`` function takes a validated job and an open
:class:`~bayescal.io.outputs.OutputFolder` (files staged there move into place when
the folder closes) and returns ``None`` on success or a failure message (exit
code 1, outputs kept for diagnosis).
"""

from __future__ import annotations

import numpy as np

from ..errors import DegenerateInputError, ExtractionError, Failure, UsageError
from ..io.runinfo import POSTERIOR_FILE, RESULT_FILE, RUN_FILE, run_record
from ..io.tables import OFFSET_SD_KEY, image_size_line, offset_sd_line
from ..sensor.pose import POSE_NAMES
from . import matching as mt
from .options import EXTRACTION_ADVICE, cli_words
from .pixelcov import uses_pixel_cov

__all__ = ["run_simulate", "run_extract", "write_simulation", "run_calibrate", "calibrate_result",
           "run_reconstruct", "run_report", "points_csv", "write_laser_pixels"]


def write_simulation(folder, ds, *, seed, image_size=(800, 600)):
    """Write a simulated dataset as the files the other commands read; returns the paths.

    Files: ``laser.csv`` and ``laser.npz`` (u, v, x, y, z, sigma_x/y/z, sigma_px),
    ``calibration.npz`` (CalibrationData fields), ``grid.csv`` and
    ``calib_laser.csv`` (the same in CSV), ``walls.csv`` (the rough floor plan of
    the room, for ``calibrate --walls``), ``truth.json`` (true parameters, points
    and walls, settings). The approximate points' sds are floored at
    :data:`~bayescal.scene.simulate.SIGMA_SCENE_FLOOR_MM`; ``laser.csv`` starts with
    ``# image_size: WxH`` (``image_size``, px).
    """
    from dataclasses import asdict

    from ..io.data import (
        _write_csv,
        write_calibration_npz,
        write_json,
        write_laser_csv,
        write_laser_npz,
    )
    from ..scene.simulate import SIGMA_SCENE_FLOOR_MM

    p = folder.path
    sigma_scene = np.maximum(ds.sigma_scene, SIGMA_SCENE_FLOOR_MM)
    pose = "" if ds.laser.is_aligned else (
        f", laser cone tilted ({np.degrees(ds.laser.tilt_x):g}, {np.degrees(ds.laser.tilt_y):g})"
        f" deg, offset ({ds.laser.offset_x:g}, {ds.laser.offset_y:g}) mm")
    note = (f"{image_size_line(image_size)}\n"
            f"bayescal simulate: range {ds.range_mm:g} mm, {ds.n_points} points, sigma_px "
            f"{ds.sigma_px:g}, approx_error {ds.approx_error:g} ({ds.approx_model}){pose}, "
            f"seed {seed}\n"
            "u, v: laser pixel (px); x, y, z: approximate point (mm, frame C); sigma_*: its sd "
            f"(mm, at least {SIGMA_SCENE_FLOOR_MM:g}; inf = no information); sigma_px: pixel "
            "noise (px)")
    write_laser_csv(p / "laser.csv", ds.pixels, ds.approx_points, sigma_scene=sigma_scene,
                    sigma_px=ds.sigma_px, header_comment=note)
    write_laser_npz(p / "laser.npz", ds.pixels, ds.approx_points, sigma_scene=sigma_scene,
                    sigma_px=ds.sigma_px)
    cal = ds.calibration
    write_calibration_npz(p / "calibration.npz", cal)
    _write_csv(p / "grid.csv", {"plane": cal.grid_plane, "u": cal.grid_pixels[:, 0],
                                "v": cal.grid_pixels[:, 1], "x": cal.grid_points[:, 0],
                                "y": cal.grid_points[:, 1], "z": cal.grid_points[:, 2]})
    _write_csv(p / "calib_laser.csv", {"plane": cal.laser_plane, "u": cal.laser_pixels[:, 0],
                                       "v": cal.laser_pixels[:, 1]})
    settings = {k: v for k, v in asdict(ds).items()
                if k in ("sigma_px", "sigma_3d", "approx_error", "range_mm", "approx_model")}
    write_json(p / "truth.json", {
        "params": ds.params.as_dict(), "nominal": ds.nominal.as_dict(), "points": ds.points,
        "pixels_true": ds.pixels_true, "walls": ds.walls, "settings": settings, "seed": seed,
        "n_points": ds.n_points, "laser": dict(zip(POSE_NAMES, ds.laser.to_array().tolist(),
                                                   strict=True))})
    names = ["laser.csv", "laser.npz", "calibration.npz", "grid.csv", "calib_laser.csv",
             "truth.json"]
    if ds.floor_plan is not None:
        from ..io.planfile import write_walls_csv

        write_walls_csv(p / "walls.csv", ds.floor_plan, header_comment=(
            f"bayescal simulate: the rough floor plan of the simulated room (seed {seed})\n"
            "x0, y0, x1, y1: wall end points (mm, frame C, counterclockwise); distance_sd: sd "
            "of the wall's distance from the axis (mm); angle_sd: sd of its orientation (rad)"))
        names.insert(1, "walls.csv")
    files = [p / n for n in names]
    folder.add(*files)
    return files


def run_simulate(job, folder):
    """Simulate and write the inputs of ``calibrate`` (see :func:`write_simulation`)."""
    ds = job.dataset()
    files = write_simulation(folder, ds, seed=job.seed, image_size=job.image_size)
    if job.images:
        files += write_images(folder, ds, seed=job.seed, image_size=job.image_size)
    for f in files:
        print(f"wrote {job.out / f.name}")


def write_images(folder, ds, *, seed, image_size=(800, 600)):
    """Render the simulated room: ``image.png``, ``image_off.png`` (16 bit), ``ring.csv``;
    ``image_size`` (width, height) px."""
    import imageio.v3 as iio

    from ..io.data import _write_csv
    from ..scene.render import render_image

    img, truth = render_image(ds.params, ds.walls, n_lamps=2, ghost=0.3, bits=16,
                              with_background=True, rng=seed, laser=ds.laser,
                              shape=(int(image_size[1]), int(image_size[0])))
    p = folder.path
    iio.imwrite(p / "image.png", img)
    iio.imwrite(p / "image_off.png", truth.background)
    _write_csv(p / "ring.csv", {"u": truth.pixels[:, 0], "v": truth.pixels[:, 1],
                                "x": truth.points[:, 0], "y": truth.points[:, 1],
                                "z": truth.points[:, 2], "azimuth": truth.azimuth},
               header_comment="bayescal simulate --images: the true laser centre line of "
               "image.png\nu, v (px); x, y, z (mm, frame C); azimuth (rad)")
    files = [p / "image.png", p / "image_off.png", p / "ring.csv"]
    folder.add(*files)
    return files


def run_extract(job, folder):
    """Extract the laser pixels; write ``laser.csv`` and ``overlay.png``."""
    from ..image.extract import extract_laser
    from ..image.ringcv import ring_cv_line
    from ..plotting.basic import savefig
    from ..plotting.image import plot_laser_overlay

    try:
        lp = extract_laser(job.image, background=job.background, center=job.center,
                           along_sd=job.along_sd, radius=job.radius, channel=job.channel)
    except ExtractionError as exc:          # an implausible ring is bad input: exit 2
        raise UsageError(f"{job.image_path}: {exc.reason}. {EXTRACTION_ADVICE}") from None
    p, cv = folder.path, ring_cv_line(lp)
    write_laser_pixels(p / "laser.csv", lp, job.image_path.name,
                       image_size=job.image.shape[1::-1], extra_note=f"\n{cv}")
    savefig(plot_laser_overlay(job.image, lp), p / "overlay.png")
    folder.add(p / "laser.csv", p / "overlay.png")
    sd = np.nanmedian(lp.sd_normal[~lp.flagged])      # flagged points may have no sd
    print(f"{len(lp)} laser pixels ({int(lp.flagged.sum())} flagged), median sd across the "
          f"ring {sd:.3f} px (unflagged); wrote {job.out / 'laser.csv'}, "
          f"{job.out / 'overlay.png'}\n{cv}")


def write_laser_pixels(path, lp, image_name, *, rows=None, extra_note="", image_size=None):
    """Write extracted laser pixels as ``bayescal extract``'s CSV (u, v, cov_uu, cov_uv,
    cov_vv, snr, flagged); ``rows`` (bool or int index) writes a subset. ``image_size``
    ``(width, height)`` px is written first as ``# image_size: WxH``, which ``calibrate``
    and ``reconstruct`` read; then ``# offset_sd: SD``, the sd of a translation shared by
    every pixel (``lp.offset_sd``), which ``calibrate`` adds to u0 and v0."""
    from ..io.data import _write_csv

    k = slice(None) if rows is None else rows
    note = (f"bayescal extract {image_name}: u, v laser centre line (px); cov_*: "
            "covariance (px^2), small along the ring's normal, large along it; snr: peak over "
            "noise sd; flagged: 1 = likely distractor, left out by calibrate" + extra_note)
    if getattr(lp, "offset_sd", 0.0) > 0:
        note = f"{offset_sd_line(lp.offset_sd)}\n" + note
    if image_size is not None:
        note = f"{image_size_line(image_size)}\n" + note
    px, cov = lp.pixels[k], lp.covariance[k]
    _write_csv(path, {
        "u": px[:, 0], "v": px[:, 1], "cov_uu": cov[:, 0, 0], "cov_uv": cov[:, 0, 1],
        "cov_vv": cov[:, 1, 1], "snr": lp.snr[k], "flagged": lp.flagged[k].astype(int)},
        header_comment=note)
    return path


def points_csv(path, points, cov, outlier_prob=None, *, first=None):
    """Write points (mm) with sds and covariances (and ``outlier_prob``) as CSV.

    ``first`` is an optional ``{name: column}`` dict written before the points.
    """
    from ..io.data import _write_csv

    sd = np.sqrt(np.maximum(np.diagonal(cov, axis1=1, axis2=2), 0))
    cols = dict(first or {})
    cols |= {"x": points[:, 0], "y": points[:, 1], "z": points[:, 2],
            "sd_x": sd[:, 0], "sd_y": sd[:, 1], "sd_z": sd[:, 2],
            "cov_xy": cov[:, 0, 1], "cov_xz": cov[:, 0, 2], "cov_yz": cov[:, 1, 2]}
    if outlier_prob is not None:
        cols["outlier_prob"] = np.asarray(outlier_prob, float)
    _write_csv(path, cols)
    return path


def _bayes(job):
    """The posterior of a bayes job; returns ``(posterior, failure message or None)``."""
    import bayescal as bc

    from ..sensor.parameters import SensorParams

    data, kw = job.data, {}
    if job.max_steps is not None:         # asked for a longer run: no time budget
        kw["max_steps"] = job.max_steps
        kw["budget"] = None
    if job.nominal != SensorParams.paper():
        kw["init"] = job.nominal
    if not job.outliers:
        kw["outliers"] = False
    if uses_pixel_cov(job.method, data, job.plan):
        kw["pixel_cov"] = data.pixel_cov
    kw |= _offset(data)
    if job.camera is not None:
        kw["camera"] = job.camera
    if job.plan is None:
        post = bc.sample_posterior(data.pixels, data.approx_points, sigma_px=job.sigma_px,
                                   sigma_scene=job.sigma_scene, prior=job.prior, rng=job.seed,
                                   progress=job.progress, model=job.model, **kw)
    else:
        try:
            post = bc.sample_posterior(data.pixels, job.plan, sigma_px=job.sigma_px,
                                       prior=job.prior, rng=job.seed, progress=job.progress,
                                       model=job.model, **kw)
        except TypeError as exc:
            raise Failure("--method bayes with --walls needs a sampler that takes a floor "
                          f"plan; this bayescal's does not ({exc}). Use --method "
                          "simultaneous") from None
    if post.converged or job.allow_unconverged:
        return post, None
    diag = getattr(post, "diagnostics", None)
    stopped = (diag.extra or {}).get("stopped") if diag is not None else None
    if stopped:
        return post, (f"the posterior sampler did not converge: it {stopped}; outputs "
                      "written for diagnosis. Check the rows flagged as outliers, run "
                      "longer (--max-steps) or pass --allow-unconverged")
    return post, ("the posterior sampler did not converge (chains shorter than 50 "
                  "autocorrelation times); outputs written for diagnosis. Run longer "
                  "(--max-steps) or pass --allow-unconverged")


def _offset(data):
    """``{"offset_sd": sd}`` when the data file has ``# offset_sd: SD`` (the extractor's
    translation of the whole ring, px), else ``{}``."""
    sd = 0.0 if data is None else data.pixel_table.meta.get(OFFSET_SD_KEY, 0.0)
    return {"offset_sd": sd} if sd > 0 else {}


def _least_squares(job):
    """The sequential or simultaneous result of ``job`` (may raise ConvergenceError)."""
    import bayescal as bc

    from ..sensor.parameters import SensorParams

    kw = {} if job.camera is None else {"camera": job.camera}
    if job.prior is not None or job.nominal != SensorParams.paper():
        kw["init"] = job.nominal
    if job.method == "sequential":
        # only an explicit --sigma-px describes the pattern pixels
        if job.sigma_px_how == "given":
            kw["sigma_px"] = job.sigma_px
        return bc.calibrate_sequential(job.calib, model=job.model, **kw)
    if uses_pixel_cov(job.method, job.data, job.plan):
        kw["pixel_cov"] = job.data.pixel_cov
    kw |= _offset(job.data)
    if job.plan is not None:
        return bc.calibrate_simultaneous(job.data.pixels, job.plan, sigma_px=job.sigma_px,
                                         prior=job.prior, outliers=job.outliers,
                                         model=job.model, ring_corr_deg=job.ring_corr, **kw)
    return bc.calibrate_simultaneous(job.data.pixels, job.data.approx_points,
                                     sigma_px=job.sigma_px, sigma_scene=job.sigma_scene,
                                     prior=job.prior, outliers=job.outliers, model=job.model,
                                     **kw)


def calibrate_result(job, choice=None):
    """Run the job's method; returns ``(result, failure message or None)``.

    Library messages about the input (duplicate rows, a collapsing noise level)
    are shown with the file's line numbers; a collapsing noise level is bad
    input (:class:`~bayescal.errors.UsageError`, exit code 2). ``choice`` (a
    :class:`~bayescal.cli.lasermodel.ModelChoice`, filled in here) records the
    laser model fitted: with ``--model auto`` both models are fitted by least
    squares first and the preferred one is used.
    """
    from ..checks.datafile import library_messages
    from .lasermodel import ModelChoice

    data = job.data
    choice = ModelChoice(job.model) if choice is None else choice
    try:
        with library_messages(data, reported=job.duplicate_lines) if data is not None \
                else _nothing():
            return _calibrate(job, choice)
    except DegenerateInputError as exc:         # input that cannot calibrate: exit 2
        hint = mt.camera_hint(data, job.nominal, job.inputs.get("camera"))
        raise UsageError(f"{data.pixel_table.path}: {exc}{hint}" if data is not None
                         else str(exc)) from None


def _calibrate(job, choice):
    """:func:`calibrate_result` inside the library-message context."""
    from dataclasses import replace

    from ..checks.fit import NoiseCollapseError
    from ..results.calibration import ConvergenceError

    data = job.data
    job = replace(job, model=choice.resolve(job, _least_squares).model)
    try:
        if job.method == "bayes":
            return _bayes(job)
        result = choice.fits.get(job.model)
        result = _least_squares(job) if result is None else result
    except ConvergenceError as exc:
        if exc.result is None:
            raise Failure(f"{job.method} calibration did not converge: {exc}") from None
        if job.method == "bayes":           # no posterior without its least-squares start
            raise Failure("the posterior's least-squares start did not converge: "
                          f"{_located(exc.result, data)}; nothing was written") from None
        return exc.result, (f"{job.method} calibration did not converge: "
                            f"{_located(exc.result, data)}")
    except (NoiseCollapseError, DegenerateInputError):
        raise
    except (ValueError, ArithmeticError, np.linalg.LinAlgError) as exc:
        raise Failure(f"{job.method} calibration failed on these data ({exc}); nothing "
                      "was written") from None
    if job.sigma_px is not None:
        result.extras["sigma_px"] = float(job.sigma_px)
    if job.sigma_scene is not None and job.method == "simultaneous":
        result.extras["sigma_scene"] = np.asarray(job.sigma_scene, float)
    if not result.converged:
        return result, f"{job.method} calibration did not converge: {_located(result, data)}"
    misfit = result.extras.get("model_misfit") and _located(result, data, "misfit_message")
    return result, f"{job.method} calibration: {misfit}" if misfit else None   # 1: written


def _located(result, data, key=None):
    """A result's message (or ``extras[key]``), the rows it names as the file's lines."""
    from ..checks.datafile import rows_to_lines
    rows, text = result.extras.get("failed_rows"), str(result.extras.get(key, result.message))
    if rows is None or data is None:
        return text
    lines = ", ".join(map(str, rows_to_lines(data, rows)))
    text = text.split(" (rows fitting worst", 1)[0]
    return f"{text} (input fitting worst: {data.pixel_table.path} lines {lines})"


def _nothing():
    import contextlib

    return contextlib.nullcontext()


def _recon(job, result):
    """(points, covariances) of the laser points for points.csv and the report, or None."""
    data = job.data
    if data is None:
        return None
    if hasattr(result, "param_samples"):
        return result.points, result.point_covariance()
    if result.points is not None and "point_covariance" in result.extras:
        return result.points, result.point_covariance()
    return tuple(result.reconstruct(data.pixels))


def _prior_of(job):
    if job.method != "simultaneous":
        return None
    from ..likelihood.priors import Prior, default_prior

    if job.camera is not None:          # the camera's marginals beside the other priors
        return dict(Prior(job.prior, nominal=job.nominal, camera=job.camera).dists)
    prior = default_prior(job.nominal)
    prior.update(job.prior or {})
    return prior


def run_calibrate(job, folder):
    """Calibrate, then write the result, ``run.json``, ``points.csv``, ``params.csv`` and the
    report; with ``--model auto`` the run record, the summary and the report name the model
    chosen and give the log-evidence table."""
    from ..io.data import write_json
    from ..report.report import write_report
    from .lasermodel import ModelChoice

    out = folder.path
    choice = ModelChoice(job.model, note=job.model_note)
    result, failed = calibrate_result(job, choice)
    if hasattr(result, "param_samples"):
        folder.add(result.save(out / POSTERIOR_FILE, overwrite=True))
    else:
        folder.add(result.save(out / RESULT_FILE, overwrite=True))
    recon = _recon(job, result)
    if recon is not None:
        folder.add(points_csv(out / "points.csv", *recon,
                              outlier_prob=getattr(result, "outlier_prob", None)))
    folder.add(_params_csv(out, job, result))
    acc, model = None, {"laser_model": choice.record()}
    if job.data is None or recon is not None or result.points is not None:
        info = run_record(job, **model)
        files, acc = write_report(out, result, info, data=job.data, recon=recon,
                                  truth=job.truth, prior=_prior_of(job), title=job.title,
                                  figures=job.figures)
        folder.add(*files.values())
    folder.add(write_json(out / RUN_FILE, run_record(job, accuracy=acc, **model)))
    from ..checks.datafile import located_summary

    print(cli_words(located_summary(result, job.data)))
    if choice.text():
        print(choice.text())
    if acc:
        print(f"mean 3D error against the truth: {acc['mean_error_mm']:.1f} mm")
    print(f"wrote {job.out}/" + (POSTERIOR_FILE if job.method == "bayes" else RESULT_FILE)
          + (f", {job.out}/report.html" if (out / "report.html").exists() else ""))
    return failed, acc


def _params_csv(out, job, result):
    """``params.csv``: the eight parameters and, misaligned, the laser pose."""
    from ..io.paramtable import pose_rows, write_params_csv
    from ..report.report import parameter_rows

    return write_params_csv(out / "params.csv", parameter_rows(result, prior=_prior_of(job)),
                            pose_rows(result), model=getattr(result, "model", "aligned"))


def run_reconstruct(job, folder):
    """Triangulate new pixels with error bars, frame by frame.

    One frame: ``reconstruction.csv``, ``reconstruction.ply`` and a plot; several:
    one ``<frame>.ply`` each and ``frames.csv`` (a line per frame), with a progress
    bar. The calibration is prepared once (:meth:`reconstructor`)."""
    import sys
    import time

    from ..io.data import _write_csv
    from ..plotting import plot_reconstruction_ellipses, savefig

    out, result = folder.path, job.result
    recon = result.reconstructor(rng=job.seed) if hasattr(result, "param_samples") \
        else result.reconstructor(sigma_px=job.sigma_px)
    mt.say_pixel_noise(job)
    rows, single = [], len(job.frames) == 1
    frames = job.frames
    if not single:
        from tqdm.auto import tqdm

        frames = tqdm(frames, desc="frames", unit="frame", file=sys.stderr)
    for path, pixels, pixel_cov in frames:
        t0 = time.perf_counter()
        rec = recon(pixels, pixel_cov=mt.frame_noise(job, pixel_cov))
        seconds = time.perf_counter() - t0
        name = "reconstruction" if single else path.stem
        folder.add(rec.save(out / f"{name}.ply"))
        sd = np.sqrt(np.maximum(np.diagonal(rec.covariance, axis1=1, axis2=2), 0))
        rows.append((str(path), len(pixels), int((~rec.valid).sum()),
                     mt.quiet_median(np.linalg.norm(sd, axis=1)), seconds, f"{name}.ply"))
    if single:
        mean, cov = rec
        folder.add(points_csv(out / "reconstruction.csv", mean, cov,
                              first={"u": pixels[:, 0], "v": pixels[:, 1]}),
                   savefig(plot_reconstruction_ellipses(mean, cov), out / "reconstruction.png"))
    else:
        cols = list(zip(*rows, strict=True))
        _write_csv(out / "frames.csv", {
            "frame": np.arange(len(rows)), "points": np.array(cols[1]),
            "missed": np.array(cols[2]), "median_sd_mm": np.array(cols[3]),
            "seconds": np.array(cols[4])},
            header_comment="\n".join(f"frame {k}: {r[0]} -> {r[5]}" for k, r in enumerate(rows)))
        folder.add(out / "frames.csv")
    miss = sum(r[2] for r in rows)
    if miss:
        print(f"bayescal: warning: {miss} pixel(s) have rays that miss the laser cone; their "
              "rows are nan", file=sys.stderr)
    method = "bayes" if hasattr(result, "param_samples") else getattr(result, "method", "")
    print(f"reconstructed {sum(r[1] for r in rows)} pixels in {len(rows)} frame(s) with the "
          f"{method} calibration of {job.run}; median sd "
          f"{mt.quiet_median([r[3] for r in rows]):.3g} mm")
    written = (["reconstruction.csv", "reconstruction.ply", "reconstruction.png"] if single
               else [r[5] for r in rows[:3]] + (["..."] if len(rows) > 3 else [])
               + ["frames.csv"])
    print("wrote " + ", ".join(str(job.out / w) if w != "..." else w for w in written))


def run_report(job, folder):
    """Rebuild ``report.md`` and ``report.html`` of a calibration run."""
    from ..io.data import read_table
    from ..report.report import write_report

    recon = None
    pts = job.run / "points.csv"
    if pts.is_file():
        c = read_table(pts, required=("x", "y", "z", "sd_x", "sd_y", "sd_z", "cov_xy", "cov_xz",
                                      "cov_yz"), optional=("outlier_prob",)).columns
        cov = np.empty((len(c["x"]), 3, 3))
        for i, a in enumerate("xyz"):
            cov[:, i, i] = c[f"sd_{a}"] ** 2
        cov[:, 0, 1] = cov[:, 1, 0] = c["cov_xy"]
        cov[:, 0, 2] = cov[:, 2, 0] = c["cov_xz"]
        cov[:, 1, 2] = cov[:, 2, 1] = c["cov_yz"]
        recon = (np.column_stack([c["x"], c["y"], c["z"]]), cov)
    files, _ = write_report(folder.path, job.result, job.run_info, data=job.data, recon=recon,
                            truth=job.truth)
    folder.add(*files.values())
    print(f"wrote {job.out / 'report.html'} and {job.out / 'report.md'}")
