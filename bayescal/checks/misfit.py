"""Is a converged least-squares fit one its own model check accepts?

:func:`flag_misfit` marks a solution whose model check
(:func:`bayescal.checks.model.model_check`) fails at p < :data:`MISFIT_ALPHA` on a statistic
of the residuals' structure, which a wrong fit leaves and a right one with a slightly wrong
noise model does not; :func:`bayescal.calibrate_simultaneous` then warns
(:class:`ModelMisfitWarning`) and the command line exits 1 (``docs/robustness.md``, 4c).
"""

from __future__ import annotations

import numpy as np

from ..errors import BayescalWarning, InvalidValueError
from ..likelihood.scene_noise import scene_range
from .datafile import OUTLIER_FLAG
from .model import _residuals, _result_data

__all__ = ["ModelMisfitWarning", "flag_misfit", "misfit_p_values", "misfit_run_p",
           "MISFIT_ALPHA", "MISFIT_STATISTICS", "RUN_WIDTHS"]


class ModelMisfitWarning(BayescalWarning):
    """The least squares converged, but its own model check fails at p <
    :data:`MISFIT_ALPHA` (:func:`flag_misfit`): the result is not a plain success.
    ``result.extras["model_misfit"]`` names the statistics that failed,
    ``extras["model_check"]`` holds the p-values, ``extras["failed_rows"]`` the rows
    fitting worst; the command line exits 1, keeping the result."""


#: a result whose own model check fails below this p-value is not a success (a correct
#: model fails at most once in 10 000 fits on each statistic)
MISFIT_ALPHA = 1e-4
#: the statistics of the model check that refuse a result: the correlation of neighbouring
#: points' scene residuals and the second harmonic of the misfit around the ring, which a
#: fit that moved the whole scene leaves (the collapse to h = 2.3 mm: p = 7e-34 and 3e-4).
#: The sum of squares and the tail fraction are left to the report: with the noise given
#: they fail on sds a few per cent off, with it inferred on approximate points whose
#: errors are relative per coordinate (p = 3e-7 on clean rooms: docs/robustness.md, 4c)
#: ``misfit_run``: a run of neighbouring points holding much of the misfit (a streak of
#: pixels or a ghost arc a few sds off each, which bend the geometry to themselves and, with
#: the noise inferred, raise it until each row looks normal; docs/robustness.md, 4c).
MISFIT_STATISTICS = ("neighbour_corr", "misfit_run")
#: permutations of the ring-harmonic p-value when it is computed to MISFIT_ALPHA
_PERMUTATIONS = 20000
#: the run scan's widths (neighbouring points in azimuth): a streak or an arc of 15 rows
RUN_WIDTHS = (8, 16, 32)
#: the run scan's permutations: a first look, then more where its p-value is under 0.01
_RUN_FIRST, _RUN_MORE = 1000, 20000


def misfit_p_values(result):
    """Exact p-values of the least-squares model check's statistics (the check's 200
    replicates resolve no p-value below 0.005): ``{name: p}`` for ``chi2`` (upper tail,
    chi-square of the rows checked), ``tail`` (binomial count of ``|z| > 3``) and
    ``neighbour_corr`` (the lag-one correlation of the scene residuals in azimuth, normal
    with variance ``1 / pairs`` for independent residuals; normalised by their spread or
    the model's, whichever is larger), and the per-point misfit
    ``point_chi2`` (N,); an empty dict when the result carries no data to check.

    Parameters
    ----------
    result : CalibrationResult
        A simultaneous result on approximate points (flagged outliers are left out).
    """
    from scipy import stats

    pix, apx, info = _result_data(result, None, None)
    res = None if apx is None else _residuals(result, info, pix, apx)
    if res is None or not res[2]:
        return {}
    z = np.array(res[1][0], dtype=float)                          # (N, 3)
    op = result.outlier_prob
    if op is not None:
        z[np.asarray(op) > OUTLIER_FLAG] = np.nan
    used = np.isfinite(z)
    n = int(used.sum())
    if n < 20:
        return {}
    zz = np.where(used, z, 0.0)
    out = {"chi2": float(stats.chi2.sf(np.sum(zz * zz), n)),
           "tail": float(stats.binom.sf(np.sum(np.abs(zz) > 3) - 1, n, 2 * stats.norm.sf(3)))}
    pts = np.asarray(result.points, float)
    order = np.argsort(np.arctan2(pts[:, 1], pts[:, 0]))
    a, b = zz[order][:-1], zz[order][1:]
    ok = used[order][:-1] & used[order][1:]
    pairs = int(ok.sum())
    # the correlation in units of the noise: the residuals' own spread, but never less than
    # the model's (1), so that residuals far inside the noise (exact data) do not count
    den = max(float(np.sqrt(np.sum(a * a * ok) * np.sum(b * b * ok))), pairs, 1)
    corr = float(np.sum(a * b * ok) / den)
    out["neighbour_corr"] = float(stats.norm.sf(corr * np.sqrt(pairs)))
    out["observed"] = {"neighbour_corr": corr}
    out["point_chi2"] = np.sum(zz * zz, axis=1)
    m = np.where(used.all(axis=1), out["point_chi2"], np.nan)
    out["misfit_run"], rows = misfit_run_p(m[order], scene_range(apx)[order])
    out["run_rows"] = order[rows]
    return out


def _run_scan(m, widths):
    """The scan statistic of rows of misfit ``m`` (P, n) in ring order (closed): over the
    ``widths``, the largest sum over a run of neighbouring points, in sds of such a sum
    about its mean; and, for the first row, where that run starts and its width."""
    P, n = m.shape
    mu, sd = m.mean(axis=1), m.std(axis=1) + 1e-300
    cs = np.concatenate([np.zeros((P, 1)), np.cumsum(np.concatenate(
        [m, m[:, :max(widths)]], axis=1), axis=1)], axis=1)
    best, where = np.full(P, -np.inf), (0, widths[0])
    for w in widths:
        sums = cs[:, w:w + n] - cs[:, :n]
        t = (sums.max(axis=1) - w * mu) / (np.sqrt(w) * sd)
        if t[0] > best[0]:
            where = (int(np.argmax(sums[0])), w)
        best = np.maximum(best, t)
    return best, where


def misfit_run_p(misfit, rho, *, rng=0):
    """Is the misfit concentrated in a run of neighbouring points? A permutation p-value.

    Each point's misfit is divided by its expected value as a smooth function of its range
    (a quadratic in the standardised log range, fitted by least squares): a noise model
    whose scale is wrong by a factor that changes with range (relative errors inferred for
    isotropic ones) makes the near (or far) walls misfit more than the others, which is no
    run of bad rows. The statistic
    is the largest sum over :data:`RUN_WIDTHS` neighbouring points, in sds about its mean;
    its p-value is that of the same statistic over random orders of the same misfits
    (:data:`_RUN_FIRST` of them, then :data:`_RUN_MORE` more when p < 0.01; smallest
    p-value 1 / 21001). Exact for exchangeable misfits whatever their distribution.

    Parameters
    ----------
    misfit : ndarray, shape (N,)
        Per-point misfit in ring (azimuth) order; NaN for points left out.
    rho : ndarray, shape (N,)
        Each point's range, mm, same order.
    rng : int, optional
        Seed of the permutations (the p-value is reproducible).

    Returns
    -------
    p : float
        1.0 when fewer than 4 x 8 points are checked.
    rows : ndarray of int
        Indices (into ``misfit``) of the run of largest misfit.
    """
    m, rho = np.asarray(misfit, float), np.asarray(rho, float)
    if m.ndim != 1 or rho.shape != m.shape:
        raise InvalidValueError(f"misfit and rho must be two arrays of shape (N,), got "
                                f"{m.shape} and {rho.shape}")
    idx = np.flatnonzero(np.isfinite(m) & np.isfinite(rho) & (rho > 0))
    widths = tuple(w for w in RUN_WIDTHS if w <= len(idx) // 4)
    if not widths:
        return 1.0, np.zeros(0, int)
    x = np.log(rho[idx])
    x = (x - x.mean()) / (x.std() + 1e-12)
    A = np.stack([np.ones_like(x), x, x * x], axis=1)
    expected = A @ np.linalg.lstsq(A, m[idx], rcond=None)[0]
    v = m[idx] / np.maximum(expected, 0.1 * max(float(np.mean(m[idx])), 1e-300))
    t0, (start, w) = _run_scan(v[None], widths)
    g = np.random.default_rng(rng)
    hits = total = 0
    for count in (_RUN_FIRST, _RUN_MORE):
        chunk = max(1, 2_000_000 // len(v))         # ~16 MB a chunk at any N
        for k in np.diff(np.r_[0:count:chunk, count]):
            perm = g.permuted(np.broadcast_to(v, (k, len(v))), axis=1)
            hits += int(np.sum(_run_scan(perm, widths)[0] >= t0[0]))
        total += count
        if (1 + hits) / (1 + total) >= 0.01:
            break
    return (1 + hits) / (1 + total), idx[(start + np.arange(w)) % len(idx)]


_MISFIT_WORDS = {"neighbour_corr": "neighbouring points' scene errors are correlated",
                 "misfit_run": "a run of neighbouring points holds much of the misfit",
                 "chi2": "the residuals' sum of squares is too large",
                 "tail": "too many residuals beyond 3 sd"}


def flag_misfit(result):
    """Mark a converged least-squares result whose own model check fails at p <
    :data:`MISFIT_ALPHA` on one of :data:`MISFIT_STATISTICS` (in place): its
    ``extras["model_check"]`` gets the p-values (always), ``extras["model_misfit"]`` the
    failed statistics, ``extras["misfit_message"]`` the text and ``extras["failed_rows"]``
    the rows fitting worst.

    Returns
    -------
    str or None
        The message of a failure (what :func:`bayescal.calibrate_simultaneous` warns with,
        :class:`ModelMisfitWarning`), None when the check passes. The cost is one pass
        over the points (0.02 s at 300).
    """
    p = misfit_p_values(result)
    if not p:
        return None
    result.extras["model_check"] = {k: v for k, v in p.items()
                                    if k not in ("point_chi2", "run_rows")}
    failed = [k for k in MISFIT_STATISTICS if p.get(k, 1.0) < MISFIT_ALPHA]
    if not failed:
        return None
    rows = np.argsort(-p["point_chi2"], kind="stable")[:5]
    if "misfit_run" in failed:             # the run's rows, fitting worst first
        run = p["run_rows"]
        rows = run[np.argsort(-p["point_chi2"][run], kind="stable")]
    what = "; ".join(
        f"{_MISFIT_WORDS[k]} (p = {p[k]:.2g}"
        + (f", correlation {p['observed']['neighbour_corr']:.2f})" if k == "neighbour_corr"
           else ")") for k in failed)
    result.extras["failed_rows"] = rows
    result.extras["model_misfit"] = failed
    result.extras["misfit_message"] = (
        f"the fit's own model check fails: {what}: errors the model does not describe - a "
        f"few rows it did not flag moving the scene as a whole (h = {result.params.h:.4g} mm), "
        "a laser cone tilted against the camera (model='misaligned'), "
        + ("a streak or an arc of neighbouring rows a few sds off each (a ghost reflection, "
           "pixels of another feature), " if "misfit_run" in failed else "")
        + "or approximate points whose errors a wall shares (give a floor plan); its sds are "
        "not to be trusted (rows fitting worst, 0-based: " + ", ".join(map(str, rows[:10]))
        + (f" and {len(rows) - 10} more" if len(rows) > 10 else "") + ")")
    return result.extras["misfit_message"]
