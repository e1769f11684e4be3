"""Posterior predictive checks on residual arrays.

:func:`posterior_predictive_residuals` standardizes the data's residuals under
every posterior draw; :func:`posterior_predictive_check` compares them with
replicates (global p-values and per-point statistics). The check of a whole
result is :func:`bayescal.checks.model.predictive_check`; the plot is
:func:`bayescal.plotting.checks.plot_predictive_check`.
"""

from __future__ import annotations

import numpy as np

from .._validation import as_pixels, as_points, resolve_rng
from ..errors import InvalidValueError

__all__ = ["posterior_predictive_residuals", "posterior_predictive_check"]


def posterior_predictive_residuals(param_samples, point_samples, pixels, approx_points, *,
                                   sigma_px, sigma_scene):
    """Standardized residuals of the data under every posterior draw.

    For each draw s of the parameters and the points, the pixel residuals
    ``(project(params_s, P_si) - pixel_i) / sigma_px_s`` and the scene residuals
    ``(P_si - approx_i) / sigma_scene_si``; not the posterior-mean point through
    the posterior-mean parameters (which is a fit, not a check).

    Parameters
    ----------
    param_samples : array_like, shape (S, 8)
        Paper parameters per draw (order :data:`~bayescal.PARAM_NAMES`).
    point_samples : array_like, shape (S, N, 3)
        3D points per draw, mm.
    pixels : array_like, shape (N, 2)
    approx_points : array_like, shape (N, 3)
    sigma_px : float or array_like, shape (S,)
        Pixel noise, px (per draw when inferred).
    sigma_scene : float or array_like broadcastable to (S, N, 3)
        Scene noise, mm (per draw when inferred, e.g. ``kappa_s * rho_i``);
        inf = axis not used (its residual is NaN).

    Returns
    -------
    pixel : ndarray, shape (S, N, 2)
    scene : ndarray, shape (S, N, 3)
        NaN on unused axes.
    """
    from ..sensor.camera import project_theta
    from ..sensor.parameters import to_identifiable

    a = np.asarray(param_samples, dtype=float)
    P = np.asarray(point_samples, dtype=float)
    pix = as_pixels(pixels, "pixels")
    apx = as_points(approx_points, "approx_points")
    if a.ndim != 2 or a.shape[1] != 8 or P.shape != (len(a), len(pix), 3):
        raise InvalidValueError(f"param_samples must have shape (S, 8) and point_samples (S, N, 3) "
                                f"= ({len(a)}, {len(pix)}, 3), got {a.shape} and {P.shape}")
    theta = to_identifiable(a)
    uv, _ = project_theta(theta[:, None, :], P)
    sp = np.broadcast_to(np.asarray(sigma_px, dtype=float), (len(a),))
    ss = np.broadcast_to(np.asarray(sigma_scene, dtype=float), P.shape)
    with np.errstate(invalid="ignore"):
        scene = np.where(np.isfinite(ss), (P - apx) / ss, np.nan)
    return (uv - pix) / sp[:, None, None], scene


def posterior_predictive_check(pixel_res, scene_res, *, azimuth=None, rng=None, alpha=0.01):
    """Global posterior predictive check: does the model fit the data?

    Per draw, three discrepancies of the standardized residuals are compared
    with their values on data replicated from the model (independent N(0, 1)
    residuals of the same shape, which is what the model predicts for the
    residuals at a posterior draw):

    * ``chi2``: sum of squares over all rows (too-large noise or bias);
    * ``tail``: fraction of rows with ``|z| > 3`` (heavier tails than Gaussian);
    * ``neighbour_corr``: correlation of the scene residuals of neighbouring
      points in azimuth (errors shared by a wall), if ``azimuth`` is given.

    Parameters
    ----------
    pixel_res : ndarray, shape (S, N, 2)
    scene_res : ndarray, shape (S, N, 3)
        From :func:`posterior_predictive_residuals` (NaN rows are skipped).
    azimuth : array_like, shape (N,), optional
        Azimuth of each point, rad (orders the points for ``neighbour_corr``).
    rng : numpy.random.Generator, int or None
    alpha : float
        A tail probability below ``alpha`` (either side for ``chi2``) fails.

    Returns
    -------
    dict
        ``p_values`` {name: p}, ``observed`` {name: mean over draws},
        ``expected`` {name: mean under the model}, ``fits`` (bool), ``message`` (str),
        ``point_chi2`` (N,) the mean over draws of each point's sum of squares and
        ``point_rows`` (N,) its number of rows (its expectation under the model).
    """
    rng = resolve_rng(rng)
    z = np.concatenate([pixel_res, scene_res], axis=-1)           # (S, N, 5)
    used = np.isfinite(z)
    rep = np.where(used, rng.standard_normal(z.shape), np.nan)
    stats_obs, stats_rep = _ppc_stats(z, azimuth), _ppc_stats(rep, azimuth)
    p, obs, exp = {}, {}, {}
    for k in stats_obs:
        frac = np.mean(stats_rep[k] >= stats_obs[k])
        p[k] = float(2 * min(frac, 1 - frac)) if k == "chi2" else float(frac)
        obs[k], exp[k] = float(np.mean(stats_obs[k])), float(np.mean(stats_rep[k]))
    bad = [k for k in p if p[k] < alpha]
    names = {"chi2": "the residuals' sum of squares", "tail": "the fraction of |z| > 3",
             "neighbour_corr": "the correlation of neighbouring points' scene errors"}
    if bad:
        msg = "MODEL DOES NOT FIT: " + "; ".join(
            f"{names[k]} is {obs[k]:.3g} against {exp[k]:.3g} expected (p = {p[k]:.2g})"
            for k in bad)
    else:
        msg = "model fits: no discrepancy at p < " + f"{alpha:g}"
    return {"p_values": p, "observed": obs, "expected": exp, "fits": not bad, "message": msg,
            "point_chi2": np.nanmean(np.nansum(z * z, axis=-1), axis=0),
            "point_rows": used[0].sum(axis=-1)}


def _ppc_stats(z, azimuth):
    out = {"chi2": np.nansum(z * z, axis=(1, 2)),
           "tail": np.nanmean(np.abs(z) > 3, axis=(1, 2))}
    if azimuth is not None:
        sc = z[:, np.argsort(np.asarray(azimuth)), 2:]
        a, b = sc[:, :-1], sc[:, 1:]
        ok = np.isfinite(a) & np.isfinite(b)
        num = np.nansum(np.where(ok, a * b, np.nan), axis=(1, 2))
        den = np.sqrt(np.nansum(np.where(ok, a * a, np.nan), axis=(1, 2))
                      * np.nansum(np.where(ok, b * b, np.nan), axis=(1, 2)))
        out["neighbour_corr"] = num / den
    return out
