"""The high-breakdown start of the floor-plan least squares (``docs/robustness.md``, 4b).

:func:`robust_retry` looks at the solution :func:`bayescal.fit.floorplan._fit` chose and,
when it cannot be trusted - a parameter on the bound of its domain or far outside its
prior, an inferred pixel noise that disagrees with a robust scale of its own residuals or
exceeds :data:`~bayescal.fit.start.TRIMMED_NOISE_LIMIT` times its estimate from the
best-fitting 80 % of the points, or residuals far above a given noise - fits again from a
least-trimmed start (:func:`robust_solution`), the same retry as the per-point fit's
(:func:`bayescal.fit.em._robust_start`). Kept apart from :mod:`bayescal.fit.floorplan`
for size.
"""

from __future__ import annotations

import numpy as np

from ..checks.fit import fit_problems, robust_noise_ratio
from ..likelihood.outliers import NOISE_TRIM, trimmed_mean_square
from .start import ROBUST_KEEP, ROBUST_STEPS, TRIMMED_NOISE_LIMIT, trimmed_weights

__all__ = ["PlanRetry"]


class PlanRetry:
    """The floor-plan solver's robust retry; built by :mod:`bayescal.fit.floorplan` with its
    own steps (so that this module does not import it): ``solve``, ``finish``, ``e_step``,
    ``restore``, ``normal_equations`` and ``sensor`` are that module's ``_solve``,
    ``_finish``, ``_e_step``, ``_restore``, ``_normal_equations`` and ``_sensor``."""

    def __init__(self, **steps):
        self.__dict__.update(steps)

    def point_stats(self, lik, prior, g, t, sig):
        """Per-point squared whitened residuals (one degree of freedom each), unweighted."""
        weights, lik.em_weights = lik.em_weights, None
        try:
            with np.errstate(invalid="ignore", divide="ignore", over="ignore"):
                _, ne = self.normal_equations(lik, prior, g, t, sig)
        finally:
            lik.em_weights = weights
        m = np.sum(ne["R0"] ** 2, axis=1)
        return np.where(np.isfinite(m), m, np.inf)

    def problems(self, lik, prior, sol):
        """:func:`plan_problems` (the method the retry calls)."""
        return plan_problems(self, lik, prior, sol)

    def retry(self, lik, prior, best, max_iter):
        """:func:`robust_retry`."""
        return robust_retry(self, lik, prior, best, max_iter)


def plan_problems(ops, lik, prior, sol):
    """What makes a floor-plan solution untrustworthy (:func:`~bayescal.checks.fit.fit_problems`
    plus the trimmed-noise ratio when the noise is inferred); empty when it passes."""
    m = ops.point_stats(lik, prior, sol.g, sol.t, sol.sigma_px)
    ratio = robust_noise_ratio(m, 1)
    out = fit_problems(ops.sensor(lik, sol.g), prior,
                       noise_ratio=ratio if lik.infer_px else None,
                       given_ratio=None if lik.infer_px else ratio)
    if lik.infer_px:
        trimmed = np.sqrt(trimmed_mean_square(m, 1))        # its estimate / the level
        if 1.0 / trimmed > TRIMMED_NOISE_LIMIT:
            out.append(f"the inferred sigma_px is {1.0 / trimmed:.3g} times its estimate "
                       f"from the best-fitting {1 - NOISE_TRIM:.0%} of the points")
    return out


def robust_solution(ops, lik, prior, best, max_iter):
    """The EM from a least-trimmed start at ``best``: ``ROBUST_STEPS`` concentration steps,
    each keeping the ``ROBUST_KEEP`` best-fitting points (the rest weighted ``1/c^2``), the
    inferred noise at a robust scale of the residuals (first step: the median point's
    chi-square quantile; then the trimmed mean square); then the EM, its noise fitted to
    the start's inliers only. Returns the solution (as :func:`~.floorplan._finish`)."""
    ops.restore(lik, best)
    g, t, sig, n = best.g, best.t, best.sigma_px, lik.n
    for step in range(ROBUST_STEPS):
        m = ops.point_stats(lik, prior, g, t, sig)
        if lik.infer_px and step == 0:
            s = robust_noise_ratio(m, 1)
            sig, m = sig * s, m / s**2
        lik.em_weights = trimmed_weights(m, lik.outlier_scale)
        sol = ops.solve(lik, prior, g, t, sig, max_iter=max_iter)
        g, t = sol.g, sol.t
        if lik.infer_px:
            sig *= np.sqrt(trimmed_mean_square(np.sum(sol.ne["R0"] ** 2, axis=1), 1,
                                               keep=ROBUST_KEEP))
    lik.em_r = np.zeros(n)
    ops.e_step(lik, g, sig)
    sol = ops.finish(lik, prior, g, t, sig, max_iter, inliers=lik.em_r < 0.5)
    sol.robust = True
    return sol


def robust_retry(ops, lik, prior, best, max_iter):
    """``best``, or the robust start's solution when ``best`` cannot be trusted, the
    robust one can, and it passes the plan's checks (wall chi-square, flagged walls)
    wherever ``best`` did. Leaves ``lik`` in the chosen solution's state."""
    best.robust = False
    if not lik.outliers or not ops.problems(lik, prior, best):
        return best
    try:
        sol = robust_solution(ops, lik, prior, best, max_iter)
    except ValueError:                      # a step outside the model's domain
        ops.restore(lik, best)
        return best
    if not ops.problems(lik, prior, sol) and (sol.check["ok"] or not best.check["ok"]):
        return sol
    ops.restore(lik, best)
    return best
