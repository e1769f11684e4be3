"""Command-line option values: argparse ``type=`` validators and the option tables.

Every option of every command is declared once, in the tables below
(:data:`SIMULATE_OPTIONS`, :data:`CALIBRATE_OPTIONS`, ...). The parser is built
from them (:func:`add_options`) and so are the defaults a job starts from
(:func:`defaults`), so a new option is added in one place. Each validator
raises :class:`argparse.ArgumentTypeError` with a message that names the value
and what was expected; argparse prefixes the option name.

Imports only the standard library, numpy and :mod:`bayescal.errors`, so that
``bayescal --help`` is instant.
"""

from __future__ import annotations

import argparse
import math
import pathlib
import re
from dataclasses import dataclass, field

__all__ = ["Opt", "add_options", "defaults", "seed", "positive_int", "positive_float",
           "nonneg_float", "image_size", "sigma_px_option", "sigma_scene_option",
           "prior_option", "input_file", "input_folder", "SigmaScene", "distance_sd_option",
           "SIMULATE_OPTIONS", "CALIBRATE_OPTIONS", "RECONSTRUCT_OPTIONS", "REPORT_OPTIONS",
           "STUDY_OPTIONS", "DEMO_OPTIONS", "EXTRACT_OPTIONS", "METHODS", "LASER_MODELS",
           "finite_float", "board_size", "CALIBRATE_CAMERA_OPTIONS", "CAMERA_NOISE",
           "cli_words", "method_option", "EXTRACTION_ADVICE"]

METHODS = ("sequential", "simultaneous", "bayes")
#: what to try when the extractor finds no plausible laser ring, in the command's options
EXTRACTION_ADVICE = ("Try a laser-off image of the same view (--background IMAGE), the centre "
                     "of the mirror's image (--center U V), the ring's radius (--radius LOW "
                     "HIGH, px), or the laser's colour channel (--channel 0/1/2)")
#: other names ``--method`` takes: the simultaneous method is a least-squares fit
_METHOD_ALIASES = {"lsq": "simultaneous", "least-squares": "simultaneous",
                   "least_squares": "simultaneous", "ls": "simultaneous"}
#: ``--model``: the paper's coaxial cone, a tilted and offset one, or the better of both
LASER_MODELS = ("aligned", "misaligned", "auto")
_BAD = argparse.ArgumentTypeError


# -- the library's advice in the command line's words --------------------------------

#: library advice that names Python arguments, and what the command line calls them
_CLI_WORDS = ((re.compile(r"\boutliers=False\b"), "--no-outliers"),
              (re.compile(r"\bgive (sigma_px|sigma_scene|kappa) explicitly"),
               lambda m: "give --sigma-px" if m.group(1) == "sigma_px" else
               "give --sigma-scene"),
              (re.compile(r"\bmax_steps=(\d+)"), r"--max-steps \1"),
              (re.compile(r"\bextract_laser\(along_sd=([\d.]+)\)"),
               r"bayescal extract --along-sd \1"))


def cli_words(text):
    """``text`` (a library message) with its Python arguments named as the command line's
    options, e.g. ``outliers=False`` -> ``--no-outliers``."""
    text = str(text)
    for pattern, repl in _CLI_WORDS:
        text = pattern.sub(repl, text)
    return text


def method_option(text):
    """``--method``: a name of :data:`METHODS`, or ``lsq`` / ``least-squares`` for the
    simultaneous least squares."""
    t = str(text).strip().lower()
    return _METHOD_ALIASES.get(t, t)


# -- validators -------------------------------------------------------------------

def _number(text, what):
    try:
        v = float(text)
    except (TypeError, ValueError):
        raise _BAD(f"could not read {text!r} as a number; expected {what}") from None
    return v


def seed(text):
    """A random seed: an integer >= 0."""
    try:
        v = int(text)
    except (TypeError, ValueError):
        raise _BAD(f"could not read {text!r} as an integer; expected an integer >= 0") from None
    if v < 0:
        raise _BAD(f"{v} is negative; expected an integer >= 0")
    return v


def positive_int(text):
    """An integer >= 1."""
    try:
        v = int(text)
    except (TypeError, ValueError):
        raise _BAD(f"could not read {text!r} as an integer; expected an integer >= 1") from None
    if v < 1:
        raise _BAD(f"{v} is not positive; expected an integer >= 1")
    return v


def positive_float(text):
    """A finite number > 0."""
    v = _number(text, "a finite number > 0")
    if not (math.isfinite(v) and v > 0):
        raise _BAD(f"{text!r} is not a finite positive number; expected a number > 0")
    return v


def nonneg_float(text):
    """A finite number >= 0."""
    v = _number(text, "a finite number >= 0")
    if not (math.isfinite(v) and v >= 0):
        raise _BAD(f"{text!r} is not a finite number >= 0")
    return v


def image_size(text):
    """``WIDTHxHEIGHT`` in px, both positive integers, as a tuple."""
    try:
        w, h = (int(s) for s in str(text).lower().split("x"))
    except ValueError:
        raise _BAD(f"{text!r}: expected WIDTHxHEIGHT in px, like 800x600") from None
    if w <= 0 or h <= 0:
        raise _BAD(f"{text!r}: expected a positive width and height in px, like 800x600")
    return w, h


def sigma_px_option(text):
    """Pixel noise: a positive number of px, or ``infer`` (returned as the string)."""
    if str(text).strip().lower() == "infer":
        return "infer"
    return positive_float(text)


@dataclass(frozen=True)
class SigmaScene:
    """A parsed ``--sigma-scene``: ``kind`` in {"infer", "percent", "mm"} and its values.

    ``values`` is the percentage (kind "percent"), or one or three sd in mm
    (``inf`` allowed, kind "mm").
    """

    kind: str
    values: tuple = ()
    text: str = ""


def sigma_scene_option(text):
    """``infer``, a number of mm, ``sx,sy,sz`` (``inf`` allowed) or a percentage ``P%``."""
    t = str(text).strip().lower()
    if t == "infer":
        return SigmaScene("infer", (), text)
    if t.endswith("%"):
        return SigmaScene("percent", (positive_float(t[:-1]),), text)
    parts = [p.strip() for p in t.split(",")]
    if len(parts) not in (1, 3):
        raise _BAD(f"{text!r}: expected 'infer', a number of mm, 'sx,sy,sz' or a percentage "
                   "like 5%")
    vals = tuple(math.inf if p == "inf" else positive_float(p) for p in parts)
    if not any(math.isfinite(v) for v in vals):
        raise _BAD(f"{text!r} gives no information on any axis; expected at least one finite sd")
    return SigmaScene("mm", vals, text)


def distance_sd_option(text):
    """A wall-distance sd: a number of mm, or a percentage ``P%`` of each wall's distance.

    Returns a float (mm) or ``("percent", P)``.
    """
    t = str(text).strip()
    if t.endswith("%"):
        return ("percent", positive_float(t[:-1]))
    return positive_float(t)


_PRIOR_RE = re.compile(r"^\s*(\w+)\s*=\s*(\w+)\s*\((.*)\)\s*$")


def prior_option(text):
    """``NAME=DIST(ARGS)``: returns ``(name, frozen scipy.stats distribution)``.

    ``NAME`` is one of the eight parameters or of the laser pose's four
    (``tilt_x, tilt_y`` in rad, ``offset_x, offset_y`` in mm; ``--model misaligned``).
    """
    from scipy import stats

    from ..sensor.parameters import PARAM_NAMES
    from ..sensor.pose import POSE_NAMES

    m = _PRIOR_RE.match(str(text))
    if not m:
        raise _BAD(f"{text!r}: expected NAME=DIST(ARGS), e.g. 'h=norm(200, 20)'")
    name, dist, argtext = m.groups()
    if name not in PARAM_NAMES + POSE_NAMES:
        raise _BAD(f"{text!r}: unknown parameter {name!r}; expected one of "
                   + ", ".join(PARAM_NAMES + POSE_NAMES))
    family = getattr(stats, dist, None)
    if not isinstance(family, stats.rv_continuous):
        raise _BAD(f"{text!r}: {dist!r} is not a scipy.stats continuous distribution "
                   "(e.g. norm, uniform, truncnorm, lognorm)")
    try:
        frozen = family(*[float(a) for a in argtext.split(",") if a.strip()])
        sd = float(frozen.std())
    except (TypeError, ValueError) as exc:
        raise _BAD(f"{text!r}: bad arguments for {dist} ({exc})") from None
    if not (math.isfinite(sd) and sd > 0):
        raise _BAD(f"{text!r}: the distribution has sd {sd}; expected a finite positive sd")
    return name, frozen


def finite_float(text):
    """A finite number."""
    v = _number(text, "a finite number")
    if not math.isfinite(v):
        raise _BAD(f"{text!r} is not finite; expected a finite number")
    return v


def radius_range(values):
    """``--radius LOW HIGH`` as ``(low, high)`` px, or None; exit 2 unless LOW < HIGH."""
    if values is not None and not float(values[0]) < float(values[1]):
        from ..errors import UsageError
        raise UsageError(f"--radius {values[0]:g} {values[1]:g}: expected LOW < HIGH (px)")
    return None if values is None else (float(values[0]), float(values[1]))


def input_file(text):
    """An existing, readable file."""
    p = pathlib.Path(text)
    if not p.exists():
        raise _BAD(f"{text}: no such file")
    if not p.is_file():
        raise _BAD(f"{text} is not a file")
    return p


def input_folder(text):
    """An existing folder."""
    p = pathlib.Path(text)
    if not p.is_dir():
        raise _BAD(f"{text}: no such folder")
    return p


# -- option tables ----------------------------------------------------------------

@dataclass(frozen=True)
class Opt:
    """One command-line option: argparse flags and keyword arguments."""

    flags: tuple
    kw: dict = field(default_factory=dict)

    @property
    def dest(self):
        """The attribute name argparse gives the value."""
        if "dest" in self.kw:
            return self.kw["dest"]
        name = self.flags[-1] if self.flags[0].startswith("-") else self.flags[0]
        return name.lstrip("-").replace("-", "_")


def add_options(parser, options):
    """Add every :class:`Opt` of ``options`` to an argparse parser."""
    for o in options:
        parser.add_argument(*o.flags, **o.kw)


def defaults(options):
    """``{dest: default}`` of an option table (what an empty command line gives)."""
    out = {}
    for o in options:
        d = o.kw.get("default")
        if o.kw.get("action") == "store_true":
            d = bool(d)
        elif o.kw.get("action") == "append":
            d = list(d or [])
        out[o.dest] = d
    return out


def _out(default):
    return (Opt(("--out",), {"default": default, "help": "output folder; must be new or "
                             "empty unless --force"}),
            Opt(("--force",), {"action": "store_true", "help": "replace the files bayescal "
                               "wrote earlier in --out (never any other file)"}))


_SEED = Opt(("--seed",), {"type": seed, "default": 0, "help": "random seed, an integer >= 0"})
_IMAGE = (Opt(("--image-size",), {"type": image_size, "metavar": "WxH",
                                  "help": "image width x height in px (default: the data "
                                  "file's '# image_size: WxH' line, which extract writes, "
                                  "else 800x600, the paper's sensor); pixels further than "
                                  "--image-margin outside it are rejected as bad input; "
                                  "another size centres the design values on it "
                                  "(docs/cli.md)"}),
          Opt(("--image-margin",), {"type": nonneg_float, "default": 50.0, "metavar": "PX",
                                    "help": "tolerance around the image, px"}))

SIMULATE_OPTIONS = (
    Opt(("--range-mm",), {"type": positive_float, "default": 5000.0,
                          "help": "scene size in mm (paper: 1000 small, 5000 large)"}),
    Opt(("--n-points",), {"type": positive_int, "default": 580, "help": "laser points"}),
    Opt(("--n-walls",), {"type": positive_int, "default": 7, "help": "walls"}),
    Opt(("--sigma-px",), {"type": positive_float, "default": 0.1, "help": "pixel noise, px"}),
    Opt(("--approx-error",), {"type": nonneg_float, "default": 0.05,
                              "help": "relative error of the approximate points (0.05 is 5 "
                              "percent)"}),
    Opt(("--approx-model",), {"default": "fig9", "choices": ("fig9", "wall", "gaussian"),
                              "help": "how approximate points are made (fig9: the paper's "
                              "protocol)"}),
    Opt(("--sigma-3d",), {"type": nonneg_float, "default": 0.0,
                          "help": "extra 3D measurement noise, mm"}),
    Opt(("--tilt",), {"type": finite_float, "nargs": 2, "default": (0.0, 0.0),
                      "metavar": ("TX", "TY"), "help": "tilt of the laser cone about x and "
                      "y, degrees (a misaligned sensor; docs/conventions.md)"}),
    Opt(("--offset",), {"type": finite_float, "nargs": 2, "default": (0.0, 0.0),
                        "metavar": ("OX", "OY"), "help": "offset of the laser cone's apex "
                        "from the camera axis along x and y, mm"}),
    Opt(("--image-size",), {"type": image_size, "default": (800, 600), "metavar": "WxH",
                            "help": "the camera's image, width x height in px: another than "
                            "the paper's 800x600 centres the sensor on it and scales its "
                            "focal length by min(W, H) / 600"}),
    Opt(("--images",), {"action": "store_true", "help": "also render the room's camera "
                        "images: image.png (16-bit, laser on, lamps and a ghost), "
                        "image_off.png (laser off) and ring.csv (the true centre line)"}),
    *_out("sim"), _SEED,
)

CALIBRATE_OPTIONS = (
    Opt(("data",), {"nargs": "?", "type": input_file, "default": None,
                    "help": "CSV or NPZ with u, v (px) and x, y, z (mm); optional sigma_x, "
                    "sigma_y, sigma_z (mm, empty or inf = unknown axis) and sigma_px (px)"}),
    Opt(("--points",), {"type": input_file, "help": "separate CSV/NPZ with x, y, z (and sigma "
                        "columns), same rows as the data file"}),
    Opt(("--walls",), {"type": input_file, "metavar": "CSV", "help": "a rough floor plan in "
                       "place of approximate points: CSV with x0, y0, x1, y1 (mm, one wall a "
                       "line, counterclockwise around the sensor) and optional distance_sd "
                       "(mm), angle_sd (rad); the data file then needs only u, v"}),
    Opt(("--distance-sd",), {"type": distance_sd_option, "default": "5%", "metavar": "SD",
                             "help": "--walls without a distance_sd column: sd of each wall's "
                             "distance from the axis, mm or a percentage of it like '5%%'"}),
    Opt(("--angle-sd",), {"type": positive_float, "default": 0.01, "metavar": "RAD",
                          "help": "--walls without an angle_sd column: sd of each wall's "
                          "orientation, rad"}),
    Opt(("--ring-corr",), {"type": positive_float, "metavar": "DEG", "help": "--walls, --method "
        "simultaneous: errors of neighbouring ring points correlated as exp(-lag/DEG); widens "
        "the intervals (1 measured for extract's points, docs/floorplan.md)"}),
    Opt(("--no-outliers",), {"action": "store_true", "help": "no outlier mixture: every "
                             "point is an inlier (default: each point may be an outlier, "
                             "see outlier_prob in points.csv)"}),
    Opt(("--method",), {"type": method_option, "choices": METHODS, "default": "simultaneous",
                        "help": "calibration method (lsq: the simultaneous least squares)"}),
    Opt(("--model",), {"choices": LASER_MODELS, "default": "aligned",
                       "help": "laser model: aligned (the paper's cone, coaxial with the "
                       "camera), misaligned (its tilt and offset fitted too: four more "
                       "unknowns, priors 0 +- 2 deg and 0 +- 5 mm, --prior tilt_x=... to "
                       "change them), auto (fit both by least squares and keep the one with "
                       "the larger Laplace evidence); misaligned and auto need approximate "
                       "points or --walls with --method simultaneous or bayes"}),
    Opt(("--calibration",), {"type": input_file, "help": "sequential: NPZ with "
                             "CalibrationData fields, or grid CSV (plane, u, v, x, y, z)"}),
    Opt(("--calibration-laser",), {"type": input_file, "help": "sequential with a grid CSV: "
                                   "CSV of the laser on the planes (plane, u, v)"}),
    Opt(("--sigma-px",), {"type": sigma_px_option, "help": "pixel noise in px, or 'infer' "
                          "(default: the file's sigma_px column, else infer)"}),
    Opt(("--sigma-scene",), {"type": sigma_scene_option, "help": "sd of the approximate "
                             "points: mm, 'sx,sy,sz' (inf allowed), a percentage of each "
                             "point's horizontal range like '5%%', or 'infer' (default: the "
                             "file's sigma columns, else infer)"}),
    Opt(("--nominal",), {"type": input_file, "metavar": "JSON", "help": "design values "
                         "(JSON object, or one with a 'params' object) of any of the 8 "
                         "parameters, e.g. {\"u0\": 640, \"v0\": 512}; they centre the default "
                         "priors. The rest: the paper's sensor for an 800x600 image, else "
                         "derived from the image size and the data (docs/cli.md)"}),
    Opt(("--camera",), {"type": pathlib.Path, "metavar": "PATH", "help": "a camera calibrated "
                        "beforehand: the camera.json of 'bayescal calibrate-camera' or its "
                        "folder. Its intrinsics and their covariance become the prior of xi, "
                        "gamma_u, gamma_v, u0, v0 (the laser data refine them), its values the "
                        "nominal camera and its image size --image-size; --nominal then gives "
                        "phi, h and beta. sequential: stage 2 runs on it"}),
    Opt(("--prior",), {"type": prior_option, "action": "append", "metavar": "NAME=DIST(ARGS)",
                       "help": "override one prior with a scipy.stats distribution, e.g. "
                       "'h=norm(200, 20)', or with --model misaligned/auto one of the laser "
                       "pose's (tilt_x, tilt_y in rad, offset_x, offset_y in mm), e.g. "
                       "'tilt_x=norm(0, 0.01)'; repeatable"}),
    Opt(("--truth",), {"type": input_file, "metavar": "JSON", "help": "truth.json of a "
                       "simulation: adds the truth and the mean 3D error to the report"}),
    Opt(("--max-steps",), {"type": positive_int, "metavar": "N", "help": "bayes: limit on the "
                           "chain length in steps (default: the sampler's); convergence needs "
                           "50 autocorrelation times"}),
    Opt(("--no-progress",), {"action": "store_true", "help": "no progress bar"}),
    Opt(("--allow-unconverged",), {"action": "store_true", "help": "bayes: exit 0 even if "
                                   "the chains are too short for convergence"}),
    *_IMAGE, *_out("out"), _SEED,
)

RECONSTRUCT_OPTIONS = (
    Opt(("pixels",), {"type": input_file, "nargs": "+", "metavar": "PIXELS",
                      "help": "one file per frame: a CSV or NPZ with columns u, v (px) and "
                              "optionally cov_uu, cov_uv, cov_vv (px^2, per-pixel noise), or "
                              "an image (PNG, TIFF, JPEG, PGM) run through the laser extractor"}),
    Opt(("--run",), {"type": input_folder, "required": True,
                     "help": "output folder of 'bayescal calibrate'"}),
    Opt(("--sigma-px",), {"type": nonneg_float, "help": "pixel noise of pixels without cov_* "
                          "columns, px, 0: parameters alone (default: the run's; after "
                          "covariances, their typical noise times the run's scale)"}),
    *_IMAGE, *_out("reconstruction"), _SEED,
)

REPORT_OPTIONS = (
    Opt(("run",), {"type": input_folder, "help": "output folder of 'bayescal calibrate'"}),
    Opt(("--truth",), {"type": input_file, "metavar": "JSON",
                       "help": "truth.json of a simulation"}),
    *_out("report"),
)

DEMO_OPTIONS = (
    Opt(("--n-points",), {"type": positive_int, "default": 580, "help": "laser points"}),
    Opt(("--max-steps",), {"type": positive_int, "metavar": "N",
                           "help": "limit on the sampler's chain length (default: the "
                           "sampler's)"}),
    Opt(("--allow-unconverged",), {"action": "store_true",
                                   "help": "do not count a too-short chain as a failure"}),
    Opt(("--no-progress",), {"action": "store_true", "help": "no progress bar"}),
    *_out("out"), _SEED,
)

EXTRACT_OPTIONS = (
    Opt(("image",), {"type": pathlib.Path, "nargs": "+", "metavar": "IMAGE", "help": "image "
                     "with the laser on (PNG, TIFF, JPEG, 8/16 bit, grey or colour); several, "
                     "a folder or a video: frames of a sequence, the ring followed from "
                     "frame to frame (docs/images.md)"}),
    Opt(("--background",), {"type": input_file, "metavar": "IMAGE", "help": "the same view "
                             "with the laser off, subtracted first (advised on textured walls)"}),
    Opt(("--center",), {"type": finite_float, "nargs": 2, "metavar": ("U", "V"),
                        "help": "centre of the radial profiles, px (default: fitted)"}),
    Opt(("--radius",), {"type": nonneg_float, "nargs": 2, "metavar": ("LOW", "HIGH"),
                        "help": "the ring's radius about the centre lies between LOW and "
                        "HIGH px (default: searched over the mirror's image)"}),
    Opt(("--channel",), {"type": int, "default": 0, "choices": (0, 1, 2),
                         "help": "colour channel of the laser (0 red, 1 green, 2 blue)"}),
    Opt(("--along-sd",), {"type": positive_float, "default": 5.0, "metavar": "PX",
                          "help": "sd given to each point along the ring, px (default 5; 1 for "
                          "a floor-plan calibration, docs/images.md)"}),
    Opt(("--no-progress",), {"action": "store_true", "help": "no progress bar (frames)"}),
    *_out("extract"),
)

STUDY_OPTIONS = (
    Opt(("name",), {"help": "study name (see the list above)"}),
    Opt(("--quick",), {"action": "store_true", "help": "a short version of the study"}),
    Opt(("--workers",), {"type": positive_int, "default": 2,
                         "help": "local worker processes (1 runs inline)"}),
    Opt(("--scheduler",), {"metavar": "ADDRESS", "help": "address of a Dask distributed "
                           "scheduler to run the trials on, e.g. tcp://127.0.0.1:8786"}),
    *_out(None), _SEED,
)


# -- calibrate-camera (the camera alone, from chessboard views) -------------------

def board_size(text):
    """``COLUMNSxROWS`` inner corners of a chessboard, both integers >= 2, as a tuple."""
    try:
        nx, ny = (int(s) for s in str(text).lower().split("x"))
    except ValueError:
        raise _BAD(f"{text!r}: expected COLUMNSxROWS of inner corners, like 8x6") from None
    if nx < 2 or ny < 2:
        raise _BAD(f"{text!r}: expected at least 2x2 inner corners, like 8x6")
    return nx, ny


#: noise models of calibrate-camera (bayescal.calibrate_camera's ``noise``)
CAMERA_NOISE = ("view-systematic", "per-view", "plain")

CALIBRATE_CAMERA_OPTIONS = (
    Opt(("images",), {"type": input_file, "nargs": "*", "metavar": "IMAGE",
                      "help": "chessboard images (PGM, PNG, TIFF, JPEG; 8 or 16 bit; any size, "
                      "all the same), one view each; every one must show the whole board"}),
    Opt(("--corners",), {"type": input_file, "metavar": "FILE", "help": "instead of images: "
                         "a CSV or NPZ of corners (view, u, v, x, y, z [, cov_uu, cov_uv, "
                         "cov_vv]; docs/cli.md)"}),
    Opt(("--board",), {"type": board_size, "default": (8, 6), "metavar": "CxR",
                       "help": "inner corners of the board, columns x rows"}),
    Opt(("--square",), {"type": positive_float, "default": 42.0, "metavar": "MM",
                        "help": "side of a square, mm"}),
    Opt(("--detector",), {"choices": ("classic", "sb"), "default": "classic",
                          "help": "OpenCV's findChessboardCorners + cornerSubPix (classic) "
                          "or findChessboardCornersSB (sb)"}),
    Opt(("--noise",), {"choices": CAMERA_NOISE, "default": CAMERA_NOISE[0],
                       "help": "noise model of the corners: per-view noise and a per-view "
                       "systematic field (view-systematic), per-view noise only, or one "
                       "noise level (plain least squares)"}),
    Opt(("--no-cross-validation",), {"action": "store_true", "help": "skip the cross-"
        "validation between halves of the views (two fits per split, at most 10 splits)"}),
    *_out("camera"),
)
