"""Floor-plan files: the walls CSV of ``bayescal calibrate --walls`` and its run record.

The walls CSV has a header line and one wall per line (``#`` comments and blank
lines skipped, still counted in line numbers; the header is line 1):

``x0, y0, x1, y1``
    end points of the wall in mm, frame C, walls in counterclockwise order
    around the sensor axis, each ending where the next one starts (required);
``distance_sd``
    sd of the wall's perpendicular distance from the axis, mm (optional);
``angle_sd``
    sd of the wall's orientation, rad (optional).

Without the sd columns the options ``--distance-sd`` (mm, or a percentage of
each wall's distance like ``5%``) and ``--angle-sd`` (rad) apply. Every problem
raises :class:`~bayescal.errors.InputError` naming the file, the line, the
column and the value, and what was expected; a plan that is not closed or does
not surround the sensor names the wall and its line (``docs/cli.md``).
"""

from __future__ import annotations

import pathlib

import numpy as np

from ..errors import InputError, InvalidValueError
from ..scene.floorplan import FloorPlan
from .tables import read_table

__all__ = ["WALL_COLUMNS", "WALL_SD_COLUMNS", "DEFAULT_DISTANCE_SD", "DEFAULT_ANGLE_SD",
           "load_walls", "write_walls_csv", "plan_record", "plan_from_record"]

WALL_COLUMNS = ("x0", "y0", "x1", "y1")
WALL_SD_COLUMNS = ("distance_sd", "angle_sd")
#: default ``--distance-sd``: 5 % of each wall's distance from the axis
DEFAULT_DISTANCE_SD = "5%"
#: default ``--angle-sd`` in rad (about half a degree: a direction read off a drawing)
DEFAULT_ANGLE_SD = 0.01


def _sd_column(table, name, unit):
    col = table.columns.get(name)
    if col is None:
        return None
    bad = ~(np.isfinite(col) & (col > 0))
    if np.any(bad):
        k = int(np.argmax(bad))
        raise table.error(k, name, f"{col[k]:g} is not a valid standard deviation; expected a "
                          f"finite positive number of {unit}")
    return col


def _option_sd(spec, distances):
    """Per-wall distance sd (mm) from a ``--distance-sd`` value: mm or ``(percent, P)``."""
    if isinstance(spec, tuple):
        return spec[1] / 100.0 * np.abs(distances)
    return np.full(len(distances), float(spec))


def _located(exc, table):
    """The plan's ValueError with every "wall k" followed by its line in the file."""
    import re

    def line_of(m):
        k = int(m.group(1))
        return (f"wall {k} (line {int(table.lines[k])})" if 0 <= k < len(table)
                else m.group(0))

    return InputError(f"{table.path}: " + re.sub(r"wall (\d+)", line_of, str(exc)),
                      path=str(table.path))


def load_walls(path, *, distance_sd=DEFAULT_DISTANCE_SD, angle_sd=DEFAULT_ANGLE_SD):
    """Read a walls CSV into a :class:`~bayescal.FloorPlan`.

    Parameters
    ----------
    path : str or pathlib.Path
    distance_sd : float, str or tuple, optional
        Used when the file has no ``distance_sd`` column: mm, a percentage of
        each wall's distance (``"5%"`` or ``("percent", 5.0)``).
    angle_sd : float, optional
        Used when the file has no ``angle_sd`` column, rad.

    Returns
    -------
    plan : FloorPlan
    table : Table
        Where the numbers came from (line of each wall).

    Raises
    ------
    InputError
        A cell that is not a finite number, a non-positive sd, fewer than 3
        walls, a plan that is not closed or does not surround the sensor.
    """
    table = read_table(path, required=WALL_COLUMNS, optional=WALL_SD_COLUMNS)
    if len(table) < 3:
        raise InputError(f"{table.path}: {len(table)} wall(s); expected at least 3 walls "
                         "closing a polygon around the sensor", path=str(table.path))
    c = table.columns
    seg = np.stack([np.column_stack([c["x0"], c["y0"]]),
                    np.column_stack([c["x1"], c["y1"]])], axis=1)
    dsd = _sd_column(table, "distance_sd", "mm")
    asd = _sd_column(table, "angle_sd", "rad")
    if isinstance(distance_sd, str):
        distance_sd = (("percent", float(distance_sd.rstrip("%")))
                       if distance_sd.endswith("%") else float(distance_sd))
    try:
        probe = FloorPlan(seg, distance_sd=1.0, angle_sd=1.0)
        plan = FloorPlan(seg, distance_sd=dsd if dsd is not None
                         else _option_sd(distance_sd, probe.distances),
                         angle_sd=asd if asd is not None else float(angle_sd))
    except ValueError as exc:
        raise _located(exc, table) from None
    return plan, table


def write_walls_csv(path, plan, *, header_comment=None):
    """Write a plan as a walls CSV (segments and per-wall sds), readable by :func:`load_walls`.

    Returns
    -------
    pathlib.Path
    """
    from .data import _write_csv

    s = plan.segments
    _write_csv(path, {"x0": s[:, 0, 0], "y0": s[:, 0, 1], "x1": s[:, 1, 0], "y1": s[:, 1, 1],
                      "distance_sd": plan.distance_sd, "angle_sd": plan.angle_sd},
               header_comment)
    return pathlib.Path(path)


def plan_record(plan):
    """Plain-data record of a plan for ``run.json``: segments (mm) and sds (mm, rad)."""
    return {"segments": np.asarray(plan.segments, float).tolist(),
            "distance_sd": np.asarray(plan.distance_sd, float).tolist(),
            "angle_sd": np.asarray(plan.angle_sd, float).tolist()}


def plan_from_record(rec):
    """The :class:`~bayescal.FloorPlan` of a :func:`plan_record`, or None for None.

    Raises
    ------
    ValueError
        A damaged record.
    """
    if rec is None:
        return None
    try:
        return FloorPlan(np.asarray(rec["segments"], float), distance_sd=rec["distance_sd"],
                         angle_sd=rec["angle_sd"])
    except (KeyError, TypeError) as exc:
        raise InvalidValueError(f"the run's floor-plan record is damaged ({exc})") from None
