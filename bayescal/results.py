"""The result type of the classical calibrations and the identifiability report.

Both least-squares methods (:func:`~bayescal.calibrate_sequential` and the
simultaneous method) return a :class:`CalibrationResult`: the eight paper
parameters, their covariance (8x8, order :data:`~bayescal.PARAM_NAMES`) and the
covariance of the seven identifiable combinations (7x7, order
:data:`~bayescal.IDENTIFIABLE_NAMES`), residual statistics, convergence
information and an :class:`IdentifiabilityReport`.

The data never determine ``phi`` (DESIGN fact 1: ``phi``, ``alpha_u`` and
``alpha_v`` enter the model only through ``gamma_u = alpha_u (xi + phi)`` and
``gamma_v = alpha_v (xi + phi)``). The 8x8 covariance is therefore built from
the 7x7 identifiable one plus a variance for ``phi`` that the *method* chooses
(0 when ``phi`` is held fixed, a prior variance otherwise), see
:func:`covariance_8_from_identifiable`.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from ._validation import as_finite_array
from .parameters import IDENTIFIABLE_NAMES, PARAM_NAMES, SensorParams, identifiable_jacobian

__all__ = [
    "IdentifiabilityReport",
    "identifiability_report",
    "CalibrationResult",
    "ConvergenceError",
    "covariance_8_from_identifiable",
    "identifiable_to_paper_jacobian",
]

_MIN_WEIGHT = 0.05


@dataclass
class IdentifiabilityReport:
    """Singular-value analysis of a (column-scaled) Jacobian.

    Attributes
    ----------
    names : tuple of str
        Column names of the Jacobian analysed, length P.
    singular_values : ndarray, shape (P,)
        Singular values of the column-scaled Jacobian, descending.
    condition_number : float
        ``s_max / s_min`` (``inf`` if ``s_min == 0``).
    null_directions : list of dict
        One entry per singular value ``s < rtol * s_max``, each
        ``{"singular_value": s, "components": {name: weight}}``: the weights of
        the unit right-singular vector (in scaled coordinates) with
        ``|weight| >= 0.05``, largest first. These are the parameter
        combinations the data cannot determine.
    rtol : float
        Relative threshold used.
    """

    names: tuple
    singular_values: np.ndarray
    condition_number: float
    null_directions: list
    rtol: float = 1e-6

    def __str__(self) -> str:
        lines = [f"identifiability of {len(self.names)} columns: "
                 f"condition number {self.condition_number:.3g}"]
        if not self.null_directions:
            lines.append(f"no near-null direction (all s >= {self.rtol:g} * s_max)")
        for k, nd in enumerate(self.null_directions, 1):
            comps = ", ".join(f"{w:+.3f} {n}" for n, w in nd["components"].items())
            lines.append(f"near-null direction {k} (s = {nd['singular_value']:.3g}): {comps}")
            lines.append("  not determined by the data: "
                         + ", ".join(nd["components"].keys()))
        return "\n".join(lines)


def identifiability_report(jacobian, names, *, scale=None, rtol=1e-6):
    """Find the parameter combinations a Jacobian cannot determine.

    Parameters
    ----------
    jacobian : array_like, shape (n_residuals, n_params)
        Jacobian of the *whitened* residuals (each residual divided by its
        standard deviation) with respect to the parameters.
    names : sequence of str, length n_params
        Parameter (column) names.
    scale : array_like, shape (n_params,), optional
        Typical magnitude of each column; each column is divided by it before
        the SVD so that units do not decide the answer. Default: the column
        norms (every scaled column has unit norm). A zero scale leaves its
        column unscaled (an all-zero column is reported as a null direction).
    rtol : float, optional
        Singular values below ``rtol * s_max`` are near-null directions.

    Returns
    -------
    IdentifiabilityReport

    Examples
    --------
    >>> import numpy as np
    >>> J = np.array([[1.0, 2.0], [2.0, 4.0]])      # second column = 2 x first
    >>> rep = identifiability_report(J, ["a", "b"])
    >>> sorted(rep.null_directions[0]["components"])
    ['a', 'b']
    """
    J = as_finite_array(jacobian, "jacobian")
    if J.ndim != 2:
        raise ValueError(f"jacobian must have shape (n_residuals, n_params), got {J.shape}")
    names = tuple(str(n) for n in names)
    if len(names) != J.shape[1]:
        raise ValueError(f"names must have one entry per jacobian column ({J.shape[1]}), "
                         f"got {len(names)}")
    if not (np.isfinite(rtol) and 0 < rtol < 1):
        raise ValueError(f"rtol must lie in (0, 1), got {rtol!r}")
    if scale is None:
        scale = np.linalg.norm(J, axis=0)
    else:
        scale = as_finite_array(scale, "scale")
        if scale.shape != (J.shape[1],):
            raise ValueError(f"scale must have shape ({J.shape[1]},), got {scale.shape}")
    scale = np.where(scale == 0, 1.0, np.abs(scale))
    Js = J / scale
    # thin SVD unless there are fewer residuals than columns (then all of V is needed)
    _, s, vt = np.linalg.svd(Js, full_matrices=J.shape[0] < J.shape[1])
    sv = np.zeros(J.shape[1])
    sv[: s.size] = s                      # fewer residuals than columns: missing s are 0
    smax = sv[0] if sv.size else 0.0
    cond = float(smax / sv[-1]) if sv.size and sv[-1] > 0 else float("inf")
    null = []
    for k in range(sv.size):
        if sv[k] < rtol * smax or smax == 0:
            v = vt[k]
            v = v * np.sign(v[np.argmax(np.abs(v))])     # largest weight positive
            order = np.argsort(-np.abs(v))
            comps = {names[i]: float(v[i]) for i in order if abs(v[i]) >= _MIN_WEIGHT}
            null.append({"singular_value": float(sv[k]), "components": comps})
    return IdentifiabilityReport(names=names, singular_values=sv, condition_number=cond,
                                 null_directions=null, rtol=float(rtol))


def identifiable_to_paper_jacobian(params):
    """Jacobian ``d theta / d a`` of the identifiable coordinates w.r.t. the paper's.

    Parameters
    ----------
    params : SensorParams

    Returns
    -------
    ndarray, shape (7, 8)
        Rows :data:`~bayescal.IDENTIFIABLE_NAMES`, columns
        :data:`~bayescal.PARAM_NAMES`. A Jacobian ``J7`` with respect to theta
        becomes ``J7 @ identifiable_to_paper_jacobian(params)`` with respect to
        the eight paper parameters (its phi/alpha direction is then exactly null).
    """
    theta = params.to_identifiable()
    return np.linalg.inv(identifiable_jacobian(theta, params.phi))[:7]


def covariance_8_from_identifiable(theta, phi, cov7, var_phi):
    """Covariance of the eight paper parameters from the identifiable one.

    ``J @ blockdiag(cov7, var_phi) @ J.T`` with ``J = identifiable_jacobian(theta, phi)``
    (first order). ``phi`` is independent of theta: the data say nothing about it.

    Parameters
    ----------
    theta : array_like, shape (7,)
        Identifiable parameters ``(xi, gamma_u, gamma_v, u0, v0, h, beta)``.
    phi : float
        Value of ``phi`` the paper parameters are reported at.
    cov7 : array_like, shape (7, 7)
        Covariance of theta (order :data:`~bayescal.IDENTIFIABLE_NAMES`).
    var_phi : float
        Variance of ``phi``: 0 when ``phi`` is held fixed, its prior variance
        otherwise.

    Returns
    -------
    ndarray, shape (8, 8)
        Order :data:`~bayescal.PARAM_NAMES`.
    """
    theta = as_finite_array(theta, "theta")
    if theta.shape != (7,):
        raise ValueError(f"theta must have shape (7,), got {theta.shape}")
    cov7 = as_finite_array(cov7, "cov7", allow_nan=True)
    if cov7.shape != (7, 7):
        raise ValueError(f"cov7 must have shape (7, 7), got {cov7.shape}")
    var_phi = float(var_phi)
    if not var_phi >= 0:
        raise ValueError(f"var_phi must be a non-negative variance, got {var_phi!r}")
    C = np.zeros((8, 8))
    C[:7, :7] = cov7
    C[7, 7] = var_phi
    J = identifiable_jacobian(theta, phi)
    out = J @ np.nan_to_num(C) @ J.T
    # a NaN variance (parameter not estimated) stays confined to the outputs depending on it
    nan_in = np.isnan(np.diag(C))
    nan_out = np.any((J != 0) & nan_in[None, :], axis=1)
    out[nan_out, :] = np.nan
    out[:, nan_out] = np.nan
    return out


class ConvergenceError(RuntimeError):
    """A calibration did not converge; ``.result`` holds the flagged result.

    Attributes
    ----------
    result : CalibrationResult
        The result at the last iterate, with ``converged=False``.
    """

    def __init__(self, message, result=None):
        super().__init__(message)
        self.result = result


@dataclass
class CalibrationResult:
    """Result of a least-squares calibration (sequential or simultaneous).

    Attributes
    ----------
    method : str
        ``"sequential"`` or ``"simultaneous"``.
    params : SensorParams
        Estimated parameters (``phi`` as fixed or as given by its prior).
    points : ndarray, shape (N, 3) or None
        Reconstructed laser points in frame C, mm (None if the method was
        given no room pixels).
    covariance : ndarray, shape (8, 8)
        Covariance of the paper parameters, order :data:`~bayescal.PARAM_NAMES`.
        NaN rows/columns mark parameters the method did not estimate.
    covariance_identifiable : ndarray, shape (7, 7)
        Covariance of ``(xi, gamma_u, gamma_v, u0, v0, h, beta)``.
    residual_rms : dict
        RMS of each kind of residual, e.g. ``{"pixel_px": ..., "cone_mm": ...}``.
    sigma_px_estimated : float or None
        Pixel noise estimated from the pixel residuals,
        ``RMS / sqrt(1 - n_unknowns / n_residuals)`` over the pixel fit.
    n_residuals, n_unknowns : int
        Number of scalar residuals and of unknowns solved for (all stages).
    converged : bool
    message : str
    nfev : int
        Residual evaluations (all stages).
    identifiability : IdentifiabilityReport
    extras : dict
        Method-specific outputs (pose, planes, per-stage statistics).
    outlier_prob : ndarray, shape (N,) or None
        Probability that each input point (pixel and approximate point) is an
        outlier, from the outlier mixture (``docs/robustness.md``); None when
        the method has no outlier model.
    """

    method: str
    params: SensorParams
    points: np.ndarray | None
    covariance: np.ndarray
    covariance_identifiable: np.ndarray
    residual_rms: dict
    sigma_px_estimated: float | None
    n_residuals: int
    n_unknowns: int
    converged: bool
    message: str
    nfev: int
    identifiability: IdentifiabilityReport
    extras: dict = field(default_factory=dict)
    outlier_prob: np.ndarray | None = None

    @property
    def std(self) -> np.ndarray:
        """Standard deviations of the eight parameters, shape (8,) (NaN if not estimated)."""
        with np.errstate(invalid="ignore"):
            return np.sqrt(np.diag(self.covariance))

    @property
    def correlation(self) -> np.ndarray:
        """Correlation matrix, shape (8, 8); NaN rows/columns where the variance is 0 or NaN."""
        sd = self.std
        with np.errstate(divide="ignore", invalid="ignore"):
            sd = np.where(sd > 0, sd, np.nan)
            return self.covariance / np.outer(sd, sd)

    def summary(self) -> str:
        """Readable table: name, value, standard deviation; residuals; convergence; report."""
        sd = self.std
        lines = [f"{self.method} calibration: "
                 + ("converged" if self.converged else "NOT CONVERGED")
                 + f" ({self.message}; {self.nfev} evaluations)",
                 f"{'parameter':<10} {'value':>14} {'sd':>12}"]
        for name, val, s in zip(PARAM_NAMES, self.params.to_array(), sd, strict=True):
            s_txt = "not estimated" if np.isnan(s) else ("fixed" if s == 0 else f"{s:.4g}")
            lines.append(f"{name:<10} {val:>14.6g} {s_txt:>12}")
        sd7 = np.sqrt(np.maximum(np.diag(self.covariance_identifiable), 0))
        lines.append("identifiable: " + ", ".join(
            f"{n} = {v:.6g} +- {s:.3g}"
            for n, v, s in zip(IDENTIFIABLE_NAMES, self.params.to_identifiable(), sd7,
                               strict=True)))
        lines.append("residual RMS: " + ", ".join(f"{k} = {v:.4g}"
                                                    for k, v in self.residual_rms.items()))
        if self.sigma_px_estimated is not None:
            lines.append(f"estimated pixel noise: {self.sigma_px_estimated:.4g} px "
                         f"({self.n_residuals} residuals, {self.n_unknowns} unknowns)")
        if self.outlier_prob is not None:
            flagged = np.flatnonzero(self.outlier_prob > 0.5)
            lines.append(f"outliers (probability > 0.5): {flagged.size} of "
                         f"{self.outlier_prob.size}"
                         + (f", rows {', '.join(map(str, flagged[:20]))}"
                            + (" ..." if flagged.size > 20 else "") if flagged.size else ""))
        lines.append(str(self.identifiability))
        return "\n".join(lines)
