"""Blocks of neighbouring laser points off their wall: furniture the plan does not know.

A shelf, a cupboard or a person in front of a wall puts a run of neighbouring laser points
in front of it. The per-point outlier mixture sets such points aside only when the fit
leaves them far off; a block is many points, and the least squares may instead move the
wall onto the block and flag the true wall's points beside it, which then lie *behind*
their wall, or bend the sensor and an inferred noise until nothing looks off
(``docs/floorplan.md`` section 15). A laser point cannot lie behind the wall it is on (an
opening the plan does not show aside): :func:`resolve_runs` looks for runs of points behind
their wall, moves that wall back to them, fits again from there (the high-breakdown start,
then the EM) and keeps that solution when it passes the plan's checks, sets a run in front
of the moved wall aside and leaves no run of flagged points behind any wall.
:func:`find_runs` lists the runs of a solution for its result and warning (:func:`note_runs`).
Kept apart from :mod:`bayescal.fit.floorplan` for size.
"""

from __future__ import annotations

import copy
import warnings

import numpy as np

from ..checks.fit import OffPlanWarning, off_plan_text, robust_noise_ratio
from ..results.floorplan import CHECK_P
from ..scene.floorplan import wrap_angle
from ..sensor.laser import triangulate_geo
from .plan_robust import robust_solution

__all__ = ["PlanRuns", "RUN_MIN", "RUN_GAP", "RUN_Z", "depth_offsets", "find_runs", "resolve_runs",
           "note_runs"]

#: at least this many neighbouring flagged points on one side of their wall make a run
#: (fewer are the per-point mixture's business: gross extraction errors, glints)
RUN_MIN = 5
#: unflagged points a run may skip (a noisy point of the block that happens to fit)
RUN_GAP = 1
#: a run of n points not all flagged must have whitened residual norms (at a robust scale of
#: all residuals) summing to at least this times sqrt(n). Measured (docs/floorplan.md,
#: "Furniture"): at most 6.1 on the rooms without furniture, 7.6-9.1 where a simulated fit
#: bent to a block without flagging anything, 11-44 behind the rendered shelves
RUN_Z = 7.0


class PlanRuns:
    """The floor-plan solver's search for blocks off the plan; built by
    :mod:`bayescal.fit.floorplan` with its ``restore`` and ``sensor`` steps and ``retry``,
    its :class:`~bayescal.fit.plan_robust.PlanRetry`."""

    def __init__(self, **steps):
        self.__dict__.update(steps)

    def resolve(self, lik, prior, best, max_iter):
        """:func:`resolve_runs`."""
        return resolve_runs(self, lik, prior, best, max_iter)


def depth_offsets(lik, sol):
    """How far each point lies in front of its wall, and its azimuth: two (N,) arrays.

    The pixel triangulated on the laser cone with the solution's sensor: its distance in
    front of the solution's wall ``x cos a_k + y sin a_k = d_k`` (mm; negative behind it)
    and its azimuth ``atan2(y, x)`` (rad, the plan's frame); NaN where the ray misses the
    cone. (An outlier's fitted azimuth ``sol.t`` is not where its pixel points.)
    """
    nt = lik.n_geo
    pts, valid = triangulate_geo(sol.g[:nt], lik.pixels)
    d, a = sol.g[nt + 1:].reshape(-1, 2)[sol.wall_index].T
    with np.errstate(invalid="ignore"):
        off = d - pts[:, 0] * np.cos(a) - pts[:, 1] * np.sin(a)
    az = np.arctan2(pts[:, 1], pts[:, 0])
    return np.where(valid, off, np.nan), np.where(valid, az, np.nan)


def find_runs(lik, sol, *, flagged=True, min_points=RUN_MIN, gap=RUN_GAP):
    """Runs of neighbouring points on one side of their wall.

    On each wall, its points in the order of their azimuths (:func:`depth_offsets`); a run
    is a stretch of points all in front of the wall (or all behind it), with at most ``gap``
    other points between two of them, and at least ``min_points`` of them; with ``flagged``
    (the runs a result reports), points flagged as outliers (probability > 0.5); without
    (the runs :func:`resolve_runs` starts from), any points whose whitened residual norms
    ``|z_i|`` sum to at least :data:`RUN_Z` ``sqrt(n)`` (a block the fit has bent to: its
    points need not be flagged).

    Returns
    -------
    list of dict
        ``wall`` (int), ``side`` (``"front"`` or ``"behind"``), ``rows`` (int array, the
        run's points, 0-based), ``azimuth_deg`` (first, last: the points' azimuths
        in the plan's frame, deg, in increasing order round the ring), ``depth_mm`` (median
        distance in front of the wall, negative behind).
    """
    if getattr(sol, "em", None) is None:
        return []
    off, az = depth_offsets(lik, sol)
    ok = np.isfinite(off)
    pick = ok & (sol.em[1] > 0.5) if flagged else ok
    m = np.sum(sol.ne["R0"] ** 2, axis=1)
    z = np.sqrt(m) / robust_noise_ratio(m, 1)       # at a robust scale: a bent fit's noise
    walls, runs = sol.g[lik.n_geo + 1:].reshape(-1, 2), []
    for k in np.unique(sol.wall_index):
        idx = np.flatnonzero((sol.wall_index == k) & ok)
        idx = idx[np.argsort(wrap_angle(az[idx] - walls[k, 1]))]
        for side, sign in (("front", 1.0), ("behind", -1.0)):
            hit = np.flatnonzero(pick[idx] & (sign * off[idx] > 0))
            for part in np.split(hit, np.flatnonzero(np.diff(hit) > gap + 1) + 1):
                rows = idx[part]
                if part.size < min_points or (
                        not flagged and np.sum(z[rows]) < RUN_Z * np.sqrt(part.size)):
                    continue
                runs.append({"wall": int(k), "side": side, "rows": rows,
                             "azimuth_deg": _span(az[rows]),
                             "depth_mm": float(np.median(off[rows]))})
    return runs


def _span(t):
    """(first, last) azimuth of a run's points (ordered round the ring), deg in (-180, 180]."""
    rel = wrap_angle(t - t[0])
    return (float(np.degrees(wrap_angle(t[0] + rel.min()))),
            float(np.degrees(wrap_angle(t[0] + rel.max()))))


def relax_wall_check(lik, sol, runs):
    """Drop from ``sol.check["outlier_walls"]`` the walls whose flagged points are set aside
    as runs in front of them, when the rest of the wall's points keeps it measured.

    The check fails a wall most of whose points are flagged (a wall drawn far from where it
    is); a block in front of it is not that when at least :data:`RUN_MIN` of the wall's
    points fit it and, the block's points left out, the rest passes the same rule.
    """
    chk = sol.check
    if not chk.get("outlier_walls"):
        return
    front = np.zeros(lik.n, bool)
    for run in runs:
        front[run["rows"]] |= run["side"] == "front"
    flagged = sol.em[1] > 0.5
    keep = []
    for k, n_out, n_on in chk["outlier_walls"]:
        on = sol.wall_index == k
        n_front = int(np.count_nonzero(on & front))
        rest_out, rest_on = n_out - n_front, n_on - n_front
        inliers = int(np.count_nonzero(on & ~flagged))
        if n_front == 0 or inliers < RUN_MIN or (rest_out >= 3 and rest_out > 0.5 * rest_on):
            keep.append((k, n_out, n_on))
    chk["outlier_walls"] = keep
    chk["ok"] = chk["walls_ok"] and chk["p_pixels"] > CHECK_P and not keep


def _moved_back(lik, sol, behind):
    """A copy of ``sol`` with each wall that has runs ``behind`` it moved back to those
    points (the median of their depths behind it); the walls moved."""
    g, o = sol.g.copy(), lik.n_geo + 1
    off = depth_offsets(lik, sol)[0]
    moved = sorted({r["wall"] for r in behind})
    for k in moved:
        rows = np.concatenate([r["rows"] for r in behind if r["wall"] == k])
        g[o + 2 * k] -= float(np.median(off[rows]))
    start = copy.copy(sol)
    start.g = g
    return start, moved


def resolve_runs(ops, lik, prior, best, max_iter, *, rounds=2):
    """``best``, or the solution with its walls moved back behind runs of points.

    When ``best`` leaves runs of points behind their wall (:func:`find_runs` without
    ``flagged``: the fit may have bent to a block without flagging either side), those
    walls are moved back to them (:func:`_moved_back`) and the fit restarts there from the
    high-breakdown start (:func:`~bayescal.fit.plan_robust.robust_solution`: trimmed steps at
    a robust noise scale, then the EM; a fit bent to the block may have inflated an inferred
    noise so much that nothing looks off); the restart is kept if it passes the
    plan's checks (:func:`relax_wall_check` applied), sets aside a run of flagged points in
    front of a wall it moved, and leaves no run of flagged points behind any wall. At most
    ``rounds`` such moves. Sets ``best.runs`` (:func:`find_runs` of the solution kept,
    flagged points) and ``best.moved`` (the walls moved back); leaves ``lik`` in that
    solution's state.
    """
    best.runs, best.moved = [], []
    if not lik.outliers:
        return best
    best.runs, moved_all = find_runs(lik, best), []
    relax_wall_check(lik, best, best.runs)
    for _ in range(rounds):
        behind = [r for r in find_runs(lik, best, flagged=False) if r["side"] == "behind"]
        if not behind:
            break
        start, moved = _moved_back(lik, best, behind)
        ops.restore(lik, best)
        lik.assign(ops.sensor(lik, start.g), start.g[lik.n_geo + 1:].reshape(-1, 2))
        start.assignment = (lik.corner.copy(), lik.wall_pair.copy(), lik.ref_sigma_px)
        try:                                    # the high-breakdown start, then the EM
            sol = robust_solution(ops.retry, lik, prior, start, max_iter)
        except ValueError:                      # a start outside the model's domain
            break
        sol.runs = find_runs(lik, sol)
        relax_wall_check(lik, sol, sol.runs)
        if not (sol.check["ok"] and not any(r["side"] == "behind" for r in sol.runs)
                and any(r["side"] == "front" and r["wall"] in moved for r in sol.runs)):
            break
        best, moved_all = sol, moved_all + moved
    ops.restore(lik, best)
    best.moved = moved_all
    return best


def note_runs(result, sol):
    """Put the runs of ``sol`` into ``result.extras`` (``off_plan_runs``: :func:`find_runs`,
    ``walls_moved_back``) and warn (:class:`~bayescal.checks.fit.OffPlanWarning`) if any and
    the result converged (a failed one says why: e.g. a wall all of whose points are flagged)."""
    runs = getattr(sol, "runs", [])
    result.extras["off_plan_runs"] = runs
    result.extras["walls_moved_back"] = list(getattr(sol, "moved", []))
    if runs and result.converged:
        warnings.warn(OffPlanWarning(off_plan_text(runs), runs), stacklevel=3)
