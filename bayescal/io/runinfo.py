"""The record of a calibration run: ``run.json`` beside the result file.

A ``bayescal calibrate`` output folder holds the result object (``result.json`` for the
least squares, :meth:`~bayescal.CalibrationResult.save`, or ``posterior.npz`` for the
Bayesian method, :meth:`~bayescal.Posterior.save`) and ``run.json``: the inputs, the noise
settings and where they came from, the image size and where it came from (``reconstruct``
refuses pixels of another size), the seed, the command line, whether the outlier mixture was
on and, for a floor-plan run (``--walls``), the plan itself (``"plan"``: wall segments and
sds, :func:`bayescal.io.planfile.plan_record`) (format ``"bayescal-run"``, versioned).
``bayescal reconstruct`` and ``bayescal report`` load the result object through
:func:`load_run`.
"""

from __future__ import annotations

import json
import pathlib

from ..errors import InvalidValueError

__all__ = ["RUN_FILE", "RESULT_FILE", "POSTERIOR_FILE", "RUN_FORMAT", "RUN_VERSION",
           "run_record", "load_run"]

RUN_FILE = "run.json"
RESULT_FILE = "result.json"
POSTERIOR_FILE = "posterior.npz"
RUN_FORMAT = "bayescal-run"
RUN_VERSION = 1


def run_record(job, **more):
    """The plain-data record of a :class:`~bayescal.cli.jobs.CalibrateJob` (for ``run.json``)."""
    rec = {"format": RUN_FORMAT, "version": RUN_VERSION, "method": job.method,
           "inputs": dict(job.inputs), "sigma_px": job.sigma_px,
           "sigma_px_how": job.sigma_px_how, "sigma_scene": job.sigma_scene_how,
           "image_size": list(job.image_size),
           "image_size_how": getattr(job, "image_size_how", None), "seed": job.seed,
           "command": job.command,
           "nominal": job.nominal.as_dict(), "outliers": bool(job.outliers)}
    if job.plan is not None:
        from .planfile import plan_record

        rec["plan"] = plan_record(job.plan)
        rec["sigma_scene"] = (f"floor plan of {job.plan.n_walls} walls: distance sd "
                              f"{_range_text(job.plan.distance_sd)} mm, angle sd "
                              f"{_range_text(job.plan.angle_sd)} rad")
    rec.update(more)
    return rec


def _range_text(values):
    lo, hi = float(min(values)), float(max(values))
    return f"{lo:.3g}" if lo == hi else f"{lo:.3g}-{hi:.3g}"


def load_run(run):
    """Load the result object and the record of a ``bayescal calibrate`` folder.

    Parameters
    ----------
    run : str or pathlib.Path

    Returns
    -------
    result : CalibrationResult or Posterior
    info : dict
        The ``run.json`` record.

    Raises
    ------
    ValueError
        Not a calibration folder, or a missing, foreign or damaged file (the
        message names it).
    """
    from ..results.calibration import load_result
    from ..results.posterior import load_posterior

    run = pathlib.Path(run)
    rec = run / RUN_FILE
    if not rec.is_file():
        raise InvalidValueError(
            f"not a calibration output folder (no {RUN_FILE}); expected the --out "
            "folder of 'bayescal calibrate'")
    try:
        info = json.loads(rec.read_text(encoding="utf-8"))
    except (UnicodeDecodeError, json.JSONDecodeError) as exc:
        raise InvalidValueError(f"{rec} is damaged (not valid JSON: {exc})") from None
    if not isinstance(info, dict) or info.get("format") != RUN_FORMAT:
        raise InvalidValueError(f"{rec} is not a bayescal run record")
    if info.get("method") == "bayes":
        path = run / POSTERIOR_FILE
        if not path.is_file():
            raise InvalidValueError(f"{path} is missing (the run used method 'bayes')")
        try:
            return load_posterior(path), info
        except Exception as exc:  # noqa: BLE001 (zip, npz and JSON errors of a damaged file)
            raise InvalidValueError(f"{path} is not a readable bayescal posterior file "
                                    f"({type(exc).__name__}: {exc})") from None
    return load_result(run / RESULT_FILE), info
