"""Residual checks behind the residual figures and the report's warnings.

* :func:`posterior_residuals`: standardized pixel residuals under posterior
  draws (a thin call of :func:`bayescal.checks.predictive.posterior_predictive_residuals`),
  ``(pixel - project(params_s, point_s)) / sigma_px_s`` for joint draws
  ``s``. In a linear-Gaussian model these are exactly N(0, 1) when the model
  is right (the fit's shrinkage ``sigma^2 (I - H)`` plus the posterior spread
  ``sigma^2 H`` add back to ``sigma^2 I``), so the N(0, 1) overlay is the right
  reference. Projecting the posterior-mean points with the posterior-mean
  parameters is *not* a fit and must not be used.
* :func:`least_squares_residuals`: pixel residuals at the least-squares
  solution divided by ``sigma_px * sqrt(1 - n_unknowns / n_residuals)``, the
  degrees-of-freedom factor by which a fit's residuals are smaller than the
  noise (the same factor the estimated pixel noise uses).
* :func:`noise_warnings`: plain-language warnings when the pixel noise the
  least squares estimated is far from the one used, or when few degrees of
  freedom are left.
"""

from __future__ import annotations

import numpy as np

from .._validation import resolve_rng
from ..sensor.camera import project
from ..sensor.laser import cone_points_geo

__all__ = ["posterior_residuals", "least_squares_residuals", "least_squares_scene_residuals",
           "noise_warnings", "draw_indices",
           "NOISE_RATIO_WARN"]

#: estimated / used pixel noise outside [1 / NOISE_RATIO_WARN, NOISE_RATIO_WARN] is reported
NOISE_RATIO_WARN = 2.0


def draw_indices(n_samples, n_draws):
    """Evenly thinned indices of at most ``n_draws`` of ``n_samples`` draws, shape (n,)."""
    return np.unique(np.linspace(0, n_samples - 1, min(int(n_draws), n_samples)).round()
                     .astype(int))


def _scene_sd(posterior, idx):
    """Scene sds per draw, broadcastable to (n, N, 3), mm (inf without scene rows)."""
    names = tuple(getattr(posterior, "noise_names", ()))
    approx = getattr(posterior, "approx_points", None)
    if getattr(posterior, "sigma_scene", None) is not None:
        return np.asarray(posterior.sigma_scene, dtype=float)
    if "kappa" in names and approx is not None:
        kappa = np.exp(posterior.noise_samples[idx, names.index("kappa")])
        rho = np.hypot(approx[:, 0], approx[:, 1])
        return kappa[:, None, None] * rho[None, :, None]
    return np.inf


def posterior_residuals(posterior, *, n_draws=100, rng=None, scene=False):
    """Standardized residuals under joint posterior draws.

    A thin call of :func:`bayescal.checks.predictive.posterior_predictive_residuals` on
    ``n_draws`` evenly thinned draws, with each draw's noise levels, in the
    sign convention of the residual figures: data minus model.

    Parameters
    ----------
    posterior : Posterior
    n_draws : int, optional
        Draws used (evenly thinned).
    rng : numpy.random.Generator, int or None
        Unused for evenly thinned draws; accepted for symmetry.
    scene : bool, optional
        Also return the scene residuals.

    Returns
    -------
    pixel : ndarray, shape (n_draws, N, 2)
        Dimensionless ``(pixel - project(params_s, point_s)) / sigma_px_s``, whitened per
        point by the posterior's ``pixel_cov`` (N, 2, 2) when it has one.
    scene : ndarray, shape (n_draws, N, 3)
        Only with ``scene=True``: ``(approx - point_s) / sigma_scene_s``, NaN
        on axes without scene information (and everywhere for a floor plan).
    """
    from .predictive import posterior_predictive_residuals

    resolve_rng(rng)
    idx = draw_indices(posterior.n_samples, n_draws)
    approx = getattr(posterior, "approx_points", None)
    points = posterior.point_samples[idx]
    if approx is None or np.shape(approx) != points.shape[1:] or not np.all(np.isfinite(approx)):
        approx = points.mean(axis=0)              # no scene rows (floor plan): a finite stand-in
    pix, sc = posterior_predictive_residuals(
        posterior.param_samples[idx], points, posterior.pixels, approx,
        sigma_px=posterior._sigma_px_samples()[idx], sigma_scene=_scene_sd(posterior, idx))
    cov = getattr(posterior, "pixel_cov", None)
    if cov is not None:                     # per-point pixel covariances: whitened residuals
        from ..likelihood.point_algebra import pixel_whitening, whiten

        pix = whiten(pixel_whitening(cov, pix.shape[-2])[0], pix)
    return (-pix, -sc) if scene else -pix


def _projection_jacobian(params, points):
    """d project / d point, shape (N, 2, 3), px/mm (central differences, 1e-3 mm)."""
    J = np.empty(points.shape[:1] + (2, 3))
    for k in range(3):
        d = np.zeros(3)
        d[k] = 1e-3
        J[:, :, k] = (project(params, points + d) - project(params, points - d)) / 2e-3
    return J


def _cone_tangent(params, points, result=None):
    """Orthonormal tangent basis of the laser cone at each point, shape (N, 3, 2) (of the
    fitted tilted cone when ``result`` is a misaligned fit)."""
    geo = result.geometry() if hasattr(result, "geometry") else None
    if geo is not None and len(geo) > 7:
        return np.linalg.qr(cone_points_geo(geo, points[:, :2], jacobian=True)[1])[0]
    rho = np.maximum(np.hypot(points[:, 0], points[:, 1]), 1e-9)
    cb, sb = np.cos(params.beta), np.sin(params.beta)
    n = np.column_stack([cb * points[:, 0] / rho, cb * points[:, 1] / rho,
                         np.full(len(points), -sb)])
    t1 = np.column_stack([-points[:, 1] / rho, points[:, 0] / rho, np.zeros(len(points))])
    t2 = np.cross(n, t1)
    return np.stack([t1, t2 / np.linalg.norm(t2, axis=1, keepdims=True)], axis=2)


def least_squares_residuals(result, pixels, sigma_px, sigma_scene=None):
    """Pixel residuals of a least-squares result, each divided by its own expected sd.

    A fit absorbs part of the noise: the residual of a pixel coordinate has
    variance ``sigma_px^2 (1 - h)`` with ``h`` its leverage. For the
    simultaneous method each point moves on the laser cone (2 unknowns) under
    2 pixel rows and 3 scene rows, so ``h`` is the diagonal of the local hat
    matrix ``A (A^T A)^-1 A^T`` with ``A = [P T / sigma_px; T / sigma_scene]``
    (``P = d project / d point``, ``T`` the cone's tangent basis); the 7 global
    parameters' share (7 of the residuals) is neglected. Without the scene sds
    the global factor ``sqrt(1 - n_unknowns / n_residuals)`` is used.

    Parameters
    ----------
    result : CalibrationResult
        With ``points`` (N, 3).
    pixels : ndarray, shape (N, 2)
        px.
    sigma_px : float
        Pixel noise used (or estimated), px.
    sigma_scene : ndarray, shape (N, 3), optional
        Scene sds of the approximate points, mm (``inf`` = no information).

    Returns
    -------
    raw : ndarray, shape (N, 2)
        px.
    z : ndarray, shape (N, 2)
        Dimensionless (whitened by ``extras["pixel_cov"]`` when the fit had per-point
        covariances); about N(0, 1) for a correct model. For a floor-plan
        result (``extras["walls"]``) each point has one free coordinate, its
        azimuth, which absorbs the residual along the image direction it moves
        in: ``z[:, 0]`` is the residual across that direction divided by
        ``sigma_px sqrt(1 - (7 + 2W) / N)`` and ``z[:, 1]`` is NaN (one degree
        of freedom per point).
    """
    raw = np.asarray(pixels, float) - project(result.params, result.points)
    if result.extras.get("walls") is not None and result.extras.get("azimuths") is not None:
        return raw, _plan_z(result, raw, sigma_px)
    if sigma_scene is None:
        frac = 1.0 - result.n_unknowns / max(result.n_residuals, 1)
        return raw, _whiten_px(result, raw) / (sigma_px * np.sqrt(max(frac, 1e-12)))
    h = _local_leverage(result, sigma_px, sigma_scene)[:, :2]
    var = sigma_px**2 * np.clip(1.0 - h, 1e-4, 1.0)
    return raw, _whiten_px(result, raw) / np.sqrt(var)


def _whiten_px(result, r, axis=-1):
    """Pixel rows (..., N, 2) whitened by ``extras["pixel_cov"]`` (unchanged without)."""
    cov = result.extras.get("pixel_cov")
    if cov is None:
        return r
    from ..likelihood.point_algebra import pixel_whitening, whiten

    return whiten(pixel_whitening(cov, len(result.points))[0], r, axis=axis)


def _local_design(result, sigma_px, sigma_scene):
    """Each point's whitened local design ``A`` (N, 5, 2): 2 pixel rows, 3 scene rows."""
    T = _cone_tangent(result.params, result.points, result)
    top = _whiten_px(result, _projection_jacobian(result.params, result.points) @ T / sigma_px,
                     axis=-2)                                                      # (N, 2, 2)
    bottom = T / np.broadcast_to(np.asarray(sigma_scene, float), result.points.shape)[..., None]
    return np.concatenate([top, bottom], axis=1)


def _hat(A):
    """Each point's hat matrix ``A (A^T A)^-1 A^T``, shape (N, 5, 5), as ``U U^T`` of the
    SVD of ``A``: the same projection, without forming ``A^T A``, whose condition number is
    the square of ``A``'s (an sd of 3e-15 mm beside a 0.2 px one made it singular). A
    direction whose singular value is below ``1e-12`` of the largest is left out."""
    A = np.where(np.isfinite(A), A, 0.0)
    U, sv, _ = np.linalg.svd(A, full_matrices=False)
    keep = sv > 1e-12 * np.max(sv, axis=-1, keepdims=True)
    U = U * keep[:, None, :]
    return U @ np.swapaxes(U, 1, 2)


def _local_leverage(result, sigma_px, sigma_scene):
    """Diagonal of each point's local hat matrix, shape (N, 5): 2 pixel rows, 3 scene rows."""
    return np.diagonal(_hat(_local_design(result, sigma_px, sigma_scene)), axis1=1, axis2=2)


def least_squares_scene_residuals(result, pixels, approx_points, sigma_px, sigma_scene):
    """Independent N(0, 1) residuals of a per-point least-squares fit, one per scene axis.

    Each point's whitened residual vector ``r`` (2 pixel rows, whitened by
    ``extras["pixel_cov"]`` when the fit had per-point covariances, 3 scene rows;
    the rows of axes with ``sigma_scene = inf`` dropped) has covariance
    ``I - H`` after the fit, ``H`` the local hat matrix of its 2 free
    coordinates on the cone: rank = the number of finite scene axes. Its
    components along the orthonormalized ``(I - H) e_k`` (``e_k`` the scene
    row of axis ``k``, Gram-Schmidt in the order x, y, z) are independent
    N(0, 1) for a correct model, and keep the sign and the axis of the scene
    error, so that errors shared by neighbouring points stay visible. The 7
    global parameters' share of the residuals is neglected.

    Parameters
    ----------
    result : CalibrationResult
        Per-point simultaneous result with ``points`` (N, 3).
    pixels : ndarray, shape (N, 2)
        px.
    approx_points : ndarray, shape (N, 3)
        mm.
    sigma_px : float
        px.
    sigma_scene : ndarray, broadcastable to (N, 3)
        mm; inf = no information on that axis.

    Returns
    -------
    ndarray, shape (N, 3)
        Dimensionless; NaN on axes with ``sigma_scene = inf``.
    """
    pts = result.points
    ss = np.broadcast_to(np.asarray(sigma_scene, float), pts.shape)
    fin = np.isfinite(ss)
    A = _local_design(result, sigma_px, np.where(fin, ss, np.inf))
    with np.errstate(invalid="ignore", divide="ignore"):
        r = np.concatenate([_whiten_px(result, (np.asarray(pixels, float)
                                                - project(result.params, pts)) / sigma_px),
                            np.where(fin, (np.asarray(approx_points, float) - pts) / ss, 0.0)],
                           axis=1)                                               # (N, 5)
    H = _hat(A)
    B = (np.eye(5) - H)[:, :, 2:] * fin[:, None, :]                              # (N, 5, 3)
    z = np.full(pts.shape, np.nan)
    for i in range(len(pts)):
        cols = np.flatnonzero(fin[i])
        if cols.size == 0:
            continue
        q, rr = np.linalg.qr(B[i][:, cols])
        q = q * np.sign(np.diag(rr))[None, :]                                    # Gram-Schmidt
        z[i, cols] = q.T @ r[i]
    return z


def _plan_z(result, raw, sigma_px, eps=1e-6):
    """One standardized residual per point of a floor-plan fit, shape (N, 2) (column 1 NaN);
    with ``extras["pixel_cov"]`` in the metric of each point's covariance (whitened)."""
    from ..scene.floorplan import plan_point

    walls = np.asarray(result.extras["walls"], float)
    k = np.asarray(result.extras["wall_index"]).astype(int)
    t = np.asarray(result.extras["azimuths"], float)
    theta = result.params.to_identifiable()
    d, a = walls[k, 0], walls[k, 1]
    du = (project(result.params, plan_point(theta, t + eps, d, a))
          - project(result.params, plan_point(theta, t - eps, d, a))) / (2 * eps)
    raw, du = _whiten_px(result, raw), _whiten_px(result, du)   # per-point covariances
    n = np.column_stack([-du[:, 1], du[:, 0]])
    n /= np.linalg.norm(n, axis=1, keepdims=True)
    share = (result.n_unknowns - len(t)) / max(len(t), 1)   # 7 + 2W globals over N points
    z = np.full(raw.shape, np.nan)
    z[:, 0] = np.einsum("ni,ni->n", raw, n) / (sigma_px * np.sqrt(max(1.0 - share, 1e-12)))
    return z


def noise_warnings(result, sigma_px_used):
    """Warnings about the pixel noise of a least-squares result (list of str)."""
    out = []
    est = result.sigma_px_estimated
    if est is not None and sigma_px_used:
        ratio = est / sigma_px_used
        if not (1 / NOISE_RATIO_WARN <= ratio <= NOISE_RATIO_WARN):
            out.append(f"The pixel noise estimated from the residuals ({est:.3g} px) is "
                       f"{ratio:.3g} x the one given ({sigma_px_used:.3g} px): the model does "
                       "not fit these data at the stated noise, so the sds and intervals below "
                       "are not reliable (check the pixel noise, the scene sds and outliers).")
    dof = result.n_residuals - result.n_unknowns
    if dof < 10:
        out.append(f"Only {dof} degrees of freedom are left ({result.n_residuals} residuals, "
                   f"{result.n_unknowns} unknowns): the noise estimate and the sds are rough.")
    if not result.converged:
        out.append(f"The {result.method} solver did not converge: {result.message}.")
    return out
