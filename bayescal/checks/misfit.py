"""Is a converged least-squares fit one its own model check accepts?

:func:`flag_misfit` marks a solution whose model check
(:func:`bayescal.checks.model.model_check`) fails at p < :data:`MISFIT_ALPHA` on a statistic
of the residuals' structure, which a wrong fit leaves and a right one with a slightly wrong
noise model does not; :func:`bayescal.calibrate_simultaneous` then warns
(:class:`ModelMisfitWarning`) and the command line exits 1 (``docs/robustness.md``, 4c).
"""

from __future__ import annotations

import numpy as np

from ..errors import BayescalWarning
from .datafile import OUTLIER_FLAG
from .model import _residuals, _result_data

__all__ = ["ModelMisfitWarning", "flag_misfit", "misfit_p_values", "MISFIT_ALPHA",
           "MISFIT_STATISTICS"]


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
MISFIT_STATISTICS = ("neighbour_corr",)
#: permutations of the ring-harmonic p-value when it is computed to MISFIT_ALPHA
_PERMUTATIONS = 20000


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
    return out


_MISFIT_WORDS = {"neighbour_corr": "neighbouring points' scene errors are correlated",
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
    result.extras["model_check"] = {k: v for k, v in p.items() if k != "point_chi2"}
    failed = [k for k in MISFIT_STATISTICS if p.get(k, 1.0) < MISFIT_ALPHA]
    if not failed:
        return None
    rows = np.argsort(-p["point_chi2"], kind="stable")[:5]
    what = "; ".join(
        f"{_MISFIT_WORDS[k]} (p = {p[k]:.2g}"
        + (f", correlation {p['observed']['neighbour_corr']:.2f})" if k == "neighbour_corr"
           else ")") for k in failed)
    result.extras["failed_rows"] = rows
    result.extras["model_misfit"] = failed
    result.extras["misfit_message"] = (
        f"the fit's own model check fails: {what}: errors the model does not describe - a "
        f"few rows it did not flag moving the scene as a whole (h = {result.params.h:.4g} mm), "
        "a laser cone tilted against the camera (model='misaligned'), or approximate points "
        "whose errors a wall shares (give a floor plan); its sds are not to be trusted (rows "
        "fitting worst, 0-based: " + ", ".join(map(str, rows)) + ")")
    return result.extras["misfit_message"]
