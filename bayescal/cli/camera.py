"""``bayescal calibrate-camera``: the camera's intrinsics from chessboard views.

:class:`CameraJob` reads every input before anything is written: the images (each must
show the whole board; the first that does not is named, exit 2; a ``--board`` smaller than
the board, its lattice going on past the corners found in most images, is refused, exit 2,
with the size seen) or a corners file.
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
import warnings
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
#: the range of the cross-validation's mean chi-square per direction (2 expected) that honest
#: covariances gave on real and simulated views (docs/camera.md: 1.60, 0.87, 3.13)
CV_RANGE = (1.0, 3.0)
#: the start of the library's warning on intrinsics the views do not determine
_UNDETERMINED = "the views do not determine the camera"


def _detect(paths, board, square, detector):
    """One view per image; the first image without a whole board is a usage error, and so is
    a board option smaller than the board (:func:`_check_extent`)."""
    import bayescal as bc
    from bayescal.image.chessboard import board_extent

    views, sizes, seen = [], {}, []
    for p in paths:
        try:
            view = bc.find_chessboard(p, board=board, square=square, method=detector,
                                      check_extent=False)
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
        seen.append(board_extent(p, view))
    _check_extent(paths, board, seen)
    return views


def _check_extent(paths, board, seen):
    """Refuse ``--board`` smaller than the board seen in most views; warn about a few."""
    import collections

    bigger = [(p, s) for p, s in zip(paths, seen, strict=True) if s != tuple(board)]
    if not bigger:
        return
    size, _ = collections.Counter(s for _, s in bigger).most_common(1)[0]
    names = ", ".join(pathlib.Path(p).name for p, _ in bigger)
    if 2 * len(bigger) > len(paths):
        raise UsageError(f"--board {board[0]}x{board[1]}: the chessboard goes on past the "
                         f"corners found in {len(bigger)} of {len(paths)} images ({names}): "
                         f"{size[0]}x{size[1]} inner corners seen; expected --board "
                         f"{size[0]}x{size[1]} (all the board's inner corners, columns x rows "
                         f"as found; {size[1]}x{size[0]} is the same board turned)")
    warnings.warn(f"{names}: the chessboard seems to go on past the {board[0]}x{board[1]} "
                  f"corners found ({', '.join(f'{a}x{b}' for _, (a, b) in bigger)} seen); "
                  "check those views' corners (camera_report.md)", stacklevel=2)


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


def _crossval_line(cv):
    """The cross-validation's line: its mean chi-square per direction, and a word when it lies
    outside 1-3 (docs/camera.md: honest covariances gave 1.60 on the real views, 0.87 and
    3.13 on two simulations of ten views)."""
    chi2 = float(np.mean(cv["chi2"]))
    line = (f"cross-validation: chi-square per direction {chi2:.2f} (2 expected), "
            f"{len(cv['chi2'])} split(s)")
    if chi2 > CV_RANGE[1]:
        line += ("; above 3: the halves disagree more than their covariances allow (views "
                 "that do not determine the camera, wrong corners, or a noise model that "
                 "misses their errors)")
    elif chi2 < CV_RANGE[0]:
        line += "; below 1: the covariances are wider than the halves' disagreement"
    return line


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

    Returns None, or a failure message (exit 1, files kept) when the views leave an
    intrinsic undetermined (sd at least its value) or a view's residual rms is over 3x the
    median view's: wrong corners pull every intrinsic.
    """
    import bayescal as bc

    from ..report.camera import write_camera_report

    try:
        with warnings.catch_warnings():   # said below, as the exit status
            warnings.filterwarnings("ignore", message=_UNDETERMINED)
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
        print(_crossval_line(cv))
    for f in files:
        print(f"wrote {job.out / f.name}")
    bad = result.unidentified()
    if bad:
        return (f"the views do not determine {', '.join(bad)} (sd >= |value|): check --board "
                "(all the board's inner corners, columns x rows) and --square, and use views "
                "spread over the image (the outputs are kept for diagnosis)")
    suspect = result.model_check()["suspect"]
    if suspect:
        return (f"view(s) {', '.join(suspect)} fit over 3x worse than the median view; check "
                "their corners (the outputs are kept for diagnosis)")
    return None
