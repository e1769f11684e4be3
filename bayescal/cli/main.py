"""The ``bayescal`` command line: simulate, calibrate, reconstruct, report, study, demo.

Run ``bayescal --help`` or ``bayescal COMMAND --help``; docs/cli.md has a
worked example and the file formats.

This module only builds the parser and maps exceptions to exit codes. The
options are declared in :mod:`bayescal.cli.options`, each command's validated job
in :mod:`bayescal.cli.jobs`, and running them in :mod:`bayescal.cli.runs` and
:mod:`bayescal.cli.demo`; outputs go through :class:`bayescal.io.outputs.OutputFolder`
(written to a temporary folder, moved into place at the end).

Exit codes: 0 success; 1 the job failed or did not converge (outputs kept for
diagnosis); 2 bad usage or bad input (one line on stderr, nothing written);
130 interrupted (nothing left behind).
"""

from __future__ import annotations

import argparse
import io
import os
import signal
import sys
import threading
import warnings

from ..errors import (
    EXIT_FAILED,
    EXIT_INTERRUPTED,
    EXIT_OK,
    EXIT_USAGE,
    ExtractionError,
    Failure,
    InputError,
    UsageError,
)
from ..io.outputs import MANIFEST
from . import options as op

__all__ = ["main", "console_main", "build_parser", "UsageError", "Failure", "MANIFEST"]

_DESCRIPTION = ("Probabilistic calibration of a catadioptric structured-light sensor: simulate, "
                "calibrate, reconstruct, report, study, demo. Run 'bayescal COMMAND --help' "
                "for each command; docs/cli.md has a worked example and the file formats.")
_EPILOG = ("exit codes: 0 success, 1 failed or did not converge, 2 bad usage or bad input "
           "(nothing written), 130 interrupted (nothing left behind)")


class _Formatter(argparse.ArgumentDefaultsHelpFormatter):
    """Defaults shown, except None/False; descriptions keep their line breaks."""

    def _get_help_string(self, action):
        if action.default is None or action.default is False or action.default is argparse.SUPPRESS:
            return action.help
        if isinstance(action.default, tuple):       # WxH sizes; pairs of numbers (--tilt)
            sep = "x" if action.metavar in ("WxH", "CxR") else " "
            return action.help + " (default: " + sep.join(f"{v:g}" for v in action.default) + ")"
        return super()._get_help_string(action)

    def _fill_text(self, text, width, indent):
        return "\n".join(argparse.HelpFormatter._fill_text(self, p, width, indent)
                         for p in text.split("\n"))


class _Parser(argparse.ArgumentParser):
    """An argparse parser whose usage errors are one line: ``bayescal: error: ...``."""

    def error(self, message):
        print(f"{self.prog}: error: {message}", file=sys.stderr)
        raise SystemExit(EXIT_USAGE)


def _version():
    from .. import __version__

    return f"bayescal {__version__}"


def _study_description():
    from .studyrun import list_studies, studies_dir

    names = list_studies()
    return ("Run studies/NAME.py (beside the package, or in $BAYESCAL_STUDIES_DIR) into --out, "
            "passing --quick, --seed, --workers and --scheduler through.\n"
            f"Available studies in {studies_dir()}: " + (", ".join(names) or "none") + ".")


_COMMANDS = {
    "simulate": (op.SIMULATE_OPTIONS, "simulate a room and write CSV/NPZ inputs and a truth file",
                 "Simulate the paper's room and write laser.csv and laser.npz (u, v, x, y, z, "
                 "sigma_x/y/z, sigma_px), walls.csv (the room's rough floor plan, for "
                 "calibrate --walls), calibration.npz, grid.csv, calib_laser.csv and "
                 "truth.json into --out."),
    "extract": (op.EXTRACT_OPTIONS, "extract laser pixels with covariances from an image",
                "Extract the laser centre line from an image (optionally minus a laser-off "
                "image): one sub-pixel point per azimuth with its 2x2 covariance (px^2), "
                "SNR and a distractor flag. Writes laser.csv (u, v, cov_uu, cov_uv, cov_vv, "
                "snr, flagged) and overlay.png into --out. Several images, a folder or a "
                "video: the ring is followed from frame to frame; laser/<frame>.csv per frame "
                "and frames.csv (a line per frame) instead."),
    "calibrate": (op.CALIBRATE_OPTIONS, "calibrate from laser pixels and approximate points "
                  "or a rough floor plan",
                  "Calibrate the sensor. simultaneous: MAP least squares on pixels and "
                  "approximate points, or a rough floor plan with --walls (the paper's "
                  "method, with weak priors); bayes: the "
                  "posterior (emcee); sequential: the classical two-stage method from "
                  "calibration planes. Writes result.json or posterior.npz, run.json, "
                  "points.csv, PNG figures, report.md and report.html into --out. Every input "
                  "is checked before anything is written."),
    "reconstruct": (op.RECONSTRUCT_OPTIONS, "reconstruct new laser pixels with error bars",
                    "Triangulate laser pixels (CSV or NPZ with u, v) with a calibration run: "
                    "bayes runs average over the posterior, least-squares runs propagate the "
                    "parameter covariance and the pixel noise to first order. Writes "
                    "reconstruction.csv (x, y, z, sds, covariances) and a figure."),
    "report": (op.REPORT_OPTIONS, "rebuild the Markdown/HTML report of a calibration run",
               "Rebuild report.md and the self-contained report.html of a 'bayescal "
               "calibrate' output folder into --out."),
    "calibrate-camera": (op.CALIBRATE_CAMERA_OPTIONS, "calibrate the camera alone from "
                         "chessboard images or corners",
                         "Calibrate the catadioptric camera's intrinsics (xi, gamma_u, "
                         "gamma_v, u0, v0) from views of a chessboard: images (OpenCV "
                         "finds the corners; pip install bayescal[camera]) or a corners "
                         "file. Writes camera.json (the result, for calibrate --camera), "
                         "corners.csv, camera_report.md, camera_report.html and figures "
                         "into --out."),
    "study": (op.STUDY_OPTIONS, "run an uncertainty study from studies/NAME.py", None),
    "demo": (op.DEMO_OPTIONS, "the main job: simulate the paper's large room, calibrate it "
             "five ways, write reports into --out",
             "Simulate the paper's large room (5000 mm, 0.1 px, 5 percent approximate points, "
             "a true sensor drawn off the design values), calibrate it five ways (the pixels "
             "extracted from its rendered laser image on its rough floor plan; the simulated "
             "points sequential, simultaneous and Bayesian; the simulated pixels on the floor "
             "plan) and write the data, the reports and index.html into --out."),
}


def build_parser():
    """The argument parser with its subcommands (options from :mod:`bayescal.cli.options`)."""
    parser = _Parser(prog="bayescal", description=_DESCRIPTION,
                     epilog=_EPILOG, formatter_class=_Formatter)
    parser.add_argument("--version", action="version", version=_version())
    sub = parser.add_subparsers(dest="command", required=True, metavar="COMMAND",
                                parser_class=_Parser)
    for name, (table, short, desc) in _COMMANDS.items():
        p = sub.add_parser(name, help=short, description=desc or _study_description(),
                           epilog=_EPILOG, formatter_class=_Formatter)
        op.add_options(p, table)
    return parser


def _run(args, folders):
    """Build the job of ``args.command`` and run it in a staged output folder.

    The :class:`~bayescal.io.outputs.OutputFolder` is appended to ``folders``, so
    that :func:`main` can tell an interrupt after the commit from one before.
    """
    from ..io.outputs import OutputFolder
    from . import camera, demo, frames, jobs, runs

    o = {k: v for k, v in vars(args).items() if k != "command"}
    build = {"simulate": jobs.SimulateJob, "extract": frames.FramesJob,
             "calibrate": jobs.CalibrateJob,
             "reconstruct": jobs.ReconstructJob, "report": jobs.ReportJob,
             "study": jobs.StudyJob, "demo": jobs.DemoJob,
             "calibrate-camera": camera.CameraJob}[args.command].build
    if args.command == "extract":       # one image, or the frames of a sequence
        build = frames.build_extract
    run = {"simulate": runs.run_simulate, "extract": frames.run_extract,
           "calibrate": runs.run_calibrate,
           "reconstruct": runs.run_reconstruct, "report": runs.run_report,
           "study": demo.run_study, "demo": demo.run_demo,
           "calibrate-camera": camera.run_calibrate_camera}[args.command]
    job = build(**o)
    folders.append(OutputFolder(job.out))
    with folders[-1] as folder:
        failed = run(job, folder)
    if isinstance(failed, tuple):
        failed = failed[0]
    if failed:
        raise Failure(failed)
    return EXIT_OK


class _Mute(io.TextIOBase):
    def write(self, s):
        return len(s)


def _on_sigint(signum, frame):
    """Ctrl-C: silence whatever a library prints while unwinding, then interrupt."""
    sys.stdout = sys.stderr = _Mute()
    raise KeyboardInterrupt


def main(argv=None):
    """Run the command line; returns the exit code (0, 1, 2 or 130)."""
    parser = build_parser()
    try:
        args = parser.parse_args(argv)
    except SystemExit as exc:          # --help/--version (0) or a usage error (2)
        return exc.code if isinstance(exc.code, int) else EXIT_USAGE
    import matplotlib

    matplotlib.use("agg")              # files only, never a window
    stdout, stderr, show = sys.stdout, sys.stderr, warnings.showwarning
    warnings.showwarning = lambda msg, *a, **k: print(f"bayescal: warning: {op.cli_words(msg)}",
                                                      file=stderr)
    old, folders = None, []
    if threading.current_thread() is threading.main_thread():
        old = signal.signal(signal.SIGINT, _on_sigint)
    try:
        return _run(args, folders)
    except (UsageError, InputError) as exc:
        print(f"bayescal: error: {op.cli_words(exc)}", file=stderr)
        return EXIT_USAGE
    except Failure as exc:
        print(f"bayescal: failed: {op.cli_words(exc)}", file=stderr)
        return EXIT_FAILED
    except ExtractionError as exc:          # no plausible laser ring in an image: bad input
        print(f"bayescal: error: {exc.reason}. {op.EXTRACTION_ADVICE}", file=stderr)
        return EXIT_USAGE
    except (ArithmeticError, ValueError) as exc:
        # numpy's LinAlgError is a ValueError; any other ValueError is a bug to show
        if type(exc).__name__ != "LinAlgError" and not isinstance(exc, ArithmeticError):
            raise
        print(f"bayescal: failed: a matrix computation broke down on these data "
              f"({type(exc).__name__}: {exc}); nothing was written. Check the input's sds "
              "(none near zero) and rows (no duplicates)", file=stderr)
        return EXIT_FAILED
    except KeyboardInterrupt:
        sys.stdout.flush()
        done = [f.target for f in folders if f.committed]
        print(f"bayescal: interrupted after {done[0]} was written in full" if done else
              "bayescal: interrupted; nothing was written", file=stderr)
        return EXIT_INTERRUPTED
    except OSError as exc:
        where = f" {exc.filename}" if getattr(exc, "filename", None) else ""
        print(f"bayescal: error: cannot write or read{where}: {exc.strerror or exc}; nothing "
              "was written", file=stderr)
        return EXIT_USAGE
    finally:
        sys.stdout, sys.stderr, warnings.showwarning = stdout, stderr, show
        if old is not None:
            signal.signal(signal.SIGINT, old)


def console_main():
    """Entry point of the ``bayescal`` command and ``python -m bayescal``.

    Runs :func:`main` and exits with its code. After a Ctrl-C, :func:`main` has
    already removed the staged files and printed its line, so the process leaves
    at once through :func:`os._exit` with 130: a plain ``sys.exit(130)`` can
    turn into death by SIGINT (CPython marks an interrupt as unhandled when it
    lands inside ``exec`` of a string, as SciPy's distributions run on import,
    even though :func:`main` caught it), which a caller sees as -2, not 130.
    Otherwise a Ctrl-C during the interpreter's shutdown is ignored: the job is
    over and its files are complete.
    """
    code = main()
    if code == EXIT_INTERRUPTED:
        for stream in (sys.stdout, sys.stderr):
            try:
                stream.flush()
            except (OSError, ValueError):
                pass
        os._exit(code)
    if threading.current_thread() is threading.main_thread():
        signal.signal(signal.SIGINT, signal.SIG_IGN)
    sys.exit(code)
