"""Checks of calibration inputs made while a job is built (before anything is written).

:func:`load_truth` reads a simulation's truth file, :func:`check_geometry`
refuses laser data that cannot determine the sensor, :func:`warn_duplicates`
names exact duplicate lines, :func:`library_messages` shows the library's
input warnings and noise-collapse errors with file line numbers, and
:func:`flagged_lines` maps outlier flags to file lines. Every refusal is a
:class:`~bayescal.errors.UsageError` (exit code 2) naming the file and line.
"""

from __future__ import annotations

import contextlib
import re
import warnings

import numpy as np

from ..errors import UsageError

__all__ = ["load_truth", "check_geometry", "warn_duplicates", "sigma_px_setting",
           "sigma_scene_setting", "library_messages", "flagged_lines", "MIN_POINTS",
           "MIN_AZIMUTH_SPAN_DEG", "OUTLIER_FLAG", "rows_to_lines", "noise_collapse_message",
           "flagged_text", "located_summary", "runs_lines_text"]

#: outlier probability above which an input line is listed as flagged
OUTLIER_FLAG = 0.5

#: fewest laser points a calibration accepts: 2 N pixel coordinates must exceed the
#: 7 identifiable parameters plus the 2 noise levels that may be inferred
MIN_POINTS = 5
#: smallest azimuth span (degrees) of the laser points: points on one azimuth leave
#: the principal point and the ring radii undetermined
MIN_AZIMUTH_SPAN_DEG = 10.0


def load_truth(path, n_points=None):
    """Read a ``truth.json`` written by ``bayescal simulate``; check its shape.

    Parameters
    ----------
    path : path or None
    n_points : int, optional
        Number of laser points of the data it goes with.

    Returns
    -------
    dict or None
    """
    if path is None:
        return None
    from ..io.data import read_json
    from ..sensor.parameters import PARAM_NAMES

    truth = read_json(path)
    if not isinstance(truth, dict) or not isinstance(truth.get("params"), dict):
        raise UsageError(f"--truth {path}: expected a JSON object with 'params' (as written by "
                         "bayescal simulate)")
    missing = [n for n in PARAM_NAMES if n not in truth["params"]]
    if missing:
        raise UsageError(f"--truth {path}: 'params' lacks {', '.join(missing)}")
    pts = truth.get("points")
    if pts is not None:
        shape = np.shape(pts)
        if len(shape) != 2 or shape[1] != 3:
            raise UsageError(f"--truth {path}: 'points' has shape {shape}; expected (N, 3)")
        if n_points is not None and shape[0] != n_points:
            raise UsageError(f"--truth {path}: it has {shape[0]} points but the data have "
                             f"{n_points}; expected the truth of the same simulation")
    return truth


def check_geometry(data, center=None):
    """Refuse laser data that cannot determine the sensor, before any fitting.

    Parameters
    ----------
    data : LaserData
    center : (float, float), optional
        Nominal principal point ``(u0, v0)``, px: without approximate points
        (a floor plan) the azimuths are the pixels' around it.

    Raises
    ------
    UsageError
        Fewer than :data:`MIN_POINTS` points, or points spanning less than
        :data:`MIN_AZIMUTH_SPAN_DEG` of azimuth.
    """
    where = ", ".join(map(str, data.paths))
    if data.n_points < MIN_POINTS:
        raise UsageError(f"{where}: {data.n_points} laser point(s); expected at least "
                         f"{MIN_POINTS} (2 N pixel coordinates must exceed the 7 identifiable "
                         "parameters and the noise levels)")
    if data.approx_points is not None:
        x, y = data.approx_points[:, 0], data.approx_points[:, 1]
    elif center is not None:
        x, y = data.pixels[:, 0] - center[0], data.pixels[:, 1] - center[1]
    else:
        return
    az = np.sort(np.mod(np.arctan2(y, x), 2 * np.pi))
    gaps = np.diff(np.concatenate([az, az[:1] + 2 * np.pi]))
    span = np.degrees(2 * np.pi - gaps.max())
    if span < MIN_AZIMUTH_SPAN_DEG:
        raise UsageError(f"{where}: the laser points span {span:.2g} degrees of azimuth; "
                         f"expected at least {MIN_AZIMUTH_SPAN_DEG:g} (points on one azimuth "
                         "leave the principal point and the ring radii undetermined)")


def sigma_px_setting(value, data):
    """The pixel noise a job uses (px or None = inferred) and where it came from."""
    if value is None:
        if data.sigma_px is not None:
            return data.sigma_px, "from the file"
        return None, "inferred"
    if value == "infer":
        return None, "inferred"
    return float(value), "given"


def sigma_scene_setting(spec, data):
    """The scene sds (N, 3) a job uses (mm or None = inferred) and where they came from."""
    infer = "inferred (relative to each point's horizontal range)"
    if spec is None:
        if data.sigma_scene is not None:
            return data.sigma_scene, "per point and axis, from the file's sigma_x/y/z columns"
        return None, infer
    if spec.kind == "infer":
        return None, infer
    if spec.kind == "percent":
        rho = np.hypot(data.approx_points[:, 0], data.approx_points[:, 1])
        frac = spec.values[0] / 100.0
        return np.repeat((frac * rho)[:, None], 3, axis=1), f"{spec.text} of each point's range"
    vals = np.array(spec.values, float)
    return np.broadcast_to(vals, (data.n_points, 3)).copy(), f"{spec.text} mm"


def warn_duplicates(data):
    """Warn about exact duplicate rows of the laser data, naming their lines.

    Returns
    -------
    list of int
        The lines (rows) named.
    """
    from ..io.data import duplicate_rows

    groups = duplicate_rows(data)
    if groups:
        unit = "lines" if data.pixel_table.kind == "csv" else "rows"
        text = "; ".join(" and ".join(map(str, g)) for g in groups[:10])
        more = f" (and {len(groups) - 10} more groups)" if len(groups) > 10 else ""
        warnings.warn(f"{data.pixel_table.path}: exact duplicate {unit} {text}{more}: each copy "
                      "counts as a separate measurement and shrinks the sds; remove the copies "
                      "unless they are real repeated measurements", UserWarning, stacklevel=2)
    return [v for g in groups for v in g]




def _unit(data):
    return "lines" if data.pixel_table.kind == "csv" else "rows"


def rows_to_lines(data, rows):
    """File line numbers (CSV, header = 1) or NPZ indices of 0-based data rows, as ints."""
    lines = data.pixel_table.lines
    return [int(lines[int(r)]) for r in np.ravel(rows) if 0 <= int(r) < len(lines)]


def runs_lines_text(data, rows):
    """``"FILE lines 12-30, 32"``: the input lines of 0-based ``rows``, consecutive ones as
    ranges."""
    lines = sorted(set(rows_to_lines(data, rows)))
    parts, start = [], None
    for i, v in enumerate(lines):
        start = v if start is None else start
        if i + 1 == len(lines) or lines[i + 1] != v + 1:
            parts.append(f"{start}-{v}" if v > start else f"{v}")
            start = None
    return f"{data.pixel_table.path} {_unit(data)} {', '.join(parts)}"


def _lines_text(lines, limit=20):
    more = f" and {len(lines) - limit} more" if len(lines) > limit else ""
    return ", ".join(map(str, lines[:limit])) + more


def noise_collapse_message(exc, data):
    """A :class:`~bayescal.checks.fit.NoiseCollapseError` as one line naming file lines."""
    lines = rows_to_lines(data, getattr(exc, "rows", ()))
    where = f"{data.pixel_table.path} {_unit(data)} {_lines_text(lines)}"
    msg = " ".join(str(exc).split())
    new = re.sub(r"Rows driving it most \(0-based\): [^.]*\.\s*Check those rows",
                 f"The input driving it most: {where}. Check those {_unit(data)}", msg)
    if new == msg and lines:
        new = f"{msg} (input driving it most: {where})"
    return f"{data.pixel_table.path}: {new}"


def _duplicate_rows_of(message):
    rows = getattr(message, "rows", None)
    if rows is not None:
        return np.ravel(np.asarray(rows, dtype=int))
    text = str(message)
    text = text.split("(0-based)", 1)[-1].split(";", 1)[0] if "(0-based)" in text else ""
    return np.array([int(t) for t in re.findall(r"\d+", text)], dtype=int)


@contextlib.contextmanager
def library_messages(data, *, reported=()):
    """Show the library's input messages about ``data`` with file line numbers.

    Inside the block, a :class:`~bayescal.checks.inputs.DuplicateRowsWarning` is
    re-worded with the file's line numbers (and dropped when ``reported``
    already names all its lines), and a
    :class:`~bayescal.checks.fit.NoiseCollapseError` becomes a one-line
    :class:`~bayescal.errors.UsageError` naming the lines that drive it.

    Parameters
    ----------
    data : LaserData
    reported : iterable of int
        Lines already named by :func:`warn_duplicates`.
    """
    from .fit import NoiseCollapseError, OffPlanWarning, off_plan_text
    from .inputs import DuplicateRowsWarning

    show, seen = warnings.showwarning, {int(v) for v in reported}

    def translate(message, category, *args, **kw):
        if isinstance(category, type) and issubclass(category, OffPlanWarning):
            message = off_plan_text(getattr(message, "runs", ()),
                                    where=lambda rows: runs_lines_text(data, rows)) or message
        if isinstance(category, type) and issubclass(category, DuplicateRowsWarning):
            lines = rows_to_lines(data, _duplicate_rows_of(message))
            if lines and set(lines) <= seen:
                return None
            message = (f"{data.pixel_table.path}: exact duplicate {_unit(data)} "
                       f"{_lines_text(lines)}: each copy counts as a separate measurement "
                       "and shrinks the sds") if lines else message
        return show(message, category, *args, **kw)

    warnings.showwarning = translate
    try:
        yield
    except NoiseCollapseError as exc:
        raise UsageError(noise_collapse_message(exc, data)) from None
    finally:
        warnings.showwarning = show


def flagged_lines(data, outlier_prob, *, threshold=OUTLIER_FLAG):
    """File lines (CSV, header = 1) or NPZ rows of the points with ``outlier_prob > threshold``.

    Parameters
    ----------
    data : LaserData
    outlier_prob : array_like, shape (N,) or None

    Returns
    -------
    list of int
        Empty when nothing is flagged or ``outlier_prob`` is None.
    """
    if outlier_prob is None:
        return []
    p = np.asarray(outlier_prob, float)
    if p.shape != (data.n_points,):
        return []
    return rows_to_lines(data, np.flatnonzero(p > threshold))


def flagged_text(data, outlier_prob):
    """One sentence listing the flagged input lines, or None when none is flagged."""
    lines = flagged_lines(data, outlier_prob)
    if not lines:
        return None
    return (f"{len(lines)} of {data.n_points} points flagged as outliers (outlier_prob > "
            f"{OUTLIER_FLAG:g}): {data.pixel_table.path} {_unit(data)} {_lines_text(lines)}")


def located_summary(result, data):
    """``result.summary()`` with its outlier line naming file lines instead of 0-based rows.

    Parameters
    ----------
    result : CalibrationResult or Posterior
    data : LaserData or None

    Returns
    -------
    str
    """
    text = result.summary()
    prob = getattr(result, "outlier_prob", None)
    if data is None or prob is None or np.shape(prob) != (data.n_points,):
        return text
    lines = [ln for ln in text.splitlines() if not ln.startswith("outliers (probability")]
    lines.append(flagged_text(data, prob) or f"outliers (outlier_prob > {OUTLIER_FLAG:g}): "
                 f"none of the {data.n_points} points")
    for run in getattr(result, "extras", {}).get("off_plan_runs") or ():
        a0, a1 = run["azimuth_deg"]
        lines.append(f"a block off the floor plan, set aside: {len(run['rows'])} points "
                     f"({runs_lines_text(data, run['rows'])}), azimuths {a0:.0f} to {a1:.0f} "
                     f"deg, {abs(run['depth_mm']):.0f} mm "
                     f"{'in front of' if run['side'] == 'front' else 'behind'} wall {run['wall']}")
    return "\n".join(lines)
