"""The simultaneous method with the laser points taken as exact
(``calibrate_simultaneous(..., estimate_points=False)``): the pixel rows of eq. (1) and
the cone fitted through the given points, seven identifiable unknowns."""

from __future__ import annotations

import numpy as np

from ..errors import InvalidValueError
from ..results.calibration import (
    CalibrationResult,
    ConvergenceError,
    covariance_8_from_identifiable,
    identifiability_report,
)
from ..sensor.parameters import (
    PARAM_NAMES,
    SensorParams,
    from_identifiable,
    identifiable_jacobian,
    to_identifiable,
)

__all__ = ["calibrate_fixed_points"]


def calibrate_fixed_points(lik, prior, init, absolute_sigma, raise_on_failure):
    """Points taken as exact: pixel rows of eq. (1) and the cone through the points."""
    from scipy.optimize import least_squares

    from ..sensor.camera import project_theta
    from ..sensor.laser import triangulate_theta

    if lik.infer_px or lik.infer_scene:
        raise InvalidValueError(
            "estimate_points=False needs sigma_px and sigma_scene given (not None)")
    sig = lik.sigma_px
    P = lik.approx
    phi = float(prior.dists["phi"].mean())
    # scene sd along the cone normal, per point
    rho = np.hypot(P[:, 0], P[:, 1])

    def fun(t):
        uv, _ = project_theta(t, P)
        b = t[6]
        nrm = np.stack([np.cos(b) * P[:, 0] / rho, np.cos(b) * P[:, 1] / rho,
                        np.full(len(P), -np.sin(b))], -1)
        with np.errstate(divide="ignore"):
            var_n = np.sum(nrm**2 / lik.w_scene**2, axis=1)       # inf where an axis is blind
        s_n = 1.0 / np.sqrt(var_n)
        dist = rho * np.cos(b) - (P[:, 2] + t[5]) * np.sin(b)
        rp = prior.residuals(from_identifiable(t, phi))
        return np.concatenate([((uv - lik.pixels) / sig).ravel(), dist * s_n, rp])

    t0 = to_identifiable(init.to_array())
    opt = least_squares(fun, t0, x_scale="jac", method="lm", xtol=1e-12, ftol=1e-12)
    J = opt.jac
    data_rows = opt.fun[:-8]                          # the last 8 rows are the priors
    n_res, n_unk = len(data_rows), 7
    red = float(data_rows @ data_rows) / max(n_res - n_unk, 1)
    cov7 = np.linalg.inv(J.T @ J) * (1.0 if absolute_sigma else red)
    cov8 = covariance_8_from_identifiable(opt.x, phi, cov7, float(prior.dists["phi"].var()))
    params = SensorParams.from_array(from_identifiable(opt.x, phi))
    pts, _ = triangulate_theta(opt.x, lik.pixels)
    uv, _ = project_theta(opt.x, P)
    dtheta_da = np.linalg.inv(identifiable_jacobian(opt.x, phi))[:7]
    result = CalibrationResult(
        method="simultaneous", params=params, points=pts, covariance=cov8,
        covariance_identifiable=cov7,
        residual_rms={"pixel_px": float(np.sqrt(np.mean((uv - lik.pixels) ** 2)))},
        sigma_px_estimated=float(sig * np.sqrt(red)), n_residuals=n_res, n_unknowns=n_unk,
        converged=bool(opt.success), message=str(opt.message), nfev=int(opt.nfev),
        identifiability=identifiability_report(J @ dtheta_da, PARAM_NAMES),
        extras={"theta": opt.x, "reduced_chi2": red})
    if not result.converged and raise_on_failure:
        raise ConvergenceError(f"simultaneous calibration did not converge: {opt.message}",
                               result=result)
    return result
