"""Typed, validated jobs: what a ``bayescal`` command runs.

A job is built from option values (the parsed command line, or keyword
arguments from Python or the demo) by its ``build`` class method, which reads
and checks every input file before anything is written: any problem raises
:class:`~bayescal.errors.UsageError` or :class:`~bayescal.errors.InputError`
naming the file, line, option or value. Running a job (:mod:`bayescal.cli.runs`)
takes only the job object.
"""

from __future__ import annotations

import pathlib
import shlex
import sys
from dataclasses import dataclass, field, replace

import numpy as np

from ..checks.datafile import (
    MIN_AZIMUTH_SPAN_DEG,
    MIN_POINTS,
    check_geometry,
    load_truth,
    sigma_px_setting,
    sigma_scene_setting,
    warn_duplicates,
)
from ..errors import InvalidTypeError, UsageError
from ..io.outputs import check_out
from ..sensor.parameters import CAMERA_PARAM_NAMES
from . import matching as mt
from . import options as op
from .design import note_design, note_flagged, read_nominal
from .lasermodel import camera_nominal, model_setting, nominal_and_prior, read_camera
from .pixelcov import pixel_cov_setting, ring_corr_setting

__all__ = ["SimulateJob", "ExtractJob",
           "CalibrateJob", "ReconstructJob", "ReportJob", "DemoJob", "StudyJob",
           "load_truth", "check_geometry", "MIN_POINTS", "MIN_AZIMUTH_SPAN_DEG"]


def _opts(table, given):
    o = op.defaults(table)
    unknown = set(given) - set(o)
    if unknown:
        raise InvalidTypeError(f"unknown option(s) {sorted(unknown)}; expected some of {sorted(o)}")
    o.update(given)
    return o


def _resolved(path):
    return None if path is None else str(pathlib.Path(path).resolve())


@dataclass(frozen=True)
class SimulateJob:
    """Simulate a room; ``options`` as in :data:`bayescal.cli.options.SIMULATE_OPTIONS`
    (``tilt`` in degrees, ``offset`` in mm: the laser cone's pose)."""

    range_mm: float
    n_points: int
    n_walls: int
    sigma_px: float
    approx_error: float
    approx_model: str
    sigma_3d: float
    seed: int
    out: pathlib.Path
    force: bool = False
    images: bool = False
    tilt: tuple = (0.0, 0.0)
    offset: tuple = (0.0, 0.0)
    image_size: tuple = (800, 600)

    @classmethod
    def build(cls, **options):
        """Validated job from option values (defaults for the rest)."""
        o = _opts(op.SIMULATE_OPTIONS, options)
        check_out(o["out"], force=o["force"])
        o["out"] = pathlib.Path(o["out"])
        o["image_size"] = tuple(int(v) for v in o["image_size"])
        return cls(**{k: o[k] for k in cls.__dataclass_fields__})

    def sensor(self):
        """The simulated sensor: the paper's, centred on the image and its focal scale times
        ``min(W, H) / 600`` (the paper's sensor for 800x600)."""
        from .design import design_values

        return design_values({}, image_size=self.image_size)[0]

    def dataset(self):
        """Simulate the room (a :class:`~bayescal.Dataset`)."""
        from ..scene.simulate import simulate_room

        try:
            p = self.sensor()
            return simulate_room(p, nominal=p, range_mm=self.range_mm, n_points=self.n_points,
                                 n_walls=self.n_walls, sigma_px=self.sigma_px,
                                 approx_error=self.approx_error, sigma_3d=self.sigma_3d,
                                 approx_model=self.approx_model, rng=self.seed,
                                 tilt=tuple(np.radians(self.tilt)), offset=tuple(self.offset))
        except (TypeError, ValueError) as exc:
            raise UsageError(str(exc)) from None


def _read_image(path, option, channel):
    from ..image.read import read_image

    try:
        return read_image(path, channel=channel, raw=True)
    except (ValueError, TypeError) as exc:
        raise UsageError(f"{option} {path}: {exc}") from None


@dataclass(frozen=True)
class ExtractJob:
    """Extract laser pixels from an image; options as in ``EXTRACT_OPTIONS``."""

    image_path: pathlib.Path
    image: np.ndarray = field(repr=False)
    background: np.ndarray | None = field(repr=False)
    center: tuple | None
    channel: int
    out: pathlib.Path
    force: bool = False
    along_sd: float = 5.0
    radius: tuple | None = None

    @classmethod
    def build(cls, **options):
        """Validated job: both images read and checked before anything is written."""
        o = _opts(op.EXTRACT_OPTIONS, options)
        inputs = [p for p in (o["image"], o["background"]) if p is not None]
        check_out(o["out"], force=o["force"], inputs=inputs)
        image = _read_image(o["image"], "IMAGE", o["channel"])
        bg = None if o["background"] is None else _read_image(o["background"], "--background",
                                                               o["channel"])
        if bg is not None and bg.shape[:2] != image.shape[:2]:
            raise UsageError(f"--background {o['background']}: shape {bg.shape} differs "
                             f"from the image's {image.shape}")
        center = None if o["center"] is None else tuple(float(c) for c in o["center"])
        return cls(image_path=pathlib.Path(o["image"]), image=image, background=bg,
                   center=center, channel=o["channel"], out=pathlib.Path(o["out"]),
                   force=o["force"], along_sd=float(o["along_sd"]),
                   radius=op.radius_range(o["radius"]))


@dataclass(frozen=True)
class CalibrateJob:
    """A calibration with every input read and checked.

    Attributes
    ----------
    method : {"sequential", "simultaneous", "bayes"}
    data : LaserData or None
        Laser pixels and approximate points (None: sequential without room data).
    calib : CalibrationData or None
        Calibration planes (sequential).
    nominal : SensorParams
    prior : dict or None
        ``{name: frozen distribution}`` for all eight names, or None (defaults).
    truth : dict or None
    sigma_px, sigma_scene : the noise given to the method (None = inferred)
    sigma_px_how, sigma_scene_how : str (where they came from, for the report)
    image_size : (int, int)
    seed, max_steps, progress, allow_unconverged, out, force, inputs, title, command, ring_corr
    plan : FloorPlan or None
        ``--walls``: the rough floor plan in place of approximate points.
    outliers : bool
        The per-point outlier mixture (off with ``--no-outliers``).
    duplicate_lines : tuple of int
        Lines already named in the duplicate-rows warning.
    figures : tuple of (str, pathlib.Path)
        More figures for the report (caption, PNG in the output folder), e.g. the demo's
        laser extraction overlay.
    model : {"aligned", "misaligned", "auto"}
        The laser model (``--model``; ``auto`` where only aligned is supported
        became ``aligned``, and ``model_note`` says so).
    camera : CameraResult or None
        ``--camera``: the camera calibrated beforehand, the prior of its intrinsics.
    """

    method: str
    data: object
    calib: object
    nominal: object
    prior: dict | None
    truth: dict | None
    sigma_px: float | None
    sigma_px_how: str
    sigma_scene: np.ndarray | None
    sigma_scene_how: str
    image_size: tuple
    seed: int
    max_steps: int | None
    progress: bool
    allow_unconverged: bool
    out: pathlib.Path
    force: bool
    inputs: dict = field(default_factory=dict)
    title: str | None = None
    command: str = ""
    plan: object = None
    outliers: bool = True
    duplicate_lines: tuple = ()
    figures: tuple = ()
    model: str = "aligned"
    model_note: str | None = None
    camera: object = None
    image_size_how: str = "--image-size"
    derived: dict = field(default_factory=dict)
    ring_corr: float = 0.0

    @classmethod
    def build(cls, *, title=None, **options):
        """Validated job from option values (:data:`~bayescal.cli.options.CALIBRATE_OPTIONS`)."""
        o = _opts(op.CALIBRATE_OPTIONS, options)
        method = o["method"] = op.method_option(o["method"])
        if method not in op.METHODS:
            raise UsageError(f"--method {method!r}; expected one of {', '.join(op.METHODS)}")
        given = read_nominal(o["nominal"])
        camera, camera_size = (None, None) if o["camera"] is None else read_camera(o["camera"])
        data, calib, plan, size = cls._read(o, given, (o["camera"], camera_size))
        nominal, prior, derived = nominal_and_prior(given, o["prior"], image_size=size[0],
                                                    data=data, plan=plan, with_derived=True)
        if camera is not None:              # its intrinsics: the nominal camera and prior
            nominal, prior = camera_nominal(camera, o["camera"], nominal, o["prior"])
            derived = {k: v for k, v in derived.items() if k not in CAMERA_PARAM_NAMES}
        note_design(size, derived, nominal)
        model, note = model_setting(o["model"], method=method, plan=plan, prior_specs=o["prior"])
        truth = mt.truth_for(o["truth"], data)
        spx, spx_how = (sigma_px_setting(o["sigma_px"], data) if data is not None
                        else (None, "not used"))
        if data is not None and data.pixel_cov is not None:
            spx, spx_how = pixel_cov_setting(o["sigma_px"], data, method, plan, spx, spx_how)
        ssc, ssc_how = ((None, "not used") if data is None or data.approx_points is None
                        else sigma_scene_setting(o["sigma_scene"], data))
        if data is not None and method != "sequential":
            _check_model_input(data, plan, nominal, spx, ssc, o["camera"])
        dups = warn_duplicates(data) if data is not None and method != "sequential" else []
        names = ("data", "points", "walls", "calibration", "calibration_laser", "nominal",
                 "truth", "camera")
        check_out(o["out"], force=o["force"], inputs=[o[k] for k in names])
        return cls(method=method, data=data, calib=calib, nominal=nominal, prior=prior,
                   truth=truth, sigma_px=spx, sigma_px_how=spx_how, sigma_scene=ssc,
                   sigma_scene_how=ssc_how, image_size=size[0], seed=o["seed"],
                   max_steps=o["max_steps"], progress=not o["no_progress"],
                   allow_unconverged=o["allow_unconverged"], out=pathlib.Path(o["out"]),
                   force=o["force"], inputs={k: _resolved(o[k]) for k in names if o[k]},
                   title=title, command=" ".join(shlex.quote(a) for a in sys.argv),
                   plan=plan, outliers=not o["no_outliers"], duplicate_lines=tuple(dups),
                   model=model, model_note=note, camera=camera,
                   image_size_how=size[1], derived=derived,
                   ring_corr=ring_corr_setting(o["ring_corr"], method, plan))

    @staticmethod
    def _read(o, given, camera):
        """(LaserData or None, CalibrationData or None, FloorPlan or None, (image size,
        where it came from)), all checked; ``given`` the design values of ``--nominal``,
        ``camera`` (``--camera``, its image size or None)."""
        from ..io.data import (
            check_pixels_in_image,
            check_projection_domain,
            load_calibration_data,
            load_laser_data,
        )
        from ..sensor.parameters import SensorParams

        method, data, calib = o["method"], None, None
        if method != "sequential" and o["data"] is None:
            raise UsageError(f"calibrate --method {method} needs the laser data file "
                             "(u, v, x, y, z; or u, v with --walls)")
        plan = _read_plan(o)
        if method == "sequential":
            if o["calibration"] is None:
                raise UsageError("calibrate --method sequential needs --calibration FILE (NPZ "
                                 "of the calibration planes, or grid CSV with "
                                 "--calibration-laser)")
            calib = load_calibration_data(o["calibration"], o["calibration_laser"])
        if o["data"] is not None:
            data = load_laser_data(o["data"], o["points"],
                                   need_points=method != "sequential" and plan is None)
            note_flagged(data.pixel_table, data.n_points, "calibration")
        size = mt.agreed_image_size(o["image_size"], data, camera)
        if data is not None:
            check_pixels_in_image(data.pixels, data.pixel_table, image_size=size[0],
                                  margin=o["image_margin"])
            if plan is not None:       # the plan is the scene: x, y, z columns are not used
                data = replace(data, approx_points=None, sigma_scene=None, point_table=None)
            if data.approx_points is not None:        # xi alone decides the domain
                check_projection_domain(data.approx_points, data.point_table,
                                        SensorParams(**{**SensorParams.paper().as_dict(),
                                                        **given}))
        return data, calib, plan, size


def _read_plan(o):
    """The FloorPlan of ``--walls`` (None without it); refuses options that clash with it."""
    if o["walls"] is None:
        return None
    from ..io.planfile import load_walls

    for name, clash in (("method", o["method"] == "sequential"), ("points", o["points"]),
                        ("sigma_scene", o["sigma_scene"] is not None)):
        if clash:
            flag = "--" + name.replace("_", "-")
            raise UsageError(f"--walls {o['walls']}: not used with {flag}"
                             + (" sequential" if name == "method" else "")
                             + "; a floor plan replaces the approximate points and their sds "
                             "(methods simultaneous and bayes)")
    spec = o["distance_sd"]
    if isinstance(spec, str):
        spec = op.distance_sd_option(spec)
    plan, _ = load_walls(o["walls"], distance_sd=spec, angle_sd=o["angle_sd"])
    return plan


def _check_model_input(data, plan, nominal, spx, ssc, camera=None):
    """Build the likelihood once to refuse input the model cannot use (exit 2)."""
    where = ", ".join(map(str, data.paths))
    try:
        if plan is not None:
            from ..likelihood.floorplan import PlanLikelihood

            PlanLikelihood(data.pixels, plan, sigma_px=spx, azimuth_params=nominal)
        else:
            from ..likelihood.points import LaserLikelihood

            LaserLikelihood(data.pixels, data.approx_points, sigma_px=spx, sigma_scene=ssc)
    except (TypeError, ValueError) as exc:
        raise UsageError(f"{where}: {exc}") from None
    mt.centred_geometry(check_geometry, data, nominal, camera)


def _load_run(run):
    """A calibration run's result object and summary (see :func:`bayescal.load_result`)."""
    from ..io.runinfo import load_run

    try:
        return load_run(run)
    except (OSError, ValueError) as exc:
        raise UsageError(f"{run}: {exc}") from None


@dataclass(frozen=True)
class ReconstructJob:
    """Reconstruct new laser pixels with a finished calibration run."""

    frames: tuple          # ((path, pixels (N, 2), pixel covariances (N, 2, 2) or None), ...)
    result: object
    sigma_px: float | None
    seed: int
    out: pathlib.Path
    force: bool
    run: pathlib.Path
    plain_noise: object = None      # RingNoise of frames without covariances, or None

    @property
    def pixels(self):
        """The first frame's pixels (N, 2), px."""
        return self.frames[0][1]

    @classmethod
    def build(cls, **options):
        """Validated job (:data:`~bayescal.cli.options.RECONSTRUCT_OPTIONS`); every frame
        is read and checked before anything is written."""
        from ..io.data import check_pixels_in_image, load_pixels, pixel_covariance

        o = _opts(op.RECONSTRUCT_OPTIONS, options)
        run = pathlib.Path(o["run"])
        result, info = _load_run(run)
        paths = o["pixels"] if isinstance(o["pixels"], (list, tuple)) else [o["pixels"]]
        stems = [pathlib.Path(p).stem for p in paths]
        if len(set(stems)) < len(stems):
            raise UsageError("frames: two pixel files share a name "
                             f"({', '.join(sorted({s for s in stems if stems.count(s) > 1}))})"
                             "; each frame's point cloud is named after its file")
        frames = []
        for path in paths:
            if pathlib.Path(path).suffix.lower() in mt.FRAME_IMAGE_SUFFIXES:
                frames.append(mt.image_frame(path, o["image_size"], run, info,
                                          center=(result.params.u0, result.params.v0)))
                continue
            pixels, table = load_pixels(path)
            note_flagged(table, len(pixels), "reconstruction")
            size = mt.frame_image_size(o["image_size"], table, run, info)
            check_pixels_in_image(pixels, table, image_size=size, margin=o["image_margin"])
            frames.append((pathlib.Path(path), pixels, pixel_covariance(table)))
        noise = (mt.plain_pixel_noise(result, info, run, o["sigma_px"])
                 if any(f[2] is None for f in frames) else None)
        check_out(o["out"], force=o["force"], inputs=[*paths, run])
        return cls(frames=tuple(frames), result=result, sigma_px=o["sigma_px"],
                   seed=o["seed"], out=pathlib.Path(o["out"]), force=o["force"], run=run,
                   plain_noise=noise)


@dataclass(frozen=True)
class ReportJob:
    """Rebuild the report of a finished calibration run."""

    run: pathlib.Path
    result: object
    run_info: dict
    data: object
    truth: dict | None
    out: pathlib.Path
    force: bool
    plan: object = None

    @classmethod
    def build(cls, **options):
        """Validated job (:data:`~bayescal.cli.options.REPORT_OPTIONS`)."""
        from ..io.data import load_laser_data
        from ..io.planfile import plan_from_record

        o = _opts(op.REPORT_OPTIONS, options)
        run = pathlib.Path(o["run"])
        result, info = _load_run(run)
        ins = info.get("inputs", {})
        sequential = info.get("method") == "sequential"
        if not ins.get("data") and not sequential:
            raise UsageError(f"{run}: the run names no laser data file; nothing to report on")
        try:
            plan = plan_from_record(info.get("plan"))
        except ValueError as exc:
            raise UsageError(f"{run}: {exc}") from None
        data = None
        if ins.get("data"):       # a sequential run may have none: its report has no points
            data = load_laser_data(ins["data"], ins.get("points"),
                                   need_points=not sequential and plan is None)
        if plan is not None:
            data = replace(data, approx_points=None, sigma_scene=None, point_table=None)
        truth = mt.truth_for(o["truth"] or ins.get("truth"), data)
        check_out(o["out"], force=o["force"], inputs=[run] + ([] if data is None else data.paths))
        return cls(run=run, result=result, run_info=info, data=data, truth=truth,
                   out=pathlib.Path(o["out"]), force=o["force"], plan=plan)


@dataclass(frozen=True)
class DemoJob:
    """The main job end to end: simulate the large room, calibrate four ways, report."""

    n_points: int
    max_steps: int | None
    allow_unconverged: bool
    progress: bool
    seed: int
    out: pathlib.Path
    force: bool

    @classmethod
    def build(cls, **options):
        """Validated job (:data:`~bayescal.cli.options.DEMO_OPTIONS`)."""
        o = _opts(op.DEMO_OPTIONS, options)
        if o["n_points"] < MIN_POINTS:
            raise UsageError(f"--n-points {o['n_points']}: expected at least {MIN_POINTS}")
        check_out(o["out"], force=o["force"])
        return cls(n_points=o["n_points"], max_steps=o["max_steps"],
                   allow_unconverged=o["allow_unconverged"], progress=not o["no_progress"],
                   seed=o["seed"], out=pathlib.Path(o["out"]), force=o["force"])


@dataclass(frozen=True)
class StudyJob:
    """Run ``studies/NAME.py`` with ``--out``, ``--quick``, ``--seed``, ``--workers``,
    ``--scheduler`` passed through."""

    name: str
    script: pathlib.Path
    quick: bool
    workers: int
    scheduler: str | None
    seed: int
    out: pathlib.Path
    force: bool

    @classmethod
    def build(cls, **options):
        """Validated job (:data:`~bayescal.cli.options.STUDY_OPTIONS`)."""
        from .studyrun import find_study

        o = _opts(op.STUDY_OPTIONS, options)
        name, script = find_study(o["name"])
        out = pathlib.Path(o["out"] or f"out/study-{name}")
        check_out(out, force=o["force"])
        return cls(name=name, script=script, quick=o["quick"], workers=o["workers"],
                   scheduler=o["scheduler"], seed=o["seed"], out=out, force=o["force"])

    def argv(self, out):
        """The study script's command line, writing into ``out``."""
        cmd = [sys.executable, str(self.script), "--out", str(out), "--seed", str(self.seed),
               "--workers", str(self.workers)]
        if self.quick:
            cmd.append("--quick")
        if self.scheduler:
            cmd += ["--scheduler", self.scheduler]
        return cmd
