"""``bayescal calibrate-camera``: the camera's intrinsics from chessboard views.

:class:`CameraJob` reads every input before anything is written: the images (each must
show the whole board; the first that does not is named, exit 2) or a corners file.
:func:`run_calibrate_camera` calibrates (:func:`bayescal.calibrate_camera`), cross-validates
between halves of the views and writes, into ``--out``:

``camera.json`` (:data:`CAMERA_FILE`)
    the :class:`~bayescal.CameraResult` (:func:`bayescal.load_camera` reads it; so does
    ``bayescal calibrate --camera OUT/camera.json``);
``corners.csv``
    the corners used, one line per corner (:func:`bayescal.load_views` reads it; pass it
    back with ``--corners`` to calibrate again without detecting);
``camera_report.md``, ``camera_report.html`` and the report's figures: ``view_residuals.png``,
``image_residuals.png`` and (with 4 or more views) ``crossval.png``.
"""

from __future__ import annotations

import pathlib
import shlex
import sys
from dataclasses import dataclass

import numpy as np

from ..errors import DegenerateInputError, Failure, InputError, UsageError
from ..io.outputs import check_out
from . import options as op
from .jobs import _opts
from .lasermodel import CAMERA_FILE

__all__ = ["CameraJob", "run_calibrate_camera", "CAMERA_FILE", "CORNERS_FILE"]

#: the corners used, in the format of bayescal.load_views
CORNERS_FILE = "corners.csv"
#: most splits of the views in the cross-validation (each calibrates twice)
MAX_SPLITS = 10


def _detect(paths, board, square, detector):
    """One view per image; the first image without a whole board is a usage error."""
    import bayescal as bc

    views, sizes = [], {}
    for p in paths:
        try:
            view = bc.find_chessboard(p, board=board, square=square, method=detector)
        except ImportError as exc:
            raise UsageError(str(exc)) from None
        except (ValueError, TypeError) as exc:
            raise UsageError(f"IMAGE {p}: {exc}") from None
        if view is None:
            raise UsageError(f"{p}: no {board[0]}x{board[1]} chessboard found (every image "
                             "must show all the inner corners of the board; check --board, "
                             "or leave the image out)")
        sizes.setdefault(view.image_size, p)
        if len(sizes) > 1:
            (s0, p0), (s1, p1) = list(sizes.items())[:2]
            raise UsageError(f"{p1} is {s1[0]}x{s1[1]} px but {p0} is {s0[0]}x{s0[1]}; "
                             "expected images of one camera, all the same size")
        views.append(view)
    return views


@dataclass(frozen=True)
class CameraJob:
    """A camera calibration with its views read; options as in ``CALIBRATE_CAMERA_OPTIONS``."""

    views: tuple
    inputs: tuple
    board: tuple
    square: float
    noise: str
    cross_validation: bool
    out: pathlib.Path
    force: bool = False
    command: str = ""

    @classmethod
    def build(cls, **options):
        """Validated job: every image searched, or the corners file read, before any output."""
        from ..io.boards import load_views

        o = _opts(op.CALIBRATE_CAMERA_OPTIONS, options)
        images = [pathlib.Path(p) for p in (o["images"] or [])]
        if bool(images) == (o["corners"] is not None):
            raise UsageError("give either IMAGE files or --corners FILE (one of the two)")
        inputs = images or [pathlib.Path(o["corners"])]
        check_out(o["out"], force=o["force"], inputs=inputs)
        if images:
            views = _detect(images, tuple(o["board"]), float(o["square"]), o["detector"])
        else:
            views = load_views(o["corners"])
        if len(views) < 2:
            raise UsageError(f"{len(views)} view(s); expected at least 2 views of the board "
                             "(several poses, spread over the image)")
        return cls(views=tuple(views), inputs=tuple(str(p) for p in inputs),
                   board=tuple(o["board"]), square=float(o["square"]), noise=o["noise"],
                   cross_validation=not o["no_cross_validation"], out=pathlib.Path(o["out"]),
                   force=bool(o["force"]),
                   command=" ".join(shlex.quote(a) for a in ["bayescal", *sys.argv[1:]]))


def _crossval(job):
    from ..validation.camera_cv import all_splits, halves_chi2

    if not job.cross_validation or len(job.views) < 4:
        return None
    splits = all_splits(len(job.views), max_splits=MAX_SPLITS)
    return halves_chi2(list(job.views), splits, noise=job.noise)


def _figures(folder, result, views, cv):
    """The report's figures as (caption, PNG path) pairs."""
    from ..plotting.basic import savefig
    from ..plotting.camera import plot_image_residuals, plot_view_residuals
    from ..plotting.camera_cv import plot_halves_chi2

    figs = [("Residuals of each view (u and v pooled) against two of its noise sds",
             folder / "view_residuals.png"),
            ("Residuals over the image, magnified 100 times",
             folder / "image_residuals.png")]
    savefig(plot_view_residuals(result), figs[0][1])
    savefig(plot_image_residuals(result, list(views)), figs[1][1])
    if cv is not None:
        path = folder / "crossval.png"
        savefig(plot_halves_chi2(cv), path)
        figs.append(("Cross-validation: each split's chi-square per direction (2 expected) "
                     "and the mean shift between the two halves' projections", path))
    return figs


def run_calibrate_camera(job, folder):
    """Calibrate, cross-validate and write the files listed in the module docstring.

    Returns None, or a failure message (exit 1, files kept) when a view's residual rms is
    over 3x the median view's: wrong corners pull every intrinsic.
    """
    import bayescal as bc

    from ..report.camera import write_camera_report

    try:
        result = bc.calibrate_camera(list(job.views), noise=job.noise)
        cv = _crossval(job)
    except (DegenerateInputError, InputError, ValueError) as exc:
        raise UsageError(str(exc)) from None       # calibrate_camera names the bad view
    except np.linalg.LinAlgError as exc:
        raise Failure(f"the calibration broke down on these views ({exc})") from None
    p = folder.path
    result.save(p / CAMERA_FILE)
    bc.write_views(p / CORNERS_FILE, job.views)
    names = [pathlib.Path(s).name for s in job.inputs]
    figures = _figures(p, result, job.views, cv)
    files = [p / CAMERA_FILE, p / CORNERS_FILE, *(f for _, f in figures)]
    files += write_camera_report(p, result, crossval=cv, inputs=names, figures=figures)
    folder.add(*files)
    print(result.summary())
    if cv is not None:
        print(f"cross-validation: chi-square per direction {cv['chi2'].mean():.2f} "
              f"(2 expected), {len(cv['chi2'])} split(s)")
    for f in files:
        print(f"wrote {job.out / f.name}")
    suspect = result.model_check()["suspect"]
    if suspect:
        return (f"view(s) {', '.join(suspect)} fit over 3x worse than the median view; check "
                "their corners (the outputs are kept for diagnosis)")
    return None
