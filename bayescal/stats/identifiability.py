"""Identifiability: which parameter combinations a Jacobian cannot determine.

:func:`identifiability_report` analyses a whitened Jacobian by its singular
values; :func:`covariance_8_from_identifiable` turns the covariance of the seven
identifiable combinations into one of the eight paper parameters (``phi`` is
never seen by the data, ``docs/model.md``, "Identifiability").
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .._validation import as_finite_array
from ..errors import InvalidValueError
from ..sensor.parameters import identifiable_jacobian

__all__ = [
    "IdentifiabilityReport",
    "identifiability_report",
    "covariance_8_from_identifiable",
    "identifiable_to_paper_jacobian",
    "prior_dominated",
    "PRIOR_DOMINATED_RATIO",
    "RIDGE_NAMES",
]

_MIN_WEIGHT = 0.05
#: the exact phi/alpha ridge: the data see these only through gamma = alpha (xi + phi)
#: (docs/model.md, fact 1), whatever their posterior, the priors decide them
RIDGE_NAMES = ("phi", "alpha_u", "alpha_v")
#: a parameter is prior-dominated when its sd exceeds this fraction of its prior sd (the data
#: did not even halve the prior's spread)
PRIOR_DOMINATED_RATIO = 0.5


def prior_dominated(name, sd_ratio=None, null_directions=()):
    """Whether a parameter's value is the priors', not the data's: the rule of every result
    and report.

    ``phi``, ``alpha_u``, ``alpha_v`` always (:data:`RIDGE_NAMES`); any other when its sd over
    its prior sd (``sd_ratio``) exceeds :data:`PRIOR_DOMINATED_RATIO`; without a finite ratio
    (no prior: the sequential method), when it has a weight of at least 0.05 in one of
    ``null_directions`` (:attr:`IdentifiabilityReport.null_directions`). With a prior, a
    near-null direction of the data alone does not flag a parameter: the priors of the
    others in it may still pin it down (its ratio says whether they do).
    """
    if name in RIDGE_NAMES:
        return True
    if sd_ratio is not None and np.isfinite(sd_ratio):
        return bool(sd_ratio > PRIOR_DOMINATED_RATIO)
    return any(name in nd.get("components", {}) for nd in null_directions or ())


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
        raise InvalidValueError(f"jacobian must have shape (n_residuals, n_params), got {J.shape}")
    names = tuple(str(n) for n in names)
    if len(names) != J.shape[1]:
        raise InvalidValueError(f"names must have one entry per jacobian column ({J.shape[1]}), "
                                f"got {len(names)}")
    if not (np.isfinite(rtol) and 0 < rtol < 1):
        raise InvalidValueError(f"rtol must lie in (0, 1), got {rtol!r}")
    if scale is None:
        scale = np.linalg.norm(J, axis=0)
    else:
        scale = as_finite_array(scale, "scale")
        if scale.shape != (J.shape[1],):
            raise InvalidValueError(f"scale must have shape ({J.shape[1]},), got {scale.shape}")
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
        raise InvalidValueError(f"theta must have shape (7,), got {theta.shape}")
    cov7 = as_finite_array(cov7, "cov7", allow_nan=True)
    if cov7.shape != (7, 7):
        raise InvalidValueError(f"cov7 must have shape (7, 7), got {cov7.shape}")
    var_phi = float(var_phi)
    if not var_phi >= 0:
        raise InvalidValueError(f"var_phi must be a non-negative variance, got {var_phi!r}")
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
