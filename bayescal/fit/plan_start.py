"""The floor-plan least squares as the start of the collapsed sampler.

:func:`plan_map_start` runs :mod:`bayescal.fit.floorplan`'s MAP and turns it into the
sampler's start (the globals ``psi``, their Laplace covariance, the point azimuths) with
the :class:`~bayescal.likelihood.floorplan.PlanLikelihood` to sample; kept apart from
:mod:`bayescal.fit.floorplan` for size.
"""

from __future__ import annotations

import numpy as np

from ..likelihood.outliers import OUTLIER_PRIOR, OUTLIER_SCALE
from ..results.floorplan import make_result, plan_psi
from .floorplan import _fit
from .plan_runs import note_runs

__all__ = ["plan_map_start"]


def plan_map_start(pixels, plan, *, sigma_px, prior=None, init=None, absolute_sigma=True,
                   max_iter=200, raise_on_failure=True, outliers=True,
                   outlier_scale=OUTLIER_SCALE, outlier_prior=OUTLIER_PRIOR, pixel_cov=None,
                   model="aligned"):
    """MAP start for the collapsed sampler (internal); parameters as
    :func:`~bayescal.fit.floorplan.calibrate_plan`.

    Returns
    -------
    psi_map : ndarray, shape (n_geo + 2W [+ 1] [+ 1],)
        ``(theta[, pose], walls flattened[, log sigma_px][, logit w])`` (the laser pose's
        four numbers with ``model="misaligned"``).
    cov_psi : ndarray, same square shape
        Laplace covariance (phi marginalised; ``log sigma_px`` given variance
        ``1 / (2N)``, ``logit w`` variance 1 (about the Beta(1, 19) prior's
        spread), both uncorrelated).
    q_map : ndarray, shape (N, 1)
        Point azimuths at the MAP, rad.
    result : CalibrationResult
        ``result.extras["likelihood"]`` is the :class:`PlanLikelihood` to sample,
        with its candidate walls and reference noise set at the MAP.
    """
    lik, prior, sol = _fit(pixels, plan, sigma_px=sigma_px, prior=prior, init=init,
                           max_iter=max_iter, outliers=outliers, outlier_scale=outlier_scale,
                           outlier_prior=outlier_prior, pixel_cov=pixel_cov, model=model)
    res = make_result(lik, sol, absolute_sigma, raise_on_failure, prior=prior)
    res.extras["robust_start"] = bool(getattr(sol, "robust", False))
    note_runs(res, sol)                     # a block off the plan: warned, in res.extras
    res.extras["likelihood"] = lik
    # typical horizontal range of the laser points: where a finite-range ring radius would
    # straighten the sampler's (xi, gamma, h, beta) ridge (docs/floorplan.md section 8)
    lik.reference_range = float(np.median(np.hypot(res.points[:, 0], res.points[:, 1])))
    psi, cov_g, d = plan_psi(lik, sol)
    var = ([1.0 / (2 * lik.n)] if lik.infer_px else []) + ([1.0] if lik.outliers else [])
    cov = np.diag(np.r_[np.zeros(d), var])
    cov[:d, :d] = cov_g
    _restrict_pieces(lik, psi, cov)
    return psi, cov, sol.t[:, None], res


def _restrict_pieces(lik, psi, cov, *, n_draws=200, spread=3.0):
    """Skip the other wall's piece for points far from their corner (half the cost).

    The points kept with both pieces are those whose other piece matters anywhere in
    ``n_draws`` draws of the Laplace Gaussian widened ``spread`` times (far beyond
    the posterior's reach), deterministic (seeded) so that a run is reproducible.
    """
    rng = np.random.default_rng(0)
    try:
        L = np.linalg.cholesky(cov)
    except np.linalg.LinAlgError:
        return                                          # keep both pieces everywhere
    draws = psi + spread * rng.standard_normal((n_draws, len(psi))) @ L.T
    lik.restrict_pieces(np.vstack([psi, draws]))
