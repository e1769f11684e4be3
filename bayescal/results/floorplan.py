"""The floor-plan least squares' result: plausibility checks and the CalibrationResult.

Split out of :mod:`bayescal.fit.floorplan` (which solves): :func:`check_solution` tests a
MAP against its plan and its pixel noise, :func:`make_result` turns a
:class:`~bayescal.fit.floorplan.PlanMapSolution` into a
:class:`~bayescal.results.calibration.CalibrationResult` (covariances, points, identifiability
and, with the outlier mixture, ``outlier_prob``).
"""

from __future__ import annotations

import numpy as np
from scipy import stats

from ..scene.floorplan import plan_point
from ..sensor.parameters import (
    IDENTIFIABLE_NAMES,
    PARAM_NAMES,
    SensorParams,
    from_identifiable,
    identifiable_jacobian,
)
from ..sensor.pose import POSE_NAMES, LaserPose
from .calibration import CalibrationResult, ConvergenceError, identifiability_report

__all__ = ["check_solution", "make_result", "plan_psi", "plan_log_evidence", "CHECK_P",
           "WALL_CHECK_P", "N_RESTARTS"]

#: p-value below which the MAP's pixel chi-square (pixel noise given) marks a wrong minimum:
#: restart (a mis-stated sigma_px is not a failed fit)
CHECK_P = 1e-6
#: p-value below which the MAP's wall-prior chi-square marks walls inconsistent with the
#: pixels: restart, and fail if no start passes. The statistic is at most chi-square(2W)
#: under the model, so a correct plan fails at most this often; 1e-6 let a wall drawn 30 %
#: too far in a 5000 mm room pass with the noise inferred (p = 2.6e-6, good points' error
#: x6.5: docs/robustness.md)
WALL_CHECK_P = 1e-4
#: restarts from sensor draws of the prior when the first solution fails its checks
N_RESTARTS = 4


def check_solution(lik, sol):
    """Plausibility of a MAP: walls against their plan, pixels against their noise.

    At the MAP the wall prior residuals ``z = (w - plan) / sd`` have variance
    ``1 - posterior var / prior var <= 1`` each, so ``sum z^2`` is at most a
    chi-square with 2W degrees of freedom; with the pixel noise given, the pixel
    chi-square has N (two rows, one azimuth per point); with the outlier mixture it
    is the EM-weighted one (an outlier's rows at ``1 / c^2``). A p-value below
    ``WALL_CHECK_P`` (walls) or ``CHECK_P`` (pixels) marks a wrong minimum (or a plan or
    noise inconsistent with the data); only the wall checks fail the calibration, the
    pixel one restarts it. With
    the mixture, a wall most of whose points are flagged as outliers fails too
    (:func:`_outlier_walls`).
    """
    z = (sol.g[lik.n_geo + 1:] - lik.plan.param_nominal) / lik.plan.param_sd
    wall_chi2 = float(z @ z)
    p_wall = float(stats.chi2.sf(wall_chi2, z.size))
    p_px = 1.0
    if not lik.infer_px:
        p_px = float(stats.chi2.sf(np.sum(sol.ne["R"] ** 2), lik.n))
    k = int(np.argmax(np.abs(z)))
    out = _outlier_walls(sol)
    return {"ok": p_wall > WALL_CHECK_P and p_px > CHECK_P and not out,
            "walls_ok": p_wall > WALL_CHECK_P, "wall_chi2": wall_chi2, "p_wall": p_wall,
            "p_pixels": p_px, "worst": (lik.plan.param_names[k], float(z[k])),
            "outlier_walls": out}


def _outlier_walls(sol, *, min_points=3, share=0.5):
    """Walls with most of their points flagged as outliers: ``[(wall, n_flagged, n_on)]``.

    The mixture can explain a wall drawn far from where it is by declaring its points
    outliers (measured: a wall 40 % too far, 12 of its 12 points flagged, the wall
    check then passing); a wall with at least ``min_points`` flagged points making
    more than ``share`` of its points is a wall-level error, not gross point errors.
    """
    em = getattr(sol, "em", None)
    if em is None:
        return []
    flagged = em[1] > 0.5
    on = np.bincount(sol.wall_index, minlength=1)
    n_out = np.bincount(sol.wall_index[flagged], minlength=len(on))
    bad = np.flatnonzero((n_out >= min_points) & (n_out > share * on))
    return [(int(k), int(n_out[k]), int(on[k])) for k in bad]


def make_result(lik, sol, absolute_sigma, raise_on_failure, prior=None):
    """The :class:`~bayescal.results.calibration.CalibrationResult` of a floor-plan MAP ``sol``
    (with ``prior``, the :class:`~bayescal.likelihood.priors.Prior` of the fit, its
    ``extras["log_evidence"]``: :func:`plan_log_evidence`)."""
    W, N, nt = lik.n_walls, lik.n, getattr(lik, "n_geo", 7)
    o = nt + 1                                  # g = (theta[, pose], phi, walls)
    g, sig = sol.g, sol.sigma_px
    theta, phi = g[:7], g[nt]
    R = sol.ne["R0"]
    # outliers (probability r) leave the noise statistics: each point counts 1 - r
    em = getattr(sol, "em", None)
    keep = np.ones(N) if em is None else 1.0 - em[1]
    chi2 = float(np.sum(keep * np.sum(R * R, axis=1)))
    n_res, n_unk = 2 * N, nt + 2 * W + N
    # plan rows carry the walls: one dof per point's pixel pair
    red = chi2 / max(float(np.sum(keep)), 1.0)
    scale = 1.0 if absolute_sigma else red
    cov = sol.cov * scale
    J = identifiable_jacobian(theta, phi)
    sub = np.r_[0:7, nt]                        # (theta, phi) without the pose
    cov8 = J @ cov[np.ix_(sub, sub)] @ J.T
    params = SensorParams.from_array(from_identifiable(theta, phi))
    noise = {"sigma_px": sig, "kappa": None}
    if em is not None:
        noise["outlier_frac"] = float(em[2])
    walls = g[o:].reshape(W, 2)
    points = plan_point(g[:nt], sol.t, walls[sol.wall_index, 0], walls[sol.wall_index, 1])
    result = CalibrationResult(
        method="simultaneous", params=params, points=points, covariance=0.5 * (cov8 + cov8.T),
        covariance_identifiable=cov[:nt, :nt],
        laser=LaserPose.from_array(g[7:nt], h=params.h) if nt > 7 else None,
        residual_rms={"pixel_px": float(np.sqrt(np.sum(keep[:, None] * (_raw(lik, R) * sig) ** 2)
                                                / max(2 * np.sum(keep), 1e-300)))},
        sigma_px_estimated=float(sig * np.sqrt(red)), n_residuals=n_res, n_unknowns=n_unk,
        converged=bool(sol.converged and np.all(np.isfinite(g))), message=sol.message,
        nfev=sol.nfev, identifiability=_identifiability(sol, nt, J),
        extras={"walls": walls.copy(), "wall_covariance": cov[o:, o:],
                "wall_names": lik.plan.param_names, "wall_index": sol.wall_index,
                "azimuths": sol.t, "point_covariance": _point_covariances(lik, sol) * scale,
                "map": sol, "noise": noise, "theta": g[:nt].copy(),
                "identifiable_names": IDENTIFIABLE_NAMES + POSE_NAMES[:nt - 7],
                "reduced_chi2": red,
                "floor_plan": lik.plan, "em_rounds": getattr(sol, "em_rounds", 1),
                "pixels": lik.pixels.copy(),
                "sigma_px": None if lik.sigma_px is None else float(lik.sigma_px),
                "pixel_cov": getattr(lik, "pixel_cov", None),
                "log_evidence": None if prior is None else plan_log_evidence(lik, prior, sol)},
        outlier_prob=None if em is None else em[1].copy())
    result.extras["check"] = sol.check
    if result.converged:
        _flag_failed_checks(result, sol.check, W)
    if not result.converged and raise_on_failure:
        raise ConvergenceError(f"floor-plan calibration did not converge: {result.message}",
                               result=result)
    return result


def plan_psi(lik, sol):
    """The collapsed sampler's globals at a floor-plan MAP and their Laplace covariance.

    Returns ``psi = (theta[, pose], walls flattened[, log sigma_px][, logit w])`` (phi
    left out), the covariance of its geometry and walls (the inverse Schur complement),
    and the number of those (the noise level and the outlier fraction after them are
    held at their fitted values).
    """
    nt = lik.n_geo
    keep = np.r_[0:nt, nt + 1:len(sol.g)]               # phi out
    extra = []
    if lik.infer_px:
        extra.append(np.log(sol.sigma_px))
    if lik.outliers:
        w = np.clip(sol.em[2], 1e-4, 0.5)
        extra.append(np.log(w / (1.0 - w)))
    return np.append(sol.g[keep], extra), sol.cov[np.ix_(keep, keep)], len(keep)


def plan_log_evidence(lik, prior, sol):
    """Laplace estimate of the log evidence of a floor-plan fit (``docs/model.md``, "Which
    model"): the collapsed log likelihood (azimuths integrated out) and the log prior at
    the MAP, plus ``(d/2) log 2 pi + log det(cov)/2`` of the d geometric and wall
    unknowns; noise level and outlier fraction held at their fitted values. Comparable
    between the aligned and misaligned fits of the same pixels and plan."""
    psi, cov, d = plan_psi(lik, sol)
    with np.errstate(invalid="ignore", divide="ignore"):
        value = (lik.laplace(psi)[0] + prior.logpdf_theta(psi[:7])
                 + lik.log_prior_extra(psi[7:]))
        sign, logdet = np.linalg.slogdet(cov)
    return float(value + 0.5 * d * np.log(2 * np.pi) + 0.5 * logdet) if sign > 0 else np.nan


def _identifiability(sol, nt, J):
    """What pixels and plan determine of the 8 paper parameters (and the pose): walls
    reduced out, sensor and pose priors left out; square-root rows in paper coordinates."""
    o, Jp = nt + 1, sol.ne["Jp"]
    info = sol.S.copy()
    info[:o, :o] -= Jp.T @ Jp
    info_t = info[:o, :o] - info[:o, o:] @ np.linalg.solve(info[o:, o:], info[o:, :o])
    e, V = np.linalg.eigh(0.5 * (info_t[:nt, :nt] + info_t[:nt, :nt].T))
    root = np.sqrt(np.clip(e, 0, None))[:, None] * V.T
    T = np.zeros((nt, nt + 1))                        # d geometry / d (paper, pose)
    T[:7, :8] = np.linalg.inv(J)[:7]
    T[7:, 8:] = np.eye(nt - 7)
    return identifiability_report(root @ T, PARAM_NAMES + POSE_NAMES[:nt - 7])


def _raw(lik, R):
    """Pixel residuals (N, 2) back in px / sigma_px: the per-point whitening undone."""
    if getattr(lik, "px_white", None) is None:
        return R
    a, b, c = lik.px_white.T
    rv = R[:, 1] / c
    return np.stack([(R[:, 0] - b * rv) / a, rv], axis=-1)


def _flag_failed_checks(result, chk, W):
    """Mark ``result`` unconverged, with the reason, if the walls failed their checks."""
    if not chk["walls_ok"]:
        result.converged = False
        result.message = (
            f"the walls of the best least-squares solution (of {N_RESTARTS + 1} starts) are "
            f"far off the plan: wall chi-square {chk['wall_chi2']:.1f} on {2 * W} degrees of "
            f"freedom (p = {chk['p_wall']:.2g}), worst {chk['worst'][0]} at "
            f"{chk['worst'][1]:+.1f} prior sd; a local minimum, or a plan (or its sds) "
            f"inconsistent with the pixels")
    elif chk.get("outlier_walls"):
        k, n_out, n_on = chk["outlier_walls"][0]
        result.converged = False
        result.message = (
            f"{n_out} of the {n_on} points on wall {k} are flagged as outliers (probability "
            f"> 0.5): the plan's wall {k} is likely wrong (a wall-level error, which the "
            f"per-point outlier mixture cannot absorb honestly); check the plan, or refit with "
            f"outliers=False to see its wall chi-square")


def _point_covariances(lik, sol):
    """3x3 Laplace covariance of each point (azimuth, sensor and wall uncertainty)."""
    W, N, nt = lik.n_walls, lik.n, getattr(lik, "n_geo", 7)
    g, t, cov, ne = sol.g, sol.t, sol.cov, sol.ne
    k, o = sol.wall_index, nt + 1
    walls = g[o:].reshape(W, 2)
    _, dPt, dPth, dPw = plan_point(g[:nt], t, walls[k, 0], walls[k, 1], jacobian=True)
    idx = np.arange(N)
    Gg = np.zeros((N, 3, o + 2 * W))
    Gg[:, :, :nt] = dPth
    Gg[idx, :, o + 2 * k] = dPw[:, :, 0]
    Gg[idx, :, o + 1 + 2 * k] = dPw[:, :, 1]
    B, C = ne["B"], ne["C"]
    K = -np.einsum("ij,nj->ni", cov, B) / C[:, None]              # cov(g, t_i): (N, G)
    var_t = 1.0 / C + np.einsum("ni,ij,nj->n", B, cov, B) / C**2
    GK = np.einsum("nai,ni->na", Gg, K)                            # (N, 3)
    return (var_t[:, None, None] * dPt[:, :, None] * dPt[:, None, :]
            + dPt[:, :, None] * GK[:, None, :] + GK[:, :, None] * dPt[:, None, :]
            + np.einsum("nai,ij,nbj->nab", Gg, cov, Gg))
