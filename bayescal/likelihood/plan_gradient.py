"""The floor-plan log marginal's gradient, for the sampler's gradient (HMC) move.

:class:`~bayescal.likelihood.floorplan.PlanLikelihood` integrates each point's azimuth
out by two truncated Laplace pieces, ``log p_i = log sum_p exp(l_ip)`` with
``l_ip = -rr_ip / (2 sigma^2) - log(H/C)_ip / 2 + log Phi(side_ip)``. By the envelope
theorem the derivative of ``rr_ip`` (the squared residual at the piece's mode ``t*``) in
any global ``g`` is ``2 r^T dr/dg`` at fixed ``t*``, so the gradient is::

    d log p_i / d g = -sum_p share_ip r_ip^T (dr_ip / dg) / sigma^2

weighted, with the outlier mixture, by the point's inlier and outlier probabilities
(the outlier's pieces have ``c^2`` times the variance). ``dr/dg`` at fixed ``t*`` is the
pixel model's analytic derivative in the geometry (7, or 11 with the laser pose) and in
the point's own wall ``(d_k, a_k)``; the inferred noise and the outlier fraction have
theirs too. The slowly varying terms (``log(H/C)``,
the corner truncation ``log Phi``) are left out of the gradient: it is approximate, as the
per-point model's is (:meth:`~bayescal.likelihood.points.LaserLikelihood.grad_log_marginal`),
which is enough for HMC, whose acceptance test uses the exact log density (a leapfrog
step with any position-dependent force is volume-preserving and reversible).
"""

from __future__ import annotations

import numpy as np
from scipy.special import expit

from ..sensor.laser import cone_height
from .point_algebra import whiten_pair

__all__ = ["PlanGradient"]

class PlanGradient:
    """Mixin of :class:`~bayescal.likelihood.floorplan.PlanLikelihood`: ``grad_log_marginal``.

    Having it allows the collapsed sampler's HMC move
    (:class:`~bayescal.mcmc.steps.CollapsedTarget`), which its first tuning round turns on
    here (independence acceptance 8-12 %). The aligned plan likelihood does
    not take it (its independence proposal mixes in ~7 steps, cheaper than HMC:
    ``docs/floorplan.md`` section 10); the misaligned one does (section 13).
    """

    def grad_log_marginal(self, psi, q0=None, *, n_iter=2):
        """:meth:`laplace`'s log marginal and its (approximate) gradient in ``psi``.

        Parameters
        ----------
        psi : ndarray, shape (..., d)
        q0 : ignored
            Accepted for the protocol (as in :meth:`laplace`).
        n_iter : int
            Gauss-Newton iterations per piece.

        Returns
        -------
        log_marginal : ndarray, shape (...)
            Exactly :meth:`laplace`'s value.
        grad : ndarray, shape (..., d)
            NaN where the value is ``-inf``.
        """
        psi = np.asarray(psi, dtype=float)
        pieces = self._pieces(psi, n_iter=n_iter)
        per_point, _, _, r = self._mixture(psi, n_iter, pieces)
        total = per_point.sum(axis=-1)
        value = np.where(np.isfinite(total), total, -np.inf)
        grad = np.zeros(psi.shape)
        theta, walls, sig = self.split(psi)
        weights = self._piece_weights(pieces, r, (1.0 / sig**2)[..., None])
        k = self.n_geo + 2 * self.n_walls
        for p in (0, 1):
            sel = self._piece_points(p)
            wt = weights[p][..., sel]
            rr, rj_geo, rj_wall = self._piece_jacobian(theta, walls, pieces[1][p][..., sel],
                                                       p, sel)
            with np.errstate(invalid="ignore"):
                use = wt > 0
                grad[..., :self.n_geo] -= np.sum(np.where(use[..., None], wt[..., None]
                                                          * rj_geo, 0.0), axis=-2)
                g_w = np.where(use[..., None], wt[..., None] * rj_wall, 0.0)   # (..., n, 2)
                onehot = np.eye(self.n_walls)[self.wall_pair[sel, p]]          # (n, W)
                # sum over each wall's points: a matrix product (einsum's loop was 10x slower)
                grad[..., self.n_geo:k] -= np.swapaxes(np.swapaxes(g_w, -1, -2) @ onehot,
                                                       -1, -2).reshape(
                    psi.shape[:-1] + (2 * self.n_walls,))
                if self.infer_px:
                    grad[..., k] += np.sum(np.where(use, wt * rr, 0.0), axis=-1)
        if self.infer_px:
            grad[..., k] -= self.n                     # the pixel normaliser, -log sigma each
        if self.outliers:
            grad[..., -1] = np.sum(r - expit(self.logit_frac(psi))[..., None], axis=-1)
        return value, np.where(np.isfinite(value)[..., None], grad, np.nan)

    def _piece_points(self, p):
        """The points whose piece ``p`` is computed: all, or after :meth:`restrict_pieces`
        those whose primary wall it is and those near a corner."""
        if self.primary is None:
            return np.arange(self.n)
        keep = self.primary == p
        keep[self.near] = True
        return np.flatnonzero(keep)

    def _piece_weights(self, pieces, r, inv_s2):
        """Each piece's weight of ``-r^T dr/dg`` (..., N): its share of the point's inlier
        mass, and with the mixture its share of the outlier's mass over ``c^2``, times
        ``inv_s2 = 1 / sigma^2``."""
        logm, _, _, lo = pieces
        with np.errstate(invalid="ignore", over="ignore"):
            m = np.logaddexp(logm[0], logm[1])
            share = [np.exp(logm[p] - m) for p in (0, 1)]
            if r is None:
                return [s * inv_s2 for s in share]
            lout = [logm[p] - m + lo[p] for p in (0, 1)]
            mo = np.logaddexp(lout[0], lout[1])
            c2 = self.outlier_scale**2
            return [((1.0 - r) * share[p] + r * np.exp(lout[p] - mo) / c2) * inv_s2
                    for p in (0, 1)]

    def _piece_jacobian(self, theta, walls, t, p, sel):
        """At fixed azimuths ``t`` (..., n) of the points ``sel`` (n,) on walls
        ``wall_pair[sel, p]``: the squared whitened residual ``rr`` (..., n) and ``r^T
        dr/dg`` for the geometry (..., n, n_geo) and the point's wall ``(d, a)`` (..., n,
        2), unit noise.

        The pixel model of ``_pixel_terms`` differentiated by hand: ``u = gamma_u x / D +
        u0``, ``D = xi |P| - z``, with ``z`` and its derivatives from
        :func:`~bayescal.sensor.laser.cone_height`.
        """
        d, a = (walls[..., self.wall_pair[sel, p], k] for k in (0, 1))
        pixels, white = self.pixels[sel], None if self.px_white is None else self.px_white[sel]
        xi, gu, gv, u0, v0 = (theta[..., k, None] for k in range(5))
        with np.errstate(invalid="ignore", divide="ignore"):
            ct, st = np.cos(t), np.sin(t)
            ic = 1.0 / np.cos(t - a)
            rho = np.where(ic > 0, d * ic, np.nan)
            x, y = rho * ct, rho * st
            z, zx, zy, dz_geo = cone_height(theta, x, y, geometry=True)
            r = np.sqrt(x * x + y * y + z * z)
            iD = 1.0 / (xi * r - z)
            mx, my = x * iD, y * iD
            # the residual pulled back through the whitening: r_w^T J_w = (L^T r_w)^T J
            ru, rv = whiten_pair(white, gu * mx + u0 - pixels[:, 0], gv * my + v0 - pixels[:, 1])
            if white is None:
                gu_, gv_ = ru, rv
            else:
                wa, wb, wc = white.T
                gu_, gv_ = wa * ru, wb * ru + wc * rv
            su, sv = gu_ * gu * mx, gv_ * gv * my     # r^T d(u, v)/d(log x, log y) ...
            geo = [-(su + sv) * r * iD, gu_ * mx, gv_ * my, gu_, gv_]
            dD_dz = (xi * z / r - 1.0) * iD            # d log D / d z
            geo += [-(su + sv) * dD_dz * g for g in dz_geo]
            wall = []
            for drho in (ic, -rho * np.tan(t - a)):   # d rho / d d, d rho / d a
                dx, dy = drho * ct, drho * st
                dz = zx * dx + zy * dy
                dD = (xi * (x * dx + y * dy + z * dz) / r - dz) * iD
                wall.append(gu_ * gu * (dx * iD - mx * dD) + gv_ * gv * (dy * iD - my * dD))
        return ru * ru + rv * rv, np.stack(geo, axis=-1), np.stack(wall, axis=-1)
