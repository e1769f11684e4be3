"""Least squares on a floor plan: MAP and Laplace covariance of sensor and walls.

Unknowns: ``g = (theta (7), phi, d_0, a_0, ..., d_{W-1}, a_{W-1})`` and one azimuth ``t_i``
per laser point; rows: two whitened pixel residuals per point
(:class:`~bayescal.likelihood.floorplan.PlanLikelihood`), the eight sensor prior rows
(:class:`~bayescal.likelihood.priors.Prior`, ``phi`` seen by its prior only, as in the per-point
method) and ``2W`` wall prior rows; misaligned, ``g = (theta, pose (4), phi, walls)`` and four
pose rows (:class:`~bayescal.likelihood.plan_misaligned.MisalignedPlanLikelihood`).
Levenberg-Marquardt with the azimuths eliminated by a Schur complement: O(N) per iteration.

Each point's wall is re-decided at every iteration from its azimuth and the current corner
azimuths (the cost is continuous across a corner: both walls meet there). With the Jeffreys
point prior and a one-dimensional latent, the maximum over ``(g, t)`` is also the maximum of
the collapsed posterior the sampler explores; the inverse Schur complement is its Laplace
covariance.
"""

from __future__ import annotations

import numpy as np

from ..checks.fit import flag_untrusted
from ..errors import InvalidTypeError, InvalidValueError
from ..likelihood.outliers import (
    OUTLIER_PRIOR,
    OUTLIER_SCALE,
    annealed_outlier_prob,
    em_update,
    trimmed_mean_square,
)
from ..likelihood.plan_misaligned import plan_likelihood
from ..likelihood.point_algebra import whiten
from ..likelihood.priors import Prior
from ..results.calibration import ConvergenceError
from ..results.floorplan import CHECK_P, N_RESTARTS, check_solution, make_result
from ..scene.corners import candidate_walls, shallow_corners
from ..scene.floorplan import FloorPlan, corner_azimuths, wrap_angle
from ..sensor.laser import triangulate_geo
from ..sensor.parameters import (
    SensorParams,
    from_identifiable,
    to_identifiable,
)
from ..sensor.pose import POSE_NAMES
from .plan_robust import PlanRetry
from .plan_runs import PlanRuns, note_runs
from .schur import _prior_rows, damped_step, safe_inv

__all__ = ["calibrate_plan", "PlanMapSolution", "CHECK_P", "N_RESTARTS", "RING_CORR_DEG",
           "normal_sensitivity", "ring_corr_cov"]
RING_CORR_DEG = 1.0     #: the extractor's error correlation scale, deg (docs/floorplan.md)


class PlanMapSolution:
    """Raw MAP of the floor-plan least squares (internal; users get a CalibrationResult).

    Attributes
    ----------
    g : ndarray, shape (n_geo + 1 + 2W,)
        ``(theta[, pose], phi, walls flattened)`` at the MAP (``n_geo`` 7, or 11 with a pose).
    t : ndarray, shape (N,)
        Point azimuths, rad.
    wall_index : ndarray of int, shape (N,)
    cov : ndarray, shape (n_geo + 1 + 2W,) * 2
        Laplace covariance of ``g`` (inverse Schur complement).
    """

    def __init__(self, **kw):
        self.__dict__.update(kw)


def _normal_equations(lik, prior, g, t, sig):
    W, N, nt = lik.n_walls, lik.n, lik.n_geo
    o = nt + 1                              # the walls' offset in g
    G = o + 2 * W
    theta, walls = g[:nt], g[o:].reshape(W, 2)
    k = lik.hard_wall_index(walls, t)
    R, Jth, Jw, Jt = lik.residuals(theta, walls, t, k, sig, jacobian=True)
    R0 = R
    if lik.em_weights is not None:           # EM M-step: each point's rows weighted
        s = np.sqrt(lik.em_weights)
        R, Jth, Jw, Jt = R * s[:, None], Jth * s[:, None, None], Jw * s[:, None, None], \
            Jt * s[:, None]
    idx = np.arange(N)
    Jg = np.zeros((N, 2, G))
    Jg[:, :, :nt] = Jth
    Jg[idx, :, o + 2 * k] = Jw[:, :, 0]
    Jg[idx, :, o + 1 + 2 * k] = Jw[:, :, 1]
    rp, Jp = _prior_rows(prior, g[:o])      # sensor (and pose) prior rows in (theta, phi)
    rw = (g[o:] - lik.plan.param_nominal) / lik.plan.param_sd
    A = np.einsum("nki,nkj->ij", Jg, Jg)
    A[:o, :o] += Jp.T @ Jp
    A[o:, o:] += np.diag(1.0 / lik.plan.param_sd**2)
    B = np.einsum("nki,nk->ni", Jg, Jt)
    C = np.einsum("nk,nk->n", Jt, Jt)
    gg = np.einsum("nki,nk->i", Jg, R)
    gg[:o] += Jp.T @ rp
    gg[o:] += rw / lik.plan.param_sd
    gt = np.einsum("nk,nk->n", Jt, R)
    cost = 0.5 * (np.sum(R * R) + rp @ rp + rw @ rw)
    return cost, dict(A=A, B=B, C=C, gg=gg, gt=gt, R=R, R0=R0, k=k, Jp=Jp, Jg=Jg, Jt=Jt)


def _cost(lik, prior, g, t, sig):
    W, nt = lik.n_walls, lik.n_geo
    walls = g[nt + 1:].reshape(W, 2)
    # outside the physical domain (walls behind the axis, h <= 0, beta outside (0, pi/2), xi < 0,
    # xi + phi <= 0): not a step to take
    if (np.any(walls[:, 0] <= 0) or g[5] <= 0 or not 0 < g[6] < np.pi / 2
            or g[0] < 0 or g[0] + g[nt] <= 0):
        return np.inf
    R = lik.residuals(g[:nt], walls, t, lik.hard_wall_index(walls, t), sig)
    if lik.em_weights is not None:
        R = R * np.sqrt(lik.em_weights)[:, None]
    rp = _prior_rows(prior, g[:nt + 1], jacobian=False)
    rw = (g[nt + 1:] - lik.plan.param_nominal) / lik.plan.param_sd
    c = 0.5 * (np.sum(R * R) + rp @ rp + rw @ rw)
    return c if np.isfinite(c) else np.inf


def _schur(ne, lam=0.0):
    """Damped Schur complement of the azimuths; returns S, the step solver."""
    A, B, C = ne["A"], ne["B"], ne["C"]
    Ad = A + lam * np.diag(np.diag(A))
    Cd = C * (1.0 + lam)
    S = Ad - np.einsum("ni,nj,n->ij", B, B, 1.0 / Cd)
    return S, Cd


def _step(ne, lam, free=None):
    S, Cd = _schur(ne, lam)
    rhs = -(ne["gg"] - np.einsum("ni,n->i", ne["B"], ne["gt"] / Cd))
    if free is None:
        dg = np.linalg.solve(S, rhs)
    else:                               # held parameters: their rows and columns dropped
        dg = np.zeros_like(rhs)
        dg[free] = np.linalg.solve(S[np.ix_(free, free)], rhs[free])
    dt = -(ne["gt"] + ne["B"] @ dg) / Cd
    return dg, dt


def _solve(lik, prior, g, t, sig, *, max_iter=200, ftol=1e-12, xtol=1e-10, free=None):
    """Levenberg-Marquardt on (g, t) at fixed pixel noise; returns a PlanMapSolution.

    ``free`` (bool, shape (n_geo + 1 + 2W,)) holds the other entries of ``g`` at their start.
    """
    lam, nfev, converged, message = 1e-3, 1, False, "maximum number of iterations reached"
    cost, ne = _normal_equations(lik, prior, g, t, sig)
    if not np.isfinite(cost):
        raise InvalidValueError("the starting point puts some laser points outside the model's "
                                "domain (non-finite residuals); give a better init or plan")
    n_done = 0
    for n_done in range(1, max_iter + 1):  # noqa: B007 (n_done is reported after the loop)
        # the two closures are called within this iteration only (so B023 does not apply)
        step, new_cost, lam, n = damped_step(
            lambda lam: _step(ne, lam, free),  # noqa: B023
            lambda st: _cost(lik, prior, g + st[0], t + st[1], sig), cost, lam)  # noqa: B023
        nfev += n
        if step is None:
            converged, message = True, "no further decrease of the cost (at a minimum)"
            break
        dg, dt = step
        small = (np.all(np.abs(dg) <= xtol * (np.abs(g) + xtol))
                 and np.all(np.abs(dt) <= xtol))
        g, t = g + dg, t + dt
        rel = (cost - new_cost) / max(new_cost, 1e-300)
        cost, ne = _normal_equations(lik, prior, g, t, sig)
        lam = max(lam / 3.0, 1e-12)
        if rel < ftol or small:
            converged, message = True, "relative cost decrease or step below tolerance"
            break
    S, _ = _schur(ne)
    cov = safe_inv(S)
    return PlanMapSolution(g=g, t=t, cost=float(cost), cov=0.5 * (cov + cov.T), S=S, ne=ne,
                           wall_index=ne["k"], nfev=nfev, n_iter=n_done, converged=converged,
                           message=message, sigma_px=float(sig))


def _fit(pixels, plan, *, sigma_px, prior, init, max_iter, outliers=True,
         outlier_scale=OUTLIER_SCALE, outlier_prior=OUTLIER_PRIOR, pixel_cov=None,
         model="aligned"):
    """MAP with the pixel noise given or estimated; returns (lik, prior, sol).

    A staged solve from ``init`` (see :func:`_fit_from`); if its solution fails the
    checks of :func:`~bayescal.results.floorplan.check_solution` (walls far off their plan,
    or pixels far off the model), up to ``N_RESTARTS`` restarts from sensor draws of
    the prior (a fixed seed: the result is deterministic). The lowest collapsed cost
    wins; ``sol.check`` says whether it passed (:func:`~bayescal.results.floorplan.make_result`
    flags it unconverged otherwise). ``outliers``: the per-point outlier mixture,
    solved by EM (:func:`_finish`). ``pixel_cov`` (N, 2, 2) px^2: per-point pixel
    covariances (every pixel residual row whitened, :class:`PlanLikelihood`). ``model``
    ``"misaligned"`` fits the laser cone's pose too (starting at its prior mean).
    """
    if not isinstance(plan, FloorPlan):
        raise InvalidTypeError(f"plan must be a FloorPlan, got {type(plan).__name__}")
    prior = prior if isinstance(prior, Prior) else Prior(prior)
    if init is None:
        init = prior.mean()
    elif not isinstance(init, SensorParams):
        raise InvalidTypeError(f"init must be a SensorParams or None, got {type(init).__name__}")
    lik = plan_likelihood(model, pixels, plan, prior, sigma_px=sigma_px, azimuth_params=init,
                          outliers=outliers, outlier_scale=outlier_scale,
                          outlier_prior=outlier_prior, pixel_cov=pixel_cov)
    if lik.n < 4:
        raise InvalidValueError(f"need at least 4 laser points, got N={lik.n}")
    best = None
    for staged in (True, False):            # both from init: neither is always the better
        try:
            sol = _fit_from(lik, prior, init, max_iter, staged=staged)
        except ValueError:
            if not staged:
                raise
            continue
        best = sol if best is None or sol.objective < best.objective else best
    draws = np.random.default_rng(0).standard_normal((N_RESTARTS, 8))
    for z in draws:
        if best.check["ok"]:
            break
        start = SensorParams.from_array(init.to_array() + prior.std() * z)
        try:
            sol = _fit_from(lik, prior, start, max_iter)
        except ValueError:                  # a start outside the model's domain
            continue
        best = sol if sol.objective < best.objective else best
    best = _corner_restarts(lik, prior, best, max_iter)
    _restore(lik, best)
    return lik, prior, RUNS.resolve(lik, prior, RETRY.retry(lik, prior, best, max_iter), max_iter)


def _fit_from(lik, prior, init, max_iter, *, staged=True):
    """One start: (staged) solve, noise estimate, re-picked corners; returns the solution.

    If ``staged``, stage 1 holds the wall orientations at the plan and fits the sensor and the
    walls' distances; stage 2 frees everything. From the design sensor a rough plan
    (orientations off by ~3 degrees per wall) can otherwise lead the joint solve into a wrong
    wall configuration: in the Fig. 9 case of ``docs/floorplan.md`` section 3, walls 14 prior
    sd off and 1.6 m errors. But held orientations can also mislead stage 1 (h driven to 0 in
    one 5000 mm replication), so :func:`_fit` runs both and keeps the better.
    """
    plan = lik.plan
    lik.assign(init)
    lik.ref_sigma_px = 1.0 if lik.infer_px else lik.sigma_px
    lik.em_weights = None                   # a fresh start: its own EM
    theta0 = to_identifiable(init.to_array())
    pose0 = [float(lik.prior.pose_dists[n].mean()) for n in POSE_NAMES] if lik.n_geo > 7 else []
    g = np.concatenate([theta0, pose0, [init.phi], plan.param_nominal])
    t = lik._start(theta0[None])[0]
    sig = 1.0 if lik.infer_px else lik.sigma_px
    stage1 = np.r_[np.ones(lik.n_geo + 1, bool), np.tile([True, False], lik.n_walls)]
    if staged:
        sol = _solve(lik, prior, g, t, sig, max_iter=max_iter, free=stage1)
        g, t = sol.g, sol.t
    return _finish(lik, prior, g, t, sig, max_iter)


def _finish(lik, prior, g, t, sig, max_iter, *, max_rounds=30, r_tol=1e-3, inliers=None):
    """Joint solve from (g, t) (re-estimating an inferred noise, EM for the outliers),
    re-picked corners, checks and the collapsed objective; returns the solution.

    EM for the outlier mixture, as for approximate points: the E-step takes each
    point's outlier probability ``r`` at the MAP with its azimuth integrated out
    (:meth:`~bayescal.likelihood.floorplan.PlanLikelihood.outlier_prob`), the M-step the least
    squares with weights ``(1 - r) + r / c^2`` on the point's pixel rows and the
    logit-scale mode ``w = (sum r + a) / (N + a + b)``, until ``r`` settles. Without
    EM weights yet (a fresh start) the first E-step is annealed (:func:`_anneal`).
    """
    if lik.outliers and lik.em_weights is None:
        _anneal(lik, prior, g, t, sig)
    rounds = max_rounds if lik.outliers else (4 if lik.infer_px else 1)
    for k in range(rounds):
        sol = _solve(lik, prior, g, t, sig, max_iter=max_iter)
        g, t, old = sol.g, sol.t, sig
        if lik.infer_px:
            # collapsed likelihood per point: -S_i / (2 sigma^2) - log sigma (one degree of
            # freedom per point: two pixel rows, one azimuth); maximum at mean S_i (EM:
            # the weighted S_i, each component's -log sigma summing to one per point)
            # first round trimmed: a streak of bad rows cannot inflate it (robustness.md)
            sig = float(sig * np.sqrt(_noise_factor(lik, sol, k, inliers)))
        if lik.outliers and _e_step(lik, g, sig) < r_tol and k > 0 \
                and abs(np.log(sig / old)) < 1e-4:
            break
    n_rounds = k + 1
    sol = _repick(lik, prior, sol, g, t, sig, max_iter)
    sol.em_rounds = n_rounds
    if lik.outliers:                        # the probabilities at the final MAP
        _e_step(lik, sol.g, sol.sigma_px)
    sol.em = _em_state(lik)
    sol.check = check_solution(lik, sol)
    # comparable across starts with inferred noise: the collapsed negative log posterior
    sol.objective = sol.cost + (lik.n * np.log(sol.sigma_px) if lik.infer_px else 0.0)
    sol.assignment = (lik.corner.copy(), lik.wall_pair.copy(), lik.ref_sigma_px)
    return sol


def _noise_factor(lik, sol, k, inliers):
    """The inferred pixel noise's update factor (squared) after round ``k`` of :func:`_finish`."""
    if inliers is not None and np.count_nonzero(inliers) >= 0.5 * lik.n:
        return float(np.sum(sol.ne["R"][inliers] ** 2) / np.count_nonzero(inliers))
    if k == 0:
        return trimmed_mean_square(np.sum(sol.ne["R0"] ** 2, axis=1), 1)
    return float(np.sum(sol.ne["R"] ** 2) / lik.n)


def _em_state(lik):
    """A copy of the EM state ``(weights, r, w)`` (None without the mixture)."""
    return (lik.em_weights.copy(), lik.em_r.copy(), lik.em_w) if lik.outliers else None


def _restore(lik, sol):
    """Put the likelihood back in the state (walls' pairs, reference noise, EM) of ``sol``."""
    lik.corner, lik.wall_pair, lik.ref_sigma_px = sol.assignment
    if sol.em is not None:
        lik.em_weights, lik.em_r, lik.em_w = sol.em[0].copy(), sol.em[1].copy(), sol.em[2]


def _logit(w):
    return float(np.log(w) - np.log1p(-w))


def _e_step(lik, g, sig):
    """EM E-step at ``g``: sets ``r``, ``w`` and the weights; returns ``max |change of r|``."""
    psi = np.concatenate([g[:lik.n_geo], g[lik.n_geo + 1:], [np.log(sig)] if lik.infer_px else [],
                          [_logit(lik.em_w)]])
    r = lik.outlier_prob(psi)
    r = np.where(np.isfinite(r), r, 1.0)         # no inlier fit at all: an outlier
    change = float(np.max(np.abs(r - lik.em_r)))
    lik.em_r = r
    lik.em_w, lik.em_weights = em_update(r, lik.outlier_prior, lik.outlier_scale)
    return change


def _anneal(lik, prior, g, t, sig):
    """First E-step at a start (:func:`~.outliers.annealed_outlier_prob`; ``m_i`` at
    the point's own best azimuth, one degree of freedom: two pixel rows, one latent)."""
    a, b = lik.outlier_prior
    lik.em_weights, lik.em_r, lik.em_w = None, np.zeros(lik.n), a / (a + b)
    with np.errstate(invalid="ignore", divide="ignore", over="ignore"):
        _, ne = _normal_equations(lik, prior, g, t, sig)
        m = np.sum(ne["R0"] ** 2, axis=1) - ne["gt"] ** 2 / ne["C"]
    c = lik.outlier_scale

    def log_ratio(mm):                  # log L_out - log L_in (planmodel's module doc)
        return 0.5 * mm * (1.0 - 1.0 / c**2) - np.log(c)

    r = annealed_outlier_prob(m, 1.0, _logit(lik.em_w), log_ratio)
    if r is None:
        lik.em_weights = np.ones(lik.n)
        return
    lik.em_r = r
    lik.em_weights = em_update(r, lik.outlier_prior, c)[1]


def _corner_restarts(lik, prior, best, max_iter):
    """Restarts that move each shallow corner across the points (``docs/floorplan.md`` s. 9).

    For each shallow corner of the best solution (:mod:`bayescal.scene.corners`), the
    points of its two walls, triangulated with the fitted sensor, are split at a few
    candidate azimuths (the best two-line split and a grid); the solve restarts from
    walls meeting at each split, and a restart wins if its collapsed cost is lower
    (and it passes the checks when the best did). Measured on the two wrong-wall
    replications of the coverage study: objective 382 -> 296 (the true configuration).
    """
    W, o = lik.n_walls, lik.n_geo + 1
    for j in shallow_corners(best.g[o:].reshape(W, 2)):
        walls = best.g[o:].reshape(W, 2)
        pts, valid = triangulate_geo(best.g[:o - 1], lik.pixels)
        jj = (j + 1) % W
        sel = np.flatnonzero(np.isin(best.wall_index, (j, jj)) & valid)
        c = corner_azimuths(walls[:, 0], walls[:, 1])[j]
        order = sel[np.argsort(wrap_angle(best.t[sel] - c))]
        current = int(np.sum(best.wall_index[order] == j))
        found = None                        # (cost, g, t, assignment) of the best candidate
        for k, w_j, w_jj in candidate_walls(pts[order, :2], current):
            if abs(k - current) <= 2:
                continue
            g = best.g.copy()
            for i, (d, a) in ((j, w_j), (jj, w_jj)):
                g[o + 2 * i:o + 2 + 2 * i] = d, walls[i, 1] + wrap_angle(a - walls[i, 1])
            _restore(lik, best)
            lik.assign(_sensor(lik, g), g[o:].reshape(W, 2))
            try:                # a short solve at the best's noise: enough to rank the basins
                sol = _solve(lik, prior, g, best.t, best.sigma_px, max_iter=min(max_iter, 12))
            except ValueError:
                continue
            if sol.cost < best.cost and (found is None or sol.cost < found[0]):
                found = (sol.cost, sol.g, sol.t, (lik.corner.copy(), lik.wall_pair.copy()))
        if found is not None:               # polish the winner as any start is polished
            lik.corner, lik.wall_pair = found[3]
            try:
                sol = _finish(lik, prior, found[1], found[2], best.sigma_px, max_iter)
            except ValueError:
                sol = None
            if sol is not None and sol.objective < best.objective \
                    and (sol.check["ok"] or not best.check["ok"]):
                best = sol
        _restore(lik, best)
    return best


def _sensor(lik, g):
    """The sensor (8 paper parameters) of ``g = (theta[, pose], phi, walls)``."""
    return SensorParams.from_array(from_identifiable(g[:7], g[lik.n_geo]))


def _repick(lik, prior, sol, g, t, sig, max_iter):
    """Re-pick each point's candidate walls around the MAP's corners and re-solve.

    The plan's corners may be far off at shallow corners; re-solve if any point
    changed its pair (at most three rounds).
    """
    for _ in range(3):
        before, corner = lik.wall_pair.copy(), lik.corner.copy()
        lik.assign(_sensor(lik, g), g[lik.n_geo + 1:].reshape(-1, 2))
        if lik.infer_px:
            lik.set_reference_noise(sigma_px=sig)
        if np.array_equal(before, lik.wall_pair) and not lik.infer_px:
            break
        try:
            sol = _solve(lik, prior, g, t, sig, max_iter=max_iter)
        except ValueError:
            # a re-picked pair misses some point's MAP azimuth: keep the pairs that fitted
            lik.wall_pair, lik.corner = before, corner
            break
        g, t = sol.g, sol.t
        if np.array_equal(before, lik.wall_pair):
            break
    return sol


def calibrate_plan(pixels, plan, *, sigma_px, prior=None, init=None, absolute_sigma=True,
                   max_iter=200, raise_on_failure=True, outliers=True,
                   outlier_scale=OUTLIER_SCALE, outlier_prior=OUTLIER_PRIOR, pixel_cov=None,
                   model="aligned", ring_corr_deg=0.0):
    """Calibrate from laser pixels and a rough floor plan (MAP + Laplace covariance).

    Called by :func:`bayescal.calibrate_simultaneous` when its second argument
    is a :class:`~bayescal.FloorPlan`; parameters as there. ``pixel_cov`` (N, 2, 2),
    px^2: per-point pixel covariances, the noise of pixel i ``sigma_px^2 pixel_cov_i``
    (``sigma_px`` a scale on them; ``None`` infers that scale). ``model="misaligned"``
    fits the laser cone's tilt and offset too (``result.laser``). ``ring_corr_deg``
    > 0: :func:`ring_corr_cov` added to the covariance.

    Returns
    -------
    CalibrationResult
        ``params``, ``points`` (N, 3), ``covariance`` (8, 8); ``extras``: ``walls`` (W, 2)
        the estimated ``(d_k, a_k)``, ``wall_covariance`` (2W, 2W) in the order ``d_0, a_0,
        d_1, ...``, ``wall_index`` (N,), ``azimuths`` (N,), ``point_covariance`` (N, 3, 3),
        ``map``, ``noise`` (with ``outlier_frac``, the MAP of ``w``), ``em_rounds``;
        ``outlier_prob`` (N,) at the MAP (None with ``outliers=False``). With the
        misaligned model, ``laser`` (the fitted pose) and ``covariance_identifiable``
        (11, 11), the pose after theta.
    """
    lik, prior, sol = _fit(pixels, plan, sigma_px=sigma_px, prior=prior, init=init,
                           max_iter=max_iter, outliers=outliers, outlier_scale=outlier_scale,
                           outlier_prior=outlier_prior, pixel_cov=pixel_cov, model=model)
    sol.cov = sol.cov + ring_corr_cov(lik, sol, ring_corr_deg) if ring_corr_deg > 0 else sol.cov
    result = make_result(lik, sol, absolute_sigma, False, prior=prior)
    result.extras["ring_corr_deg"] = ring_corr_deg
    result.extras["robust_start"] = bool(getattr(sol, "robust", False))
    note_runs(result, sol)
    if result.converged:         # one degree of freedom per point: its pixel pair, its azimuth
        flag_untrusted(result, prior, np.sum(sol.ne["R0"] ** 2, axis=1), 1,
                       noise_inferred=lik.infer_px)
    if not result.converged and raise_on_failure:
        raise ConvergenceError(f"floor-plan calibration did not converge: {result.message}",
                               result=result)
    return result


def normal_sensitivity(lik, sol):
    """``(P, sd)``: ``P`` (G, N) the first-order change of the MAP ``g`` per px pixel ``i``
    moves along the ring's normal (radial about the fitted ``(u0, v0)``): ``-S^-1 h_i``, ``h_i
    = J_g,i^T dR_i - B_i (J_t,i . dR_i) / C_i`` (azimuths eliminated; ``dR_i`` the whitened
    residuals' change); ``sd`` (N,) px, pixel ``i``'s sd along that normal, ``1 / |dR_i|``."""
    ne, rad = sol.ne, lik.pixels - sol.g[3:5]
    w = 1.0 if lik.em_weights is None else np.sqrt(lik.em_weights)[:, None]
    dR = -whiten(lik.px_white, rad / np.linalg.norm(rad, axis=1, keepdims=True) / sol.sigma_px) * w
    h = np.einsum("nki,nk->ni", ne["Jg"], dR) - ne["B"] * (
        np.einsum("nk,nk->n", ne["Jt"], dR) / ne["C"])[:, None]
    return -(sol.cov @ h.T), 1.0 / np.linalg.norm(dR, axis=1)


def ring_corr_cov(lik, sol, scale_deg):
    """Covariance of ``g`` (G, G) added when the points' errors along the ring's normal, each
    of its sd, are correlated as ``R = exp(-|t_i - t_j| / scale)``: ``Q (R - I) Q^T``, ``Q =
    P diag(sd)`` (:func:`normal_sensitivity`; docs/floorplan.md, "Errors correlated ...")."""
    Q, t, C, s = np.multiply(*normal_sensitivity(lik, sol)), sol.t, 0.0, np.radians(scale_deg)
    for a in range(0, len(t), 1024):       # (1024, N) rows at a time: no N x N array
        K = np.exp(-np.abs(np.angle(np.exp(1j * (t[a:a + 1024, None] - t[None])))) / s)
        K[np.arange(len(K)), a + np.arange(len(K))] -= 1.0
        C = C + Q[:, a:a + 1024] @ K @ Q.T
    return 0.5 * (C + C.T)


#: the robust retry of :func:`_fit` and the search for blocks of points off their wall
#: (:mod:`bayescal.fit.plan_robust`, :mod:`bayescal.fit.plan_runs`), on this module's steps
RETRY = PlanRetry(solve=_solve, finish=_finish, e_step=_e_step, restore=_restore,
                  normal_equations=_normal_equations, sensor=_sensor)
RUNS = PlanRuns(restore=_restore, sensor=_sensor, retry=RETRY)
