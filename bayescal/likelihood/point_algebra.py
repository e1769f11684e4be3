"""The per-point algebra of the collapsed laser likelihood: the hot path's terms
(:func:`point_terms`) and the analytic gradient (envelope theorem, :func:`grad_terms`).

Kept apart from :mod:`bayescal.likelihood.points` for size; used by
:meth:`bayescal.likelihood.points.LaserLikelihood.laplace` and
:meth:`~bayescal.likelihood.points.LaserLikelihood.grad_log_marginal`; the aligned cone's
fused passes also serve the point draws (:mod:`bayescal.likelihood.point_draws`) and the
posterior's outlier probabilities (:func:`outlier_probs`).
"""

from __future__ import annotations

import numpy as np
from scipy.special import expit, log_expit

from ..errors import InvalidValueError
from ..sensor.laser import cone_height

_LOG2PI = np.log(2 * np.pi)

__all__ = ["grad_terms", "point_terms", "normal_terms", "cone_height", "pixel_whitening",
           "whiten", "whiten_pair", "marginal_sum", "marginal_block",
           "point_columns", "outlier_probs"]


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
        raise InvalidValueError(f"pixel_cov must have shape (N, 2, 2) = {(n, 2, 2)} px^2, got "
                                f"{cov.shape}")
    bad = ~np.all(np.isfinite(cov), axis=(1, 2)) | (np.abs(cov[:, 0, 1] - cov[:, 1, 0])
                                                   > 1e-9 * np.abs(cov).max(axis=(1, 2)))
    det = cov[:, 0, 0] * cov[:, 1, 1] - cov[:, 0, 1] * cov[:, 1, 0]
    bad |= ~(cov[:, 0, 0] > 0) | ~(det > 0)
    if np.any(bad):
        i = int(np.flatnonzero(bad)[0])
        raise InvalidValueError(f"pixel_cov must be symmetric positive definite; row {i} is "
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


def point_columns(lik):
    """Contiguous per-point columns of :func:`marginal_sum`, cached on ``lik`` (a block
    likelihood has its own: :mod:`~bayescal.likelihood.point_blocks` drops the cache)."""
    cols = lik.__dict__.get("_marginal_columns")
    if cols is None:
        px, ap = lik.pixels, lik.approx
        cols = {"pu": px[:, 0].copy(), "pv": px[:, 1].copy(), "ax": ap[:, 0].copy(),
                "ay": ap[:, 1].copy(), "az": ap[:, 2].copy(),
                "rows": float(np.sum(lik._n_rows))}
        if not lik.infer_scene:
            cols.update(wx=lik.w_scene[:, 0].copy(), wy=lik.w_scene[:, 1].copy(),
                        wz=lik.w_scene[:, 2].copy(), log_w=float(np.sum(lik._log_w_given)))
        else:
            cols["log_rho"] = float(np.sum(np.log(lik.rho)))
        lik._marginal_columns = cols
    return cols


def _fused_applies(lik, psi, q0):
    """Whether :func:`marginal_sum` covers this call: the aligned cone (``lik.n_geo`` 7),
    no per-point pixel covariances, ``psi`` (W, d), ``q0`` (N, 2) or (W, N, 2)."""
    return (lik.n_geo == 7 and np.ndim(psi) == 2 and getattr(lik, "px_white", None) is None
            and np.ndim(q0) in (2, 3) and np.shape(q0)[-1] == 2)


def _fused_call(lik, psi, q0, n_iter, modes):
    psi = np.asarray(psi, dtype=float)
    theta, extra = psi[:, :7], psi[:, 7:]
    sig = np.exp(extra[:, 0]) if lik.infer_px else np.full(len(psi), lik.sigma_px)
    with np.errstate(invalid="ignore", divide="ignore", over="ignore"):
        return marginal_sum(lik, theta, extra, sig, q0, n_iter, modes=modes), theta, extra, sig


def marginal_block(lik, psi, q0, n_iter, *, gradient=False):
    """``(total,)``: the sum over points (W,) of the log marginals of a
    :class:`~bayescal.likelihood.points.LaserLikelihood` (one block of points): by
    :func:`marginal_sum` where it applies (:func:`_fused_applies`), else by ``laplace``'s
    per-point terms. With ``gradient``: ``(total, grad)`` by :func:`marginal_sum` (the
    value exactly the same, its modes and outlier probabilities for :func:`grad_terms`),
    or None where it does not apply."""
    if not _fused_applies(lik, psi, q0):
        return None if gradient else (lik._laplace_block(psi, q0, n_iter)[0].sum(axis=-1),)
    if not gradient:
        return (_fused_call(lik, psi, q0, n_iter, False)[0],)
    (total, x, y, r), theta, extra, sig = _fused_call(lik, psi, q0, n_iter, True)
    _, w, _ = lik.noise(extra)
    lw = extra[..., -1] if lik.outliers else None
    with np.errstate(invalid="ignore", divide="ignore"):
        return total, grad_terms(lik, theta, x, y, sig, w, outlier_resp=r, logit_w=lw)


def _walker_terms(theta, sig):
    """Per-walker factors (W, 1) of :func:`_fused_terms`; ``inv_s`` a float when every
    walker has the same pixel noise (then the pixels' share is per point)."""
    t = theta[:, :, None]
    inv = 1.0 / sig
    inv_s = float(inv[0]) if np.all(inv == inv[0]) else inv[:, None]
    return {"xi": t[:, 0], "h": t[:, 5], "iT": 1.0 / np.tan(t[:, 6]), "inv_s": inv_s,
            "A": t[:, 1] * inv_s, "B": t[:, 2] * inv_s, "cu": t[:, 3] * inv_s,
            "cv": t[:, 4] * inv_s}


def _fused_terms(p, c, x, y, w, last, keep_cp, grad=True):
    """:func:`point_terms` of the aligned cone in fewer passes (in place, rho-based slopes):
    ``(rr, (C00, C01, C11), g0, g1, (Cp, Cs) or None)`` with ``C = Cp + Cs`` (``rr`` only
    on the ``last`` pass). ``x, y`` (N,) on the first Gauss-Newton pass (the shared start:
    per-point work stays (N,)), else (W, N); ``w`` = ``(wx, wy, wz)``, each (N,) or (W, N).
    Without ``grad`` (a density alone) C, g0 and g1 are None (the same ``rr`` and parts)."""
    xi, iT, inv_s = p["xi"], p["iT"], p["inv_s"]
    wx, wy, wz = w
    rho2 = x * x + y * y
    rho = np.sqrt(rho2)
    cx, cy = x / rho, y / rho
    z = rho * iT
    z -= p["h"]
    r = z * z
    r += rho2
    np.sqrt(r, out=r)
    D = xi * r
    D -= z
    bad = None if D.min() > 0 else ~(D > 0)         # NaN there, as point_terms
    iD = np.divide(1.0, D, out=D)
    if bad is not None:
        iD[bad] = np.nan
    t = z * iT                                      # d D / d q = (x, y) / rho * k, k:
    t += rho
    t *= xi
    t /= r
    t -= iT
    t *= iD
    a, b = p["A"] * iD, p["B"] * iD                 # gu / (s D), gv / (s D)
    ru = a * x
    ru += p["cu"]
    ru -= c["pu"] * inv_s
    rv = b * y
    rv += p["cv"]
    rv -= c["pv"] * inv_s
    ux = (x * cx) * t
    np.subtract(1.0, ux, out=ux)
    ux *= a                                         # d ru / d x
    vy = (y * cy) * t
    np.subtract(1.0, vy, out=vy)
    vy *= b                                         # d rv / d y
    pm = (x * cy) * t
    nuy, nvx = a * pm, b * pm                       # -d ru / d y, -d rv / d x
    sx, sy = (wz * cx) * iT, (wz * cy) * iT           # wz dz/dx, wz dz/dy
    rx, ry = (x - c["ax"]) * wx, (y - c["ay"]) * wy
    rz = z - c["az"]
    rz *= wz
    g0 = g1 = C = None
    if grad:
        g0 = ux * ru - nvx * rv
        g1 = vy * rv - nuy * ru
        g0 += wx * rx + sx * rz
        g1 += wy * ry + sy * rz
    rr = None
    if last:
        rr = ru * ru
        rr += rv * rv
        rr += rx * rx + ry * ry + rz * rz
    if not (grad or keep_cp):
        return rr, C, g0, g1, None
    cp = (ux * ux + nvx * nvx, ux * nuy + nvx * vy, nuy * nuy + vy * vy)   # cp[1]: -Cp01
    cs = (wx * wx + sx * sx, sx * sy, wy * wy + sy * sy)
    if grad:
        C = (cp[0] + cs[0], cs[1] - cp[1], cp[2] + cs[2])
    return rr, C, g0, g1, (((cp[0], -cp[1], cp[2]), cs) if keep_cp else None)


def _fused_newton(p, c, x, y, w, n_iter, keep_cp):
    """The Gauss-Newton passes of :func:`marginal_sum`: at the last iterate ``(x, y)``, its
    residual at the mode ``m = |R|^2 - g^T C^-1 g``, ``det C``, the next step ``(d0, d1)``
    and (``keep_cp``) the pixel and scene parts of ``C``."""
    for it in range(n_iter + 1):
        last = it == n_iter
        rr, (C00, C01, C11), g0, g1, parts = _fused_terms(p, c, x, y, w, last,
                                                          last and keep_cp)
        det = C00 * C11
        det -= C01 * C01
        d0 = C11 * g0
        d0 -= C01 * g1
        d0 /= det
        d1 = C00 * g1
        d1 -= C01 * g0
        d1 /= det
        if not last:
            x, y = x - d0, y - d1
    m = g0 * d0
    m += g1 * d1
    np.subtract(rr, m, out=m)
    return {"x": x, "y": y, "m": m, "det": det, "d": (d0, d1), "parts": parts,
            "C": (C00, C01, C11)}


def outlier_probs(lik, psi, q0, n_iter):
    """:meth:`~bayescal.likelihood.points.LaserLikelihood.outlier_prob` (W, N) of the aligned
    cone in the fused passes of :func:`marginal_sum` (the same Gauss-Newton steps from
    ``q0`` (N, 2) or (W, N, 2), the same mixture); ``None`` where they do not apply
    (:func:`_fused_applies`) or without the mixture."""
    if not (getattr(lik, "outliers", False) and _fused_applies(lik, psi, q0)):
        return None
    return _fused_call(lik, psi, q0, n_iter, True)[0][3]


def _noise_setup(lik, theta, extra, sig):
    """Per-walker terms of the fused passes for ``theta`` (W, 7), ``extra`` (W, n_extra) and
    the pixel noise ``sig`` (W,): the walker factors ``p``, the points' columns ``c``, the
    scene weights ``w``, ``kappa`` (None unless inferred) and the squared noise scales (W,)
    of the Jeffreys point prior (pixel ``sp``, scene ``ss``)."""
    c, kappa = point_columns(lik), None
    if lik.infer_scene:
        kappa = np.exp(extra[:, int(lik.infer_px)])
        ws = 1.0 / (kappa[:, None] * lik.rho)
        w, ss = (ws, ws, ws), (kappa / lik.ref_kappa) ** 2
    else:
        w, ss = (c["wx"], c["wy"], c["wz"]), np.ones(len(theta))
    return {"p": _walker_terms(theta, sig), "c": c, "w": w, "kappa": kappa,
            "sp": (sig / lik.ref_sigma_px) ** 2, "ss": ss}


def marginal_sum(lik, theta, extra, sig, q0, n_iter, *, modes=False):
    """Sum over points of :meth:`~bayescal.likelihood.points.LaserLikelihood.laplace`'s
    per-point log marginals, shape (W,), for the aligned cone (:func:`marginal_block`):
    the same Gauss-Newton steps and terms, fused (the sampler's hot path). With ``modes``
    also the modes ``x, y`` (W, N) one step past the last iterate and the outlier
    probabilities (W, N) (None without the mixture), as the gradient needs them."""
    n = lik.n
    s = _noise_setup(lik, theta, extra, sig)
    c, p, w, sp, ss = s["c"], s["p"], s["w"], s["sp"], s["ss"]
    if lik.infer_scene:
        sum_log_w = -3.0 * (n * np.log(s["kappa"]) + c["log_rho"])
    else:
        sum_log_w = c["log_w"]
    flat = lik.point_prior == "flat"
    # Jeffreys prior at the sampled noise: |C|^(1/2) cancels the Laplace determinant
    cancel = not flat and np.all(sp == 1.0) and np.all(ss == 1.0)
    q0 = np.asarray(q0, dtype=float)
    g = _fused_newton(p, c, q0[..., 0], q0[..., 1], w, n_iter, not (cancel or flat))
    total = -0.5 * g["m"].sum(axis=-1)
    if not cancel:
        total -= 0.5 * np.log(g["det"]).sum(axis=-1)
    if not (flat or cancel):
        c00, c01, c11 = (a * sp[:, None] + b_ * ss[:, None]
                         for a, b_ in zip(*g["parts"], strict=True))
        total += 0.5 * np.log(c00 * c11 - c01 * c01).sum(axis=-1)
    total += (n - 0.5 * c["rows"]) * _LOG2PI + sum_log_w - 2.0 * n * np.log(sig)
    r = None
    if lik.outliers:
        mixed, r = _mix_sum(extra[:, -1], g["m"], lik._n_rows, lik.outlier_scale, modes)
        total += mixed
    if not modes:
        return total
    return total, g["x"] - g["d"][0], g["y"] - g["d"][1], r


def _mix_sum(logit_w, m, n_rows, scale, resp=False):
    """Sum over points of ``log((1 - w) + w L_out / L_in)``: the outlier mixture's share of
    the log marginal (:func:`~bayescal.likelihood.outliers.mix` with ``laplace=True``), from
    each point's residual ``m`` (W, N) at its mode; with ``resp`` the outlier probabilities
    ``w L_out / ((1 - w) L_in + w L_out)`` (W, N) too, else None."""
    delta = m * (0.5 * (1.0 - 1.0 / scale**2))
    delta += (2.0 - n_rows) * np.log(scale)
    r = expit(delta + logit_w[:, None]) if resp else None
    delta += log_expit(logit_w)[:, None]
    np.logaddexp(log_expit(-logit_w)[:, None], delta, out=delta)
    return delta.sum(axis=-1), r
