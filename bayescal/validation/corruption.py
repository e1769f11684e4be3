"""Seeded corruptions of laser data, and the robustness invariant they are judged by.

A user's file carries mistakes: a spurious laser pixel, a reflection streak, a unit slip
in one approximate point, two rows swapped, a block pasted twice, a wall drawn in the
wrong place. :func:`corrupt` makes each kind from a clean :class:`~bayescal.Dataset`
(seeded, so a failing case can be replayed) and says which rows it touched;
:func:`judge` checks what the package did with it against the invariant of
``docs/robustness.md``:

* **handled**: the fit converged, the uncorrupted points' mean 3D error is at most
  ``ERROR_RATIO`` times the clean fit's, at least ``MIN_FLAGGED`` of the corrupted rows
  and at most ``MAX_FALSE_FLAGGED_ROWS`` (or ``MAX_FALSE_FLAGGED`` of them, if more) of the
  good ones are flagged (outlier probability > 0.5, or named by a warning);
* **refused**: a bayescal error (a failed fit, a not-converged result, bad input) that
  names rows, when more than ``MAX_REFUSABLE`` (5 %) of the rows are corrupted or the
  corruption is in the floor plan (with fewer bad rows a refusal is a failure);
* anything else fails: a converged result that misses the corruption, a parameter on a
  bound called converged, a result whose own model check fails (a
  :class:`~bayescal.checks.fit.ModelMisfitWarning`: the command line exits 1 on it) with
  few rows corrupted, or an exception that is not bayescal's own.
"""

from __future__ import annotations

import dataclasses
import warnings

import numpy as np

from .._validation import resolve_rng
from ..checks.inputs import DuplicateRowsWarning
from ..checks.misfit import ModelMisfitWarning
from ..errors import BayescalError, FitError, InputError, InvalidValueError, NotConvergedError
from ..fit.simultaneous import calibrate_simultaneous
from ..mcmc.sampling import sample_posterior
from ..scene.floorplan import FloorPlan

__all__ = ["KINDS", "PIXEL_KINDS", "POINT_KINDS", "MIXED_KINDS", "PLAN_KINDS",
           "PLAN_MIXED_KINDS", "Corruption",
           "corrupt", "judge", "run_case", "ERROR_RATIO",
           "MIN_FLAGGED", "MAX_FALSE_FLAGGED", "MAX_FALSE_FLAGGED_ROWS", "MAX_REFUSABLE",
           "fit_corrupted"]

#: corruptions of the laser pixels (they apply to floor-plan fits too)
PIXEL_KINDS = ("gross_pixel", "streak", "random_gross", "ghost_ring")
#: corruptions of the approximate points (correspondences, typing and unit slips)
POINT_KINDS = ("metres", "centimetres", "sign_flip", "z_sign_flip", "times_ten", "xy_swap",
               "rows_swapped", "far_swap", "block_mispaired")
#: combinations: the messy file of docs/robustness.md (a typo, a swap, a spurious pixel and
#: a z sign flip), and 5 % of the rows corrupted by kinds drawn at random
MIXED_KINDS = ("mixed", "mixed_5pct")
#: corruptions of laser data (pixels or approximate points)
KINDS = PIXEL_KINDS + POINT_KINDS + ("duplicated_block",) + MIXED_KINDS
#: 5 % of a floor-plan file's rows (pixels only) corrupted: a reflection streak, a ghost
#: arc and spurious pixels, a third of the budget each
PLAN_MIXED_KINDS = ("pixels_5pct",)
#: corruptions of a floor plan
PLAN_KINDS = ("wall_off",)
#: the invariant (module docstring)
ERROR_RATIO = 1.25
MIN_FLAGGED = 0.9
MAX_FALSE_FLAGGED = 0.01
#: ... or this many good rows, whichever is more (3 of 300: 1 % of the good rows of a file
#: with 5 % of its rows corrupted would be 2.85)
MAX_FALSE_FLAGGED_ROWS = 3
#: with at most this fraction of the rows corrupted a refusal is a failure: the fit must
#: handle them (a wall drawn off corrupts no row and may still be refused)
MAX_REFUSABLE = 0.05


@dataclasses.dataclass
class Corruption:
    """Corrupted data and where the corruption is.

    Attributes
    ----------
    kind : str
    pixels : ndarray, shape (M, 2)
        px (``M = N`` except for ``duplicated_block``, which appends rows).
    approx_points : ndarray, shape (M, 3)
        mm.
    rows : ndarray of int
        The corrupted rows (0-based, of the corrupted arrays).
    plan : FloorPlan or None
        The corrupted plan (``wall_off``).
    """

    kind: str
    pixels: np.ndarray
    approx_points: np.ndarray
    rows: np.ndarray
    plan: object = None


def _radial(pixels, center):
    d = pixels - center
    return d / np.linalg.norm(d, axis=-1, keepdims=True)


def _pixel_kinds(kind, ds, pix, rng, count, exclude=(), run=15):
    c = np.array([ds.params.u0, ds.params.v0])
    free = np.setdiff1d(np.arange(len(pix)), exclude)
    if kind == "gross_pixel":                 # a spurious detection 25 px away
        rows = np.sort(rng.choice(free, size=count, replace=False))
        ang = rng.uniform(0, 2 * np.pi, count)
        pix[rows] += 25.0 * np.stack([np.cos(ang), np.sin(ang)], -1)
    elif kind in ("streak", "ghost_ring"):    # consecutive in azimuth
        az = np.argsort(np.arctan2(pix[:, 1] - c[1], pix[:, 0] - c[0]))
        start = int(rng.integers(len(pix)))
        rows = np.sort(az[(start + np.arange(max(count, 1) * run)) % len(pix)])
        if kind == "streak":                  # a reflection: 3 px outward
            pix[rows] += 3.0 * _radial(pix[rows], c)
        else:                                 # a ghost ring: 6 % of the radius inward
            pix[rows] = c + 0.94 * (pix[rows] - c)
    else:                                     # random_gross: 5 % of the pixels, 5-30 px
        rows = np.sort(rng.choice(free, size=max(1, int(round(0.05 * len(pix)))),
                                  replace=False))
        ang = rng.uniform(0, 2 * np.pi, len(rows))
        pix[rows] += rng.uniform(5, 30, len(rows))[:, None] * np.stack(
            [np.cos(ang), np.sin(ang)], -1)
    return rows


def _swap(apx, rows, rng, far=False):
    """Swap the points of pairs of rows at least 0.3 median ranges apart (``far``: one of
    each pair comes from another room, 3 m further out)."""
    count = len(rows) // 2
    rng_mm = float(np.median(np.hypot(apx[:, 0], apx[:, 1])))
    a, b = rows[:count], rows[count:]
    keep = np.hypot(*(apx[a, :2] - apx[b, :2]).T) > 0.3 * rng_mm
    a, b = a[keep], b[keep]
    if far:
        rho = np.hypot(apx[a, 0], apx[a, 1])
        apx[a, :2] *= (1.0 + 3000.0 / rho)[:, None]
    apx[np.r_[a, b]] = apx[np.r_[b, a]]
    return np.sort(np.r_[a, b])


def _point_kinds(kind, ds, apx, rng, count, exclude=()):
    rng_mm = float(np.median(np.hypot(apx[:, 0], apx[:, 1])))
    n = len(apx)
    free = np.setdiff1d(np.arange(n), exclude)
    if kind in ("rows_swapped", "far_swap"):
        return _swap(apx, rng.choice(free, size=2 * count, replace=False), rng,
                     far=kind == "far_swap")
    if kind == "block_mispaired":            # 10 rows paired with another block's points
        s = int(rng.integers(n))
        rows = (s + np.arange(10 * count)) % n
        src = (rows + n // 3) % n
        apx[rows] = apx[src].copy()
        return np.sort(rows)
    # a coordinate must move far: pick points with a large |x| (|x - y| for xy_swap)
    big = np.abs(apx[:, 0] - apx[:, 1]) if kind == "xy_swap" else np.abs(apx[:, 0])
    cand = np.intersect1d(np.flatnonzero(big > 0.4 * rng_mm), free)
    rows = np.sort(rng.choice(cand, size=count, replace=False))
    if kind == "metres":
        apx[rows] /= 1000.0
    elif kind == "centimetres":
        apx[rows] /= 10.0
    elif kind == "sign_flip":
        apx[rows, 0] *= -1.0
    elif kind == "z_sign_flip":
        apx[rows, 2] *= -1.0
    elif kind == "times_ten":
        apx[rows, 0] *= 10.0
    else:
        apx[rows, :2] = apx[rows, ::-1][:, 1:]
    return rows


#: the kinds a 5 % mix draws from (one row each, or one pair of rows for a swap)
_MIX_POOL = ("gross_pixel", "metres", "centimetres", "sign_flip", "z_sign_flip", "times_ten",
             "xy_swap", "rows_swapped", "far_swap")


def _mixed(kind, ds, pix, apx, rng):
    """Several kinds in one file, on distinct rows."""
    if kind == "mixed":
        parts = ("times_ten", "rows_swapped", "gross_pixel", "z_sign_flip")
    else:
        budget, parts = int(0.05 * len(pix)), []
        while budget > 0:
            parts.append(str(rng.choice(_MIX_POOL if budget > 1 else PIXEL_KINDS[:1])))
            budget -= 2 if parts[-1] in ("rows_swapped", "far_swap") else 1
    rows = np.array([], int)
    for part in parts:
        if part in PIXEL_KINDS:
            new = _pixel_kinds(part, ds, pix, rng, 1, exclude=rows)
        else:
            new = _point_kinds(part, ds, apx, rng, 1, exclude=rows)
        rows = np.union1d(rows, new)
    return rows


def _pixel_mix(ds, pix, rng):
    """5 % of the rows: a streak and a ghost arc of a third each, the rest spurious pixels
    5-30 px away (on distinct rows)."""
    n_bad = max(3, int(0.05 * len(pix)))
    run = n_bad // 3
    rows = np.array([], int)
    for kind in ("streak", "ghost_ring"):
        for _ in range(20):                 # an arc that misses the rows already used
            trial = pix.copy()
            new = _pixel_kinds(kind, ds, trial, rng, 1, run=run)
            if not np.intersect1d(new, rows).size:
                break
        pix[:] = trial
        rows = np.union1d(rows, new)
    free = np.setdiff1d(np.arange(len(pix)), rows)
    gross = np.sort(rng.choice(free, size=n_bad - len(rows), replace=False))
    ang = rng.uniform(0, 2 * np.pi, len(gross))
    pix[gross] += rng.uniform(5, 30, len(gross))[:, None] * np.stack(
        [np.cos(ang), np.sin(ang)], -1)
    return np.union1d(rows, gross)


def _shift_wall(walls, k, factor):
    """Walls (W, 2, 2) of a closed polygon with wall ``k`` moved to ``factor`` times its
    distance from the axis; its two corners follow (intersections with the neighbours)."""
    def line(seg):
        d = seg[1] - seg[0]
        n = np.array([d[1], -d[0]]) / np.linalg.norm(d)
        return n, float(n @ seg[0])

    W = len(walls)
    n_k, d_k = line(walls[k])
    d_k *= factor
    for j, end in (((k - 1) % W, 0), ((k + 1) % W, 1)):
        n_j, d_j = line(walls[j])
        corner = np.linalg.solve(np.array([n_k, n_j]), np.array([d_k, d_j]))
        walls[k, end] = corner
        walls[j, 1 - end] = corner
    return walls


def corrupt(ds, kind, *, count=1, rng=None):
    """A corrupted copy of a simulated room's laser data (or of its floor plan).

    Parameters
    ----------
    ds : Dataset
        From :func:`~bayescal.simulate_room`.
    kind : str
        One of :data:`KINDS`, :data:`PLAN_MIXED_KINDS` or :data:`PLAN_KINDS`.
    count : int, optional
        How many (rows, streaks or ghost-ring arcs of 15 pixels, swapped pairs, blocks of
        10 rows mis-paired or duplicated); ``random_gross`` always corrupts 5 % of the
        pixels, ``mixed`` five rows (a typo, a swapped pair, a spurious pixel, a z sign
        flip) and ``mixed_5pct`` 5 % of the rows, kinds drawn at random; ``pixels_5pct``
        5 % of the rows' pixels (a streak, a ghost arc, spurious pixels).
    rng : numpy.random.Generator, int or None

    Returns
    -------
    Corruption

    Raises
    ------
    ValueError
        An unknown ``kind``, or ``wall_off`` on a room without a floor plan.
    """
    rng = resolve_rng(rng)
    pix, apx = ds.pixels.copy(), ds.approx_points.copy()
    if kind in PIXEL_KINDS:
        rows = _pixel_kinds(kind, ds, pix, rng, count)
    elif kind in POINT_KINDS:
        rows = _point_kinds(kind, ds, apx, rng, count)
    elif kind in MIXED_KINDS:
        rows = _mixed(kind, ds, pix, apx, rng)
    elif kind in PLAN_MIXED_KINDS:
        rows = _pixel_mix(ds, pix, rng)
    elif kind == "duplicated_block":
        start = int(rng.integers(len(pix) - 10 * count))
        block = np.arange(start, start + 10 * count)
        rows = len(pix) + np.arange(len(block))
        pix, apx = np.concatenate([pix, pix[block]]), np.concatenate([apx, apx[block]])
    elif kind == "wall_off":
        if ds.floor_plan is None:
            raise InvalidValueError("kind='wall_off' needs a room with a floor plan")
        plan = ds.floor_plan
        walls = _shift_wall(np.array(plan.walls, float), int(rng.integers(plan.n_walls)), 1.3)
        bad = FloorPlan(walls, distance_sd=plan.distance_sd, angle_sd=plan.angle_sd)
        return Corruption(kind, pix, apx, np.array([], int), bad)
    else:
        raise InvalidValueError(f"kind must be one of {KINDS + PLAN_MIXED_KINDS + PLAN_KINDS}, "
                                f"got {kind!r}")
    return Corruption(kind, pix, apx, np.asarray(rows, int))


def _good_error(points, truth, good):
    return float(np.mean(np.linalg.norm(points[good] - truth[good], axis=1)))


def judge(outcome, corruption, truth_points, clean_error, *, warned_rows=()):
    """Check what a fit did with corrupted data against the invariant.

    Parameters
    ----------
    outcome : result or Exception
        What the fit returned (a CalibrationResult or Posterior) or raised.
    corruption : Corruption
    truth_points : ndarray, shape (N, 3)
        The true points of the clean rows (mm; duplicated rows are not judged).
    clean_error : float
        The clean fit's mean 3D error, mm.
    warned_rows : array_like of int, optional
        Rows a warning named (duplicate rows): they count as flagged.

    Returns
    -------
    dict
        ``verdict`` (``"handled"``, ``"refused"`` or ``"FAILED"``), ``why`` (str),
        ``error_ratio``, ``flagged`` (fraction of corrupted rows flagged),
        ``false_flagged`` (fraction of good rows flagged).
    """
    out = {"verdict": "FAILED", "why": "", "error_ratio": np.nan, "flagged": np.nan,
           "false_flagged": np.nan}
    n_bad = len(corruption.rows)
    refusable = n_bad == 0 or n_bad > MAX_REFUSABLE * len(truth_points)
    out = _judge_outcome(outcome, corruption, truth_points, clean_error, warned_rows, out)
    if out["verdict"] == "refused" and not refusable:
        out.update(verdict="FAILED", why=f"refused with {n_bad} of {len(truth_points)} rows "
                   f"corrupted (<= {MAX_REFUSABLE:.0%}): {out['why']}"[:200])
    return out


def _judge_outcome(outcome, corruption, truth_points, clean_error, warned_rows, out):
    if isinstance(outcome, BaseException):
        ours = isinstance(outcome, BayescalError)
        named = any(w in str(outcome) for w in ("row", "line", "wall"))
        if isinstance(outcome, (NotConvergedError, InputError)) or (ours and named):
            out.update(verdict="refused", why=f"{type(outcome).__name__}: {outcome}"[:200])
        else:
            what = "raised" if ours else "raised, not bayescal's own"
            out["why"] = f"{type(outcome).__name__} {what}: {outcome}"[:200]
        return out
    n = len(truth_points)
    good = np.setdiff1d(np.arange(n), corruption.rows)
    if not getattr(outcome, "converged", True):
        msg = str(getattr(outcome, "message", ""))
        named = any(w in msg for w in ("row", "line", "wall"))
        out.update(verdict="refused" if named else "FAILED", why=msg[:200])
        return out
    op = getattr(outcome, "outlier_prob", None)
    flags = np.zeros(len(corruption.pixels), bool) if op is None else np.asarray(op) > 0.5
    flags[np.asarray(warned_rows, int)] = True
    bad = corruption.rows[corruption.rows < len(flags)]
    out["flagged"] = float(np.mean(flags[bad])) if len(bad) else 1.0
    out["false_flagged"] = float(np.mean(flags[good]))
    out["error_ratio"] = _good_error(np.asarray(outcome.points)[:n], truth_points, good) \
        / clean_error
    n_false = int(np.sum(flags[good]))
    ok = (out["error_ratio"] <= ERROR_RATIO and out["flagged"] >= MIN_FLAGGED
          and n_false <= max(MAX_FALSE_FLAGGED_ROWS, MAX_FALSE_FLAGGED * len(good)))
    out["verdict"] = "handled" if ok else "FAILED"
    out["why"] = (f"error x{out['error_ratio']:.2f}, {out['flagged']:.0%} of corrupted and "
                  f"{out['false_flagged']:.1%} of good rows flagged")
    return out


def run_case(ds, kind, *, method="lsq", noise="inferred", plan=None, count=1, seed=7,
             clean=None, **fit_kw):
    """Corrupt ``ds``, fit it, and judge the outcome; returns :func:`judge`'s dict plus
    ``kind``, ``method`` and ``noise``.

    Parameters
    ----------
    ds : Dataset
    kind : str or Corruption
        One of :data:`KINDS` or :data:`PLAN_KINDS`; or a corruption made elsewhere (e.g.
        by a second harness), its ``kind`` the name reported.
    method : {"lsq", "posterior", "plan", "plan_posterior"}
        :func:`~bayescal.calibrate_simultaneous` on the approximate points, or
        :func:`~bayescal.sample_posterior` on them, or the least squares or the posterior
        on ``plan``.
    noise : {"given", "inferred"}
        The pixel (and scene) noise given as simulated, or inferred.
    plan : FloorPlan, optional
        For ``method="plan"`` (default ``ds.floor_plan``).
    count : int, optional
    seed : int, optional
        Seed of the corruption (and of the posterior's sampler).
    clean : float, optional
        The clean fit's mean 3D error (mm); computed when not given.
    **fit_kw
        Passed to the fit (e.g. ``min_ess``, ``progress`` for the posterior).

    Returns
    -------
    dict
        :func:`judge`'s, and ``robust_start`` (whether the result came from the robust
        start; None without a result) and ``seconds`` (CPU seconds of the corrupted fit).
    """
    plan = ds.floor_plan if plan is None else plan
    if method in ("posterior", "plan_posterior"):
        fit_kw.setdefault("rng", seed)
    c = kind if isinstance(kind, Corruption) else corrupt(ds, kind, count=count, rng=seed)
    if clean is None:
        res = fit_corrupted(ds, Corruption("clean", ds.pixels, ds.approx_points,
                                           np.array([], int)), method=method, noise=noise,
                            plan=plan, **fit_kw)[0]
        if isinstance(res, Exception):            # no clean fit to judge against
            return {"kind": c.kind, "method": method, "noise": noise, "robust_start": None,
                    "seconds": None, "verdict": "FAILED", "error_ratio": np.nan,
                    "flagged": np.nan, "false_flagged": np.nan,
                    "why": f"the clean fit: {type(res).__name__}: {res}"[:200]}
        clean = float(np.mean(np.linalg.norm(res.points - ds.points, axis=1)))
    out, warned, misfit, seconds = fit_corrupted(ds, c, method=method, noise=noise, plan=plan,
                                                 **fit_kw)
    verdict = judge(out, c, ds.points, clean, warned_rows=warned)
    if misfit and verdict["verdict"] == "handled":
        # the command line exits 1 on a failed model check: a refusal, not a success
        verdict = judge(FitError(misfit), c, ds.points, clean)
    robust = getattr(out, "extras", {}).get("robust_start")
    return {"kind": c.kind, "method": method, "noise": noise, "robust_start": robust,
            "seconds": seconds, **verdict}


def fit_corrupted(ds, c, *, method="lsq", noise="inferred", plan=None, **fit_kw):
    """Fit corrupted data ``c`` (:class:`Corruption`) of the room ``ds`` as
    :func:`run_case` does.

    Returns
    -------
    outcome : result or Exception
        What the fit returned or raised.
    warned : ndarray of int
        The corrupted rows when a duplicate-rows warning was issued, else empty.
    misfit : str or None
        The text of a :class:`~bayescal.checks.fit.ModelMisfitWarning`.
    seconds : float
        CPU seconds of the fit.
    """
    import time

    spx = ds.sigma_px if noise == "given" else None
    scene = ds.sigma_scene if noise == "given" else None
    if scene is not None and len(c.pixels) > len(scene):         # duplicated rows
        scene = np.concatenate([scene, scene[:len(c.pixels) - len(scene)]])
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        t0 = time.process_time()
        try:
            if method == "plan":
                out = calibrate_simultaneous(c.pixels, c.plan or plan, sigma_px=spx, **fit_kw)
            elif method == "plan_posterior":
                out = sample_posterior(c.pixels, c.plan or plan, sigma_px=spx, **fit_kw)
            else:
                f = sample_posterior if method == "posterior" else calibrate_simultaneous
                out = f(c.pixels, c.approx_points, sigma_px=spx, sigma_scene=scene, **fit_kw)
        except Exception as exc:  # noqa: BLE001 (judged: a bayescal error or a failure)
            out = exc
        seconds = time.process_time() - t0
    warned = c.rows if any(issubclass(w.category, DuplicateRowsWarning) for w in caught) \
        else np.array([], int)
    misfit = next((str(w.message) for w in caught
                   if issubclass(w.category, ModelMisfitWarning)), None)
    return out, warned, misfit, seconds
