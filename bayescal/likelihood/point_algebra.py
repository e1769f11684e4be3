"""The per-point algebra of the collapsed laser likelihood: the hot path's terms
(:func:`point_terms`) and the analytic gradient (envelope theorem, :func:`grad_terms`).

Kept apart from :mod:`bayescal.likelihood.points` for size; used by
:meth:`bayescal.likelihood.points.LaserLikelihood.laplace` and
:meth:`~bayescal.likelihood.points.LaserLikelihood.grad_log_marginal`.
"""

from __future__ import annotations

import numpy as np

from ..sensor.laser import cone_height

__all__ = ["grad_terms", "point_terms", "normal_terms", "cone_height", "pixel_whitening",
           "whiten", "whiten_pair"]


def pixel_whitening(pixel_cov, n):
    """Per-point whitening of the pixel residuals from their covariances.

    Parameters
    ----------
    pixel_cov : array_like, shape (n, 2, 2) or None
        Pixel covariances, px^2 (symmetric positive definite).
    n : int
        Number of points.

    Returns
    -------
    white : ndarray, shape (n, 3) or None
        ``(a, b, c)`` of the upper-triangular ``L = [[a, b], [0, c]]`` with
        ``L^T L = pixel_cov^-1``: whitened ``(ru, rv) -> (a ru + b rv, c rv)``.
    log_det : ndarray, shape (n,) or float
        ``log det L = -log det(pixel_cov) / 2`` (0.0 without covariances).
    """
    if pixel_cov is None:
        return None, 0.0
    cov = np.asarray(pixel_cov, dtype=float)
    if cov.shape != (n, 2, 2):
        raise ValueError(f"pixel_cov must have shape (N, 2, 2) = {(n, 2, 2)} px^2, got "
                         f"{cov.shape}")
    bad = ~np.all(np.isfinite(cov), axis=(1, 2)) | (np.abs(cov[:, 0, 1] - cov[:, 1, 0])
                                                   > 1e-9 * np.abs(cov).max(axis=(1, 2)))
    det = cov[:, 0, 0] * cov[:, 1, 1] - cov[:, 0, 1] * cov[:, 1, 0]
    bad |= ~(cov[:, 0, 0] > 0) | ~(det > 0)
    if np.any(bad):
        i = int(np.flatnonzero(bad)[0])
        raise ValueError(f"pixel_cov must be symmetric positive definite; row {i} is "
                         f"{cov[i].tolist()}")
    prec = np.linalg.inv(cov)
    a = np.sqrt(prec[:, 0, 0])
    b = prec[:, 0, 1] / a
    c = np.sqrt(prec[:, 1, 1] - b * b)
    return np.stack([a, b, c], axis=-1), np.log(a * c)


def whiten(white, r, axis=-1):
    """Whitened pixel rows: ``r`` (..., N, 2) with (u, v) on ``axis`` (-1, or -2 for
    Jacobians (..., N, 2, k)); ``white`` from :func:`pixel_whitening` (None: unchanged)."""
    if white is None:
        return r
    r = np.moveaxis(np.asarray(r), axis, -1)
    a, b, c = white[:, 0], white[:, 1], white[:, 2]
    if axis != -1:
        a, b, c = a[:, None], b[:, None], c[:, None]
    out = np.stack([a * r[..., 0] + b * r[..., 1], c * r[..., 1]], axis=-1)
    return np.moveaxis(out, -1, axis)


def whiten_pair(white, ru, rv):
    """Whitened pixel rows as a pair: ``ru, rv`` (..., n) with ``white`` (n, 3) or None."""
    if white is None:
        return ru, rv
    out = whiten(white, np.stack([ru, rv], axis=-1))
    return out[..., 0], out[..., 1]


def point_terms(lik, theta, x, y, sig, w):
    """Hot path of :meth:`~bayescal.likelihood.points.LaserLikelihood.laplace`: residuals and
    q-normal equations, elementwise.

    Same quantities as :meth:`~bayescal.likelihood.points.LaserLikelihood.residuals` (tested
    against it), written out for 2x2 blocks so that walkers x points cost a few
    dozen array ops.
    Returns ``(rr, Cp, Cs, g0, g1)``: ``rr = |R|^2``, the pixel and scene
    parts of ``J_q^T J_q`` as ``(C00, C01, C11)`` triples, and the gradient.
    ``theta`` (..., 7), or (..., 11) with the laser pose (:func:`cone_height`).
    """
    xi, gu, gv, u0, v0 = (theta[..., k, None] for k in range(5))
    z, gx, gy = cone_height(theta, x, y)
    r = np.sqrt(x * x + y * y + z * z)
    D = xi * r - z
    iD = np.where(D > 0, 1.0 / D, np.nan)
    mx, my = x * iD, y * iD
    inv_s = 1.0 / sig[..., None]
    ru = (gu * mx + u0 - lik.pixels[:, 0]) * inv_s
    rv = (gv * my + v0 - lik.pixels[:, 1]) * inv_s
    white = getattr(lik, "px_white", None)
    xr = xi / r
    dDx = xr * (x + z * gx) - gx
    dDy = xr * (y + z * gy) - gy
    a, b = gu * iD * inv_s, gv * iD * inv_s
    ux, uy = a * (1.0 - mx * dDx), -a * mx * dDy
    vx, vy = -b * my * dDx, b * (1.0 - my * dDy)
    if white is not None:                                   # per-point pixel covariances
        la, lb, lc = white[:, 0], white[:, 1], white[:, 2]
        ru, rv = la * ru + lb * rv, lc * rv
        ux, vx = la * ux + lb * vx, lc * vx
        uy, vy = la * uy + lb * vy, lc * vy
    return normal_terms(lik, x, y, z, (ru, rv), (ux, uy, vx, vy), (gx, gy), w)


def normal_terms(lik, x, y, z, r_px, J_px, dz, w):
    """``(rr, Cp, Cs, g0, g1)`` of :func:`point_terms` from a point's whitened pixel
    residuals ``r_px = (ru, rv)``, their q-derivatives ``J_px = (ux, uy, vx, vy)``, the
    cone's slope ``dz = (dz/dx, dz/dy)`` and the scene weights ``w`` (..., N, 3)
    (shared by the aligned and the misaligned cone)."""
    (ru, rv), (ux, uy, vx, vy), (gx, gy) = r_px, J_px, dz
    wx, wy, wz = w[..., 0], w[..., 1], w[..., 2]
    rx, ry, rz = (x - lik.approx[:, 0]) * wx, (y - lik.approx[:, 1]) * wy, \
        (z - lik.approx[:, 2]) * wz
    wz2 = wz * wz
    Cp = (ux * ux + vx * vx, ux * uy + vx * vy, uy * uy + vy * vy)
    Cs = (wx * wx + wz2 * gx * gx, wz2 * gx * gy, wy * wy + wz2 * gy * gy)
    g0 = ux * ru + vx * rv + wx * rx + wz * gx * rz
    g1 = uy * ru + vy * rv + wy * ry + wz * gy * rz
    rr = ru * ru + rv * rv + rx * rx + ry * ry + rz * rz
    return rr, Cp, Cs, g0, g1


def grad_terms(lik, theta, x, y, sig, w, *, outlier_resp=None, logit_w=None):
    """Gradient of ``sum_i log marginal_i`` of a :class:`~.points.LaserLikelihood`.

    Parameters
    ----------
    lik : LaserLikelihood
    theta : ndarray, shape (..., 7) or (..., 11)
    x, y : ndarray, shape (..., N)
        The conditional modes' scene coordinates, mm.
    sig : ndarray, shape (...)
        Pixel noise, px.
    w : ndarray, shape (..., N, 3)
        Inverse scene standard deviations, 1/mm.
    outlier_resp : ndarray, shape (..., N), optional
        With the outlier mixture: each point's outlier probability ``r_i``; its
        residual terms are weighted by ``(1 - r_i) + r_i / c^2`` (the outlier
        component has ``c`` times the noise) and ``logit w`` gets ``sum_i (r_i - w)``.
    logit_w : ndarray, shape (...), optional
        The sampled ``logit w`` (with ``outlier_resp``).

    Returns
    -------
    ndarray, shape (..., n_geo + n_noise)
        the geometry's part ``-sum_i J_theta_i^T R_i`` written out elementwise (theta, and
        the laser pose with the misaligned model: it enters through the height), then the
        inferred noise levels' (see :meth:`LaserLikelihood.grad_log_marginal`),
        then ``logit w``'s with the mixture.
    """
    if outlier_resp is None:
        wt = 1.0
    else:
        wt = (1.0 - outlier_resp) + outlier_resp / lik.outlier_scale**2
    xi, gu, gv, u0, v0 = (theta[..., k, None] for k in range(5))
    z, _, _, dz = cone_height(theta, x, y, geometry=True)
    r = np.sqrt(x * x + y * y + z * z)
    D = xi * r - z
    mx, my = x / D, y / D
    inv_s = 1.0 / sig[..., None]
    ru = (gu * mx + u0 - lik.pixels[:, 0]) * inv_s
    rv = (gv * my + v0 - lik.pixels[:, 1]) * inv_s
    white = getattr(lik, "px_white", None)
    if white is not None:       # J^T L^T L r: the residual whitened, then L^T applied again
        la, lb, lc = white[:, 0], white[:, 1], white[:, 2]
        wu, wv = la * ru + lb * rv, lc * rv
        ru, rv = la * wu, lb * wu + lc * wv
    wz = w[..., 2]
    rzw = wt * (z - lik.approx[:, 2]) * wz * wz           # r_z * d r_z / d z
    ru_w, rv_w = wt * ru, wt * rv
    A = wt * (ru * gu * mx + rv * gv * my) * inv_s / D     # -(d r_px / d D) . r_px
    K = A * (xi * z / r - 1.0) - rzw                        # -(d R / d z) . R, per point
    out = [np.sum(A * r, -1), -np.sum(ru_w * mx * inv_s, -1), -np.sum(rv_w * my * inv_s, -1),
           -np.sum(ru_w * inv_s, -1), -np.sum(rv_w * inv_s, -1)]
    out += [np.sum(K * d, -1) for d in dz]                  # h, beta (and the pose) via z
    if lik.n_noise:
        rr_p = ru * ru + rv * rv if white is None else wu * wu + wv * wv
        rr_s = ((x - lik.approx[:, 0]) * w[..., 0]) ** 2 \
            + ((y - lik.approx[:, 1]) * w[..., 1]) ** 2 + ((z - lik.approx[:, 2]) * wz) ** 2
        out += _noise_terms(lik, point_terms(lik, theta, x, y, sig, w), rr_p, rr_s, wt)
    return _with_outlier_term(out, outlier_resp, logit_w)


def _noise_terms(lik, terms, rr_p, rr_s, wt):
    """The inferred noise levels' gradient entries from the point terms at the modes and
    each point's squared pixel (``rr_p``) and scene (``rr_s``) residuals."""
    _, Cp, Cs, _, _ = terms
    C00, C01, C11 = (a + b for a, b in zip(Cp, Cs, strict=True))
    det = C00 * C11 - C01 * C01

    def tr_cinv(B):                                         # tr(C^-1 B) per point
        return (C11 * B[0] - 2 * C01 * B[1] + C00 * B[2]) / det
    out = []
    if lik.infer_px:
        out.append(np.sum(wt * rr_p - 2.0 + tr_cinv(Cp), -1))
    if lik.infer_scene:
        out.append(np.sum(wt * rr_s - 3.0 + tr_cinv(Cs), -1))
    return out


def _with_outlier_term(out, outlier_resp, logit_w):
    if outlier_resp is not None:
        w_frac = 1.0 / (1.0 + np.exp(-np.asarray(logit_w, dtype=float)))
        out.append(np.sum(outlier_resp - w_frac[..., None], -1))
    return np.stack(out, -1)
