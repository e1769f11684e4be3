"""``params.csv``: the parameter table of a calibration run, the laser pose included.

One line per parameter: the eight sensor parameters and, with the misaligned laser
model, the laser cone's pose (``tilt_x, tilt_y`` rad, ``offset_x, offset_y`` mm;
``docs/conventions.md``). Columns ``name, unit, value, sd, q05, q95``: the estimate
(least squares) or posterior mean, its sd and the 90 % interval (normal for least
squares, sample quantiles for a posterior). :func:`pose_rows` is also what the
report's pose table reads.
"""

from __future__ import annotations

import csv
import pathlib

import numpy as np

from ..constants import Z90
from ..sensor.pose import POSE_NAMES

__all__ = ["pose_rows", "write_params_csv", "PARAM_UNITS", "POSE_UNITS"]

#: unit of each sensor parameter ("" dimensionless)
PARAM_UNITS = {"xi": "", "phi": "", "alpha_u": "px", "alpha_v": "px", "u0": "px", "v0": "px",
               "h": "mm", "beta": "rad"}
#: unit of each laser-pose coordinate
POSE_UNITS = {"tilt_x": "rad", "tilt_y": "rad", "offset_x": "mm", "offset_y": "mm"}


def pose_rows(result):
    """The laser pose of a result as rows ``name, unit, mean, sd, q05, q95`` (rad, mm).

    Parameters
    ----------
    result : CalibrationResult or Posterior

    Returns
    -------
    list of dict
        Four rows (``POSE_NAMES`` order) with the misaligned model; empty with the
        aligned one (the pose is then zero by assumption, not estimated).
    """
    if getattr(result, "model", "aligned") != "misaligned":
        return []
    if hasattr(result, "laser_samples"):
        x = np.asarray(result.laser_samples, float)
        mean, sd = x.mean(axis=0), x.std(axis=0, ddof=1)
        q05, q95 = np.quantile(x, [0.05, 0.95], axis=0)
    else:
        mean = result.laser.to_array()
        cov = np.asarray(result.covariance(identifiable=True), float)[-4:, -4:]
        sd = np.sqrt(np.maximum(np.diag(cov), 0.0))
        q05, q95 = mean - Z90 * sd, mean + Z90 * sd
    return [{"name": n, "unit": POSE_UNITS[n], "mean": float(mean[k]), "sd": float(sd[k]),
             "q05": float(q05[k]), "q95": float(q95[k])} for k, n in enumerate(POSE_NAMES)]


def write_params_csv(path, rows, pose, *, model="aligned"):
    """Write ``params.csv``.

    Parameters
    ----------
    path : str or pathlib.Path
    rows : list of dict
        The eight parameters' rows (``name, mean, sd, q05, q95``), as
        ``result.summary_rows()`` gives them.
    pose : list of dict
        :func:`pose_rows` (empty for the aligned model).
    model : {"aligned", "misaligned"}
        The laser model, named in the header comment.

    Returns
    -------
    pathlib.Path
    """
    path = pathlib.Path(path)
    with open(path, "w", newline="", encoding="utf-8") as f:
        f.write(f"# bayescal calibrate: parameters, laser model {model}; value: estimate or "
                "posterior mean; q05, q95: 90 % interval\n")
        if not pose:
            f.write("# the laser pose (tilt_x, tilt_y, offset_x, offset_y) is zero by "
                    "assumption in the aligned model\n")
        w = csv.writer(f, lineterminator="\n")
        w.writerow(["name", "unit", "value", "sd", "q05", "q95"])
        for r in list(rows) + list(pose):
            unit = r.get("unit", PARAM_UNITS.get(r["name"], ""))
            w.writerow([r["name"], unit] + [repr(float(r[k])) for k in ("mean", "sd", "q05",
                                                                          "q95")])
    return path
