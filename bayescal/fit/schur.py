"""Levenberg-Marquardt on the parameters and every point, points eliminated by Schur.

The MAP solver of :func:`bayescal.calibrate_simultaneous`: unknowns ``(theta, phi)``
and each point's scene coordinates ``q_i``; each point couples only to the
parameters, so its 2x2 block is eliminated by a Schur complement and an
iteration costs O(N). Per-point weights make it the M-step of the outlier
mixture's EM (``docs/robustness.md``).
"""

from __future__ import annotations

import numpy as np

from ..errors import InvalidValueError
from ..sensor.laser import cone_points_geo

__all__ = ["solve_map", "MapSolution", "damped_step", "safe_inv", "in_domain", "SINGULAR_FLOOR",
           "STALL_WINDOW", "STALL_TOL", "STALL_ABS"]


class MapSolution:
    """Raw output of :func:`solve_map` (internal; users get a CalibrationResult).

    Attributes
    ----------
    theta : ndarray, shape (n_geo,)
        theta (7), or theta and the laser pose (11) for the misaligned model.
    q : ndarray, shape (N, 2)
    cost : float
        Half the sum of squared whitened residuals (prior rows included).
    phi : float
        phi at the MAP (set by the priors alone).
    cov_theta : ndarray, shape (n_geo, n_geo)
        Laplace covariance of theta (inverse Schur complement), unscaled.
    cov_theta_phi : ndarray, shape (n_geo + 1, n_geo + 1)
        Laplace covariance of (theta, phi) (phi last).
    cov_points : ndarray, shape (N, 3, 3)
        Laplace covariance of each 3D point (parameters' uncertainty included), computed
        when first read (a third of a start's cost when every solve computed it).
    """

    def __init__(self, **kw):
        self.__dict__.update(kw)

    @property
    def cov_points(self):
        if "_cov_points" not in self.__dict__:
            self._cov_points = _point_covariances(self.theta, self.q, self.Cinv, self.B,
                                                  self.cov_theta, self.weights)
        return self._cov_points


def _prior_rows(prior, psi, *, jacobian=True):
    """Prior rows at ``psi = (geometry, phi)`` and their Jacobian in psi.

    The geometry is theta (7) or, for the misaligned model, theta and the laser pose
    (11): eight rows on the paper parameters (with a camera prior, five whitened rows
    on its intrinsics, then phi, h, beta:
    :meth:`~bayescal.likelihood.priors.Prior.theta_residuals`), then four on the pose.
    """
    nt = len(psi) - 1
    if not jacobian:
        r = prior.theta_residuals(psi[:7], psi[nt])
        return r if nt == 7 else np.concatenate([r, prior.pose_residuals(psi[7:nt])])
    r, J8 = prior.theta_residuals(psi[:7], psi[nt], jacobian=True)   # (8, 8) in (theta, phi)
    if nt == 7:
        return r, J8
    rp, Dp = prior.pose_residuals(psi[7:nt], jacobian=True)
    J = np.zeros((12, nt + 1))
    J[:8, :7], J[:8, nt], J[8:, 7:nt] = J8[:, :7], J8[:, 7], Dp
    return np.concatenate([r, rp]), J


def _normal_equations(lik, prior, psi, q, sig, w, u):
    """Normal equations of the point-weighted cost ``sum_i u_i |R_i|^2 / 2 + prior``.

    ``B``, ``C`` and ``gq`` are returned unweighted: a point's weight scales its
    whole block, which leaves its own q-step unchanged and scales its Schur
    contribution to theta by ``u_i`` (see :func:`_schur_step`).
    """
    nt = lik.n_geo
    R, Jt, Jq = lik.residuals(psi[:nt], q, sig, w, jacobian=True)
    rp, Jp = _prior_rows(prior, psi)
    A = Jp.T @ Jp
    A[:nt, :nt] += np.einsum("n,nki,nkj->ij", u, Jt, Jt)
    B = np.zeros((lik.n, nt + 1, 2))
    B[:, :nt] = np.einsum("nki,nkj->nij", Jt, Jq)
    C = np.einsum("nki,nkj->nij", Jq, Jq)
    gt = Jp.T @ rp
    gt[:nt] += np.einsum("n,nki,nk->i", u, Jt, R)
    gq = np.einsum("nki,nk->ni", Jq, R)
    cost = 0.5 * (np.sum(u * np.sum(R * R, axis=1)) + rp @ rp)
    return cost, A, B, C, gt, gq, R


def in_domain(psi):
    """Whether ``psi = (geometry, phi)`` lies where the model is defined: ``xi > 0``,
    ``xi + phi > 0``, ``h > 0``, ``0 < beta < pi/2``. A step that leaves it is refused
    like one that raises the cost (the damping grows until the step stays inside), so
    no parameter walks through a bound of its domain inside the solver (an ``h`` walked
    through zero used to end the fit in a ValueError: ``docs/robustness.md``, 4c)."""
    xi, h, beta, phi = psi[0], psi[5], psi[6], psi[-1]
    return bool(xi > 0 and xi + phi > 0 and h > 0 and 0 < beta < np.pi / 2)


def _cost(lik, prior, psi, q, sig, w, u):
    if not in_domain(psi):
        return np.inf
    R = lik.residuals(psi[:lik.n_geo], q, sig, w)
    rp = _prior_rows(prior, psi, jacobian=False)
    c = 0.5 * (np.sum(u * np.sum(R * R, axis=1)) + rp @ rp)
    return c if np.isfinite(c) else np.inf


def _schur_step(A, B, C, gt, gq, lam, u):
    Ad = A + lam * np.diag(np.diag(A))
    Cd = C.copy()
    Cd[:, [0, 1], [0, 1]] *= 1.0 + lam
    Cinv = safe_inv(Cd)
    BC = np.einsum("nij,njk->nik", B, Cinv) * u[:, None, None]          # (N, nt + 1, 2)
    S = Ad - np.einsum("nik,njk->ij", BC, B)
    rhs = -(gt - np.einsum("nik,nk->i", BC, gq))
    dt = np.linalg.solve(S, rhs)
    dq = -np.einsum("nij,nj->ni", Cinv, gq + np.einsum("nki,k->ni", B, dt))
    return dt, dq


#: the solver stops as converged when its cost fell by less than ``STALL_TOL`` (relative),
#: or by less than ``STALL_ABS`` (the cost is half a chi-square: a parameter 0.045 sd from its
#: optimum adds 1e-3), over the last ``STALL_WINDOW`` accepted steps: a crawl that used to
#: end at max_iter (an outlier's point running along its ray to infinity, its weight 1e-4:
#: the cost fell by 4e-4 per 20 steps, 9e-7 of itself, and the parameters by 1e-5 sd)
STALL_WINDOW, STALL_TOL, STALL_ABS = 20, 1e-8, 1e-3


def solve_map(lik, prior, theta0, q0, *, phi=None, sigma_px=None, w_scene=None,
              max_iter=200, ftol=1e-12, xtol=1e-10, weights=None):
    """Levenberg-Marquardt on (theta, phi) and the scene coordinates (noise levels fixed).

    ``phi`` is an unknown like the others, but only the prior rows see it: the
    solution sits on the phi/alpha ridge where the priors of phi, alpha_u and
    alpha_v balance, and the Laplace covariance carries that ridge.

    Parameters
    ----------
    lik : LaserLikelihood
        Or a :class:`~bayescal.likelihood.misaligned.MisalignedLikelihood`: the
        geometry is then theta and the laser pose (``lik.n_geo`` = 11 numbers).
    prior : Prior
    theta0 : ndarray, shape (lik.n_geo,)
    q0 : ndarray, shape (N, 2)
    phi : float, optional
        Starting phi (default: the prior mean).
    sigma_px : float
        Pixel noise used for whitening.
    w_scene : ndarray, shape (N, 3)
        Inverse scene standard deviations.
    weights : ndarray, shape (N,), optional
        Per-point weights ``u_i`` of the squared residuals (default 1): the
        M-step of the outlier mixture's EM, ``u_i = (1 - r_i) + r_i / c^2``.

    Returns
    -------
    MapSolution
    """
    phi = float(prior.dists["phi"].mean()) if phi is None else float(phi)
    sig = np.asarray(sigma_px, dtype=float)
    theta = np.append(np.asarray(theta0, dtype=float), phi)
    q = np.array(q0, dtype=float)
    u = np.ones(lik.n) if weights is None else np.asarray(weights, dtype=float)
    lam, nfev, converged, message = 1e-3, 1, False, "maximum number of iterations reached"
    cost, A, B, C, gt, gq, R = _normal_equations(lik, prior, theta, q, sig, w_scene, u)
    if not np.isfinite(cost):
        raise InvalidValueError("the starting point puts some laser points outside the model's "
                                "domain (non-finite residuals); give a better init")
    n_done, history = 0, [cost]
    for n_done in range(1, max_iter + 1):  # noqa: B007 (n_done is reported after the loop)
        # the two closures are called within this iteration only (so B023 does not apply)
        step, new_cost, lam, n = damped_step(
            lambda lam: _schur_step(A, B, C, gt, gq, lam, u),  # noqa: B023
            lambda st: _cost(lik, prior, theta + st[0], q + st[1], sig, w_scene, u),  # noqa: B023
            cost, lam)
        nfev += n
        if step is None:
            converged, message = True, "no further decrease of the cost (at a minimum)"
            break
        dt, dq = step
        small_step = (np.all(np.abs(dt) <= xtol * (np.abs(theta) + xtol))
                      and np.all(np.abs(dq) <= xtol * (np.abs(q) + 1.0)))
        theta, q = theta + dt, q + dq
        rel = (cost - new_cost) / max(new_cost, 1e-300)
        cost, A, B, C, gt, gq, R = _normal_equations(lik, prior, theta, q, sig, w_scene, u)
        lam = max(lam / 3.0, 1e-12)
        if rel < ftol or small_step:
            converged, message = True, "relative cost decrease or step below tolerance"
            break
        history.append(cost)
        if len(history) > STALL_WINDOW and \
                history[-STALL_WINDOW - 1] - cost < max(STALL_TOL * cost, STALL_ABS):
            # crawling along a flat direction (e.g. an outlier's nearly free point): the
            # cost no longer changes by anything the noise could tell apart
            converged, message = True, "converged (cost stationary over the last steps)"
            break
    # Laplace covariance at the solution (undamped Schur complement)
    Cinv = safe_inv(C)
    BC = np.einsum("nij,njk->nik", B, Cinv) * u[:, None, None]
    S = A - np.einsum("nik,njk->ij", BC, B)
    cov_full = safe_inv(S)                           # (theta, phi)
    _, Jp = _prior_rows(prior, theta)
    nt = lik.n_geo
    info_data = (S - Jp.T @ Jp)[:nt, :nt]            # what the data alone say about theta
    cov_t = cov_full[:nt, :nt]
    return MapSolution(theta=theta[:nt], q=q, cost=float(cost), cov_theta=cov_t,
                       cov_theta_phi=cov_full, Cinv=Cinv, B=B[:, :nt], R=R, A=A, nfev=nfev,
                       n_iter=n_done, converged=converged, message=message, phi=float(theta[nt]),
                       info_data=info_data, weights=u)


def damped_step(propose, cost_of, cost, lam, *, max_tries=30):
    """Levenberg-Marquardt's inner loop: raise the damping until a step lowers the cost.

    Parameters
    ----------
    propose : callable
        ``propose(lam)`` -> the step at damping ``lam`` (may raise LinAlgError).
    cost_of : callable
        ``cost_of(step)`` -> the cost after the step.
    cost : float
        The current cost.
    lam : float
        The current damping.

    Returns
    -------
    step : object or None
        The accepted step, or None when no damping up to ``max_tries`` raises helped.
    new_cost, lam : float
    nfev : int
        Cost evaluations used.
    """
    nfev = 0
    for _ in range(max_tries):
        try:
            step = propose(lam)
        except np.linalg.LinAlgError:
            lam *= 10
            continue
        new_cost = cost_of(step)
        nfev += 1
        if new_cost < cost:
            return step, new_cost, lam, nfev
        lam *= 4.0
    return None, cost, lam, nfev


#: a singular information matrix's eigenvalues are floored at this fraction of its largest
SINGULAR_FLOOR = 1e-12


def safe_inv(M):
    """Inverse of a symmetric information matrix, or of a stack of them (..., k, k).

    A singular one (a point or parameter the data do not determine, e.g. a row whose
    approximate point lies in another room) does not stop the fit: its eigenvalues are
    floored at :data:`SINGULAR_FLOOR` of its largest, so the undetermined direction
    gets a huge variance (never a small, false one as a pseudo-inverse would give).
    """
    try:
        out = np.linalg.inv(M)
        if np.all(np.isfinite(out)):
            return out
    except np.linalg.LinAlgError:
        pass
    Ms = 0.5 * (M + np.swapaxes(M, -1, -2))
    Ms = np.where(np.isfinite(Ms), Ms, 0.0)
    e, V = np.linalg.eigh(Ms)
    top = np.max(np.abs(e), axis=-1, keepdims=True)
    e = np.maximum(e, SINGULAR_FLOOR * np.where(top > 0, top, 1.0))
    return np.einsum("...ij,...j,...kj->...ik", V, 1.0 / e, V)


def _point_covariances(theta, q, Cinv, B, cov_t, u):
    """3x3 covariance of each point from the joint Laplace covariance of (theta, q).

    A point of weight ``u_i`` has its own block ``u_i C_i``: its conditional
    covariance is ``C_i^-1 / u_i`` (an outlier's point is barely determined).
    """
    _, Gq, Gt = cone_points_geo(theta, q, jacobian=True)        # (N,3,2), (N,3,nt)
    K = -np.einsum("nij,nkj,kl->nil", Cinv, B, cov_t)            # cov(q_i, theta): (N,2,nt)
    cov_q = Cinv / u[:, None, None] + np.einsum("nij,nkj,kl,nlm,nmp->nip", Cinv, B, cov_t, B, Cinv)
    out = (np.einsum("nia,nab,njb->nij", Gq, cov_q, Gq)
           + np.einsum("nia,nab,njb->nij", Gq, K, Gt)
           + np.einsum("nia,nab,njb->nij", Gt, np.swapaxes(K, 1, 2), Gq)
           + np.einsum("nia,ab,njb->nij", Gt, cov_t, Gt))
    return out
