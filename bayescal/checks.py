"""Checks on calibration input and fits: degenerate input, noise collapse, model fit.

Three kinds of check, usable by the least squares, the sampler and the CLI:

* :func:`check_calibration_input` refuses degenerate input before any fitting
  (too few points, one azimuth, no scene information, points the model cannot
  hold) with a message saying what is missing, and warns about exact
  duplicate rows (:class:`DuplicateRowsWarning`, naming the rows);
* :func:`check_noise_levels` refuses an inferred noise level that ended at
  its prior bound (:class:`NoiseCollapseError`, naming the rows that drive it);
* :func:`posterior_predictive_residuals` and :func:`posterior_predictive_check`
  compare the data with the model under every posterior draw (the plot is in
  :mod:`bayescal.plot_checks`).

See ``docs/robustness.md``.
"""

from __future__ import annotations

import warnings

import numpy as np

from ._validation import as_pixels, as_points, resolve_rng

__all__ = ["DuplicateRowsWarning", "NoiseCollapseError", "check_calibration_input",
           "check_noise_levels", "posterior_predictive_residuals",
           "posterior_predictive_check", "MIN_POINTS", "MIN_AZIMUTH_COVERAGE_DEG"]

#: fewest laser points a calibration accepts
MIN_POINTS = 4

#: smallest azimuth range (degrees) the laser pixels must cover around the principal point
MIN_AZIMUTH_COVERAGE_DEG = 45.0


class DuplicateRowsWarning(UserWarning):
    """Exact duplicate input rows (each would count twice and shrink every sd)."""


class NoiseCollapseError(ValueError):
    """An inferred noise level ended at its prior bound.

    Attributes
    ----------
    name : str
        ``"sigma_px"`` or ``"kappa"``.
    value : float
    rows : ndarray of int
        Input rows (0-based) whose data pull the level towards the bound most.
    """

    def __init__(self, message, *, name, value, rows):
        super().__init__(message)
        self.name, self.value, self.rows = name, value, np.asarray(rows, dtype=int)


def _rows_text(rows, limit=10):
    rows = [int(r) for r in rows]
    more = f" and {len(rows) - limit} more" if len(rows) > limit else ""
    return ", ".join(map(str, rows[:limit])) + more


def check_calibration_input(pixels, approx_points, *, sigma_scene, center):
    """Refuse input a calibration cannot use, before any fitting.

    Parameters
    ----------
    pixels : array_like, shape (N, 2)
        Laser pixels, px.
    approx_points : array_like, shape (N, 3)
        Approximate 3D points in frame C, mm.
    sigma_scene : float, array_like broadcastable to (N, 3), or None
        Scene noise, mm (None = inferred).
    center : tuple of float
        ``(u0, v0)`` used to measure the pixels' azimuths, px (the start values).

    Returns
    -------
    pixels : ndarray, shape (N, 2)
    approx_points : ndarray, shape (N, 3)

    Raises
    ------
    ValueError
        Non-finite values (rows named), fewer than :data:`MIN_POINTS` points,
        pixels covering less than :data:`MIN_AZIMUTH_COVERAGE_DEG` of azimuth,
        approximate points on the sensor axis, or no scene information at all.

    Warns
    -----
    DuplicateRowsWarning
        Rows whose pixel and approximate point are both identical (rows named).
    """
    pix = _finite_rows(pixels, "pixels", as_pixels)
    apx = _finite_rows(approx_points, "approx_points", as_points)
    if pix.ndim != 2 or apx.ndim != 2 or len(pix) != len(apx):
        raise ValueError(f"pixels must have shape (N, 2) and approx_points (N, 3) with the "
                         f"same length N, got {pix.shape} and {apx.shape}")
    n = len(pix)
    if n < MIN_POINTS:
        raise ValueError(f"need at least {MIN_POINTS} laser points, got N={n}: the seven "
                         "identifiable parameters need points spread around the laser ring")
    on_axis = np.flatnonzero(np.hypot(apx[:, 0], apx[:, 1]) <= 0)
    if on_axis.size:
        raise ValueError(f"approx_points rows {_rows_text(on_axis)} lie on the sensor axis "
                         "(x = y = 0), outside the model's domain: a laser point is on the "
                         "cone, away from the axis")
    _check_azimuths(pix, center)
    if sigma_scene is not None:
        s = np.asarray(sigma_scene, dtype=float)
        if s.size and np.all(np.isinf(s)):
            raise ValueError("sigma_scene is inf everywhere: the approximate points carry no "
                             "information, and the pixels alone (two rows per point, two "
                             "unknowns per point) cannot calibrate; give finite sigma_scene "
                             "on at least x and y")
    _warn_duplicates(pix, apx)
    return pix, apx


def _finite_rows(value, name, conv):
    arr = conv(value, name, allow_nan=True)
    if arr.ndim == 2 and not np.all(np.isfinite(arr)):
        bad = np.flatnonzero(~np.all(np.isfinite(arr), axis=1))
        raise ValueError(f"{name} must contain only finite values; rows {_rows_text(bad)} "
                         f"(0-based) hold NaN or inf ({bad.size} rows in all)")
    return conv(arr, name)


def _check_azimuths(pix, center):
    az = np.sort(np.arctan2(pix[:, 1] - center[1], pix[:, 0] - center[0]))
    gaps = np.diff(np.append(az, az[0] + 2 * np.pi))
    coverage = np.degrees(2 * np.pi - np.max(gaps))
    if coverage < MIN_AZIMUTH_COVERAGE_DEG:
        raise ValueError(f"pixels: all laser pixels lie within {coverage:.1f} degrees of "
                         f"azimuth around the principal point ({center[0]:g}, {center[1]:g}) "
                         f"(nearly one azimuth); the cone and the principal point cannot be "
                         f"separated: use points spread around the laser ring (at least "
                         f"{MIN_AZIMUTH_COVERAGE_DEG:g} degrees)")


def _warn_duplicates(pix, apx):
    rows = np.hstack([pix, apx])
    _, first, inverse, counts = np.unique(rows, axis=0, return_index=True,
                                          return_inverse=True, return_counts=True)
    dup = np.flatnonzero(counts[inverse.ravel()] > 1)
    if dup.size:
        groups = {}
        for i in dup:
            groups.setdefault(int(inverse.ravel()[i]), []).append(int(i))
        txt = "; ".join("rows " + ", ".join(map(str, g)) for g in groups.values())
        warnings.warn(f"exact duplicate input rows (0-based): {txt}; each copy counts as an "
                      "independent measurement and shrinks every sd", DuplicateRowsWarning,
                      stacklevel=3)


def check_noise_levels(lik, psi, q, *, factor=2.0, n_rows=5):
    """Refuse inferred noise levels that ended within ``factor`` of their prior bounds.

    Parameters
    ----------
    lik : bayescal.model.LaserLikelihood
    psi : ndarray, shape (7 + n_extra,)
        Parameters and extra globals at the fit (``log sigma_px``, ``log kappa``...).
    q : ndarray, shape (N, 2)
        Scene coordinates at the fit.
    factor : float
        A level within this factor of a bound counts as at the bound.
    n_rows : int
        How many driving rows to name.

    Raises
    ------
    NoiseCollapseError
        Naming the level, its value, the bound and the rows whose collapsed
        likelihood gains most by moving the level further towards the bound.
    """
    from .model import NOISE_BOUNDS

    psi = np.asarray(psi, dtype=float)
    for k, name in enumerate(lik.extra_names):
        if name not in NOISE_BOUNDS:
            continue
        lo, hi = NOISE_BOUNDS[name]
        v = float(np.exp(psi[7 + k]))
        if lo * factor < v < hi / factor:
            continue
        toward = -1.0 if v <= lo * factor else 1.0
        step = np.zeros_like(psi)
        step[7 + k] = 0.1 * toward
        gain = (lik._laplace_points(psi + step, q, 2)[0]
                - lik._laplace_points(psi, q, 2)[0])
        gain = np.where(np.isfinite(gain), gain, -np.inf)
        rows = np.argsort(-gain)[:n_rows]
        what = "pixel noise sigma_px" if name == "sigma_px" else "scene noise kappa"
        side = "lower" if toward < 0 else "upper"
        raise NoiseCollapseError(
            f"the inferred {what} ended at {v:.3g}, at its {side} bound ({lo:g}-{hi:g}): "
            f"the data cannot determine it (e.g. the other noise level leaves no degrees of "
            f"freedom, or a few rows dominate). Rows driving it most (0-based): "
            f"{_rows_text(rows)}. Check those rows, or give {name} explicitly",
            name=name, value=v, rows=rows)


# -- posterior predictive checks -------------------------------------------------------
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
    from .camera import project_theta
    from .parameters import to_identifiable

    a = np.asarray(param_samples, dtype=float)
    P = np.asarray(point_samples, dtype=float)
    pix = as_pixels(pixels, "pixels")
    apx = as_points(approx_points, "approx_points")
    if a.ndim != 2 or a.shape[1] != 8 or P.shape != (len(a), len(pix), 3):
        raise ValueError(f"param_samples must have shape (S, 8) and point_samples (S, N, 3) "
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
