"""The likelihood of laser pixels and approximate 3D points (one model for all fitters).

Data: laser pixels ``pixels`` (N, 2) and approximate points ``approx_points``
(N, 3). Unknowns: the identifiable parameters ``theta`` (7,) and, per laser
point, its scene coordinates ``q_i = (x_i, y_i)`` (the horizontal position
where the ray meets the wall); the cone gives ``P_i = (x_i, y_i,
rho_i / tan(beta) - h)``. The model (``docs/bayes.md``)::

    pixels_i        ~ N(project(theta, P_i), sigma_px^2 I_2)
    approx_points_i ~ N(P_i, diag(sigma_scene_i^2))       (inf = axis not used)

Each point contributes five whitened residuals: two pixel rows, three scene
rows. :class:`LaserLikelihood` returns them with their Jacobians (analytic),
vectorized over any leading axes (walkers) and the N points; the least
squares (:mod:`bayescal.simultaneous`), the collapsed sampler and the
brute-force joint sampler (:mod:`bayescal.sampling`) all call it.

Noise levels are either given or inferred: ``sigma_px = None`` adds
``log sigma_px`` to the sampled vector; ``sigma_scene = None`` adds
``log kappa`` with ``sigma_scene_i = kappa * rho_i`` on every axis (a relative
error of the approximate point's horizontal range ``rho_i``).
"""

from __future__ import annotations

import numpy as np

from ._validation import as_pixels, as_points, check_positive
from .camera import project_theta
from .laser import cone_point_theta, triangulate_theta
from .model_grad import grad_terms

__all__ = ["LaserLikelihood", "POINT_PRIORS", "NOISE_BOUNDS", "draw_points"]

#: log-uniform prior bounds of the inferred noise levels
NOISE_BOUNDS = {"sigma_px": (1e-3, 10.0), "kappa": (1e-4, 1.0)}

#: priors of the latent scene coordinates: see :class:`LaserLikelihood`
POINT_PRIORS = ("jeffreys", "flat")

_LOG2PI = np.log(2 * np.pi)


def _inv2(C):
    """Inverse and determinant of stacked 2x2 matrices, shape (..., 2, 2)."""
    a, b, c, d = C[..., 0, 0], C[..., 0, 1], C[..., 1, 0], C[..., 1, 1]
    det = a * d - b * c
    inv = np.empty_like(C)
    inv[..., 0, 0] = d / det
    inv[..., 0, 1] = -b / det
    inv[..., 1, 0] = -c / det
    inv[..., 1, 1] = a / det
    return inv, det


class LaserLikelihood:
    """Pixel and scene-prior likelihood of N laser points.

    Parameters
    ----------
    pixels : array_like, shape (N, 2)
        Laser pixels ``(u, v)``, px.
    approx_points : array_like, shape (N, 3)
        Approximate 3D laser points in frame C, mm.
    sigma_px : float or None
        Pixel noise standard deviation, px; ``None`` = inferred.
    sigma_scene : float, array_like broadcastable to (N, 3), or None
        Standard deviation of ``approx_points - true points``, mm; ``inf``
        marks an axis that carries no information; ``None`` = inferred as
        ``kappa * rho_i``.
    point_prior : {"jeffreys", "flat"}
        Prior of each point's scene coordinates given the parameters. A flat
        prior makes the parameters' posterior inherit a Neyman-Scott bias from
        the N incidental points (the points' information ``J_q^T J_q`` depends
        on theta; measured at about -1.8 posterior sd on h in the 1000 mm room,
        see ``docs/bayes.md``). The Jeffreys prior ``|J_q^T J_q|^(1/2)`` (the
        reference prior for incidental parameters) cancels that term: the
        collapsed likelihood becomes the profile likelihood, whose score has
        zero mean. Default "jeffreys".

    Attributes
    ----------
    n_noise : int
        Number of inferred noise parameters appended to ``theta`` (0, 1 or 2).
    """

    def __init__(self, pixels, approx_points, *, sigma_px, sigma_scene, point_prior="jeffreys"):
        if point_prior not in POINT_PRIORS:
            raise ValueError(f"point_prior must be one of {POINT_PRIORS}, got {point_prior!r}")
        self.point_prior = point_prior
        self.pixels = as_pixels(pixels, "pixels")
        self.approx = as_points(approx_points, "approx_points")
        if self.pixels.ndim != 2 or self.approx.ndim != 2:
            raise ValueError(f"pixels must have shape (N, 2) and approx_points (N, 3), got "
                             f"{self.pixels.shape} and {self.approx.shape}")
        if len(self.pixels) != len(self.approx):
            raise ValueError(f"pixels and approx_points must have the same length N, got "
                             f"{len(self.pixels)} and {len(self.approx)}")
        self.n = len(self.pixels)
        self.infer_px = sigma_px is None
        self.infer_scene = sigma_scene is None
        self.sigma_px = None if self.infer_px else check_positive(sigma_px, "sigma_px")
        self.rho = np.hypot(self.approx[:, 0], self.approx[:, 1])
        if self.infer_scene:
            if np.any(self.rho <= 0):
                raise ValueError("approx_points on the axis (x = y = 0) cannot carry a relative "
                                 "scene error; give sigma_scene explicitly")
            self.w_scene = None
            self._scene_mask = np.ones((self.n, 3), bool)
        else:
            try:
                s = np.asarray(sigma_scene, dtype=float)
            except (TypeError, ValueError):
                raise TypeError(f"sigma_scene must be a float, an array or None, got "
                                f"{type(sigma_scene).__name__}") from None
            if np.any(np.isnan(s)) or np.any(s <= 0):
                raise ValueError("sigma_scene must be positive everywhere (inf allowed: no "
                                 f"information on that axis), got min {np.min(s)}")
            try:
                s = np.broadcast_to(s, (self.n, 3))
            except ValueError:
                raise ValueError(f"sigma_scene must be a float or broadcastable to (N, 3) = "
                                 f"{(self.n, 3)}, got shape {np.shape(sigma_scene)}") from None
            self.w_scene = np.where(np.isfinite(s), 1.0 / s, 0.0)
            self._scene_mask = np.isfinite(s)
        self.n_noise = int(self.infer_px) + int(self.infer_scene)
        self._n_rows = 2 + self._scene_mask.sum(axis=1)         # residual rows per point
        if not self.infer_scene:
            with np.errstate(divide="ignore"):
                self._log_w_given = np.where(self._scene_mask, np.log(self.w_scene),
                                             0.0).sum(axis=1)
        self.ref_sigma_px = 1.0 if self.infer_px else self.sigma_px
        self.ref_kappa = 0.05

    def set_reference_noise(self, *, sigma_px=None, kappa=None):
        """Noise levels at which the Jeffreys prior of the points is evaluated.

        Only matters for inferred noise: the prior ``|C(theta, q)|^(1/2)`` is
        taken at these fixed levels so that it depends on ``theta`` only and the
        noise posterior keeps the flat-prior (REML-like) degrees of freedom.
        """
        if sigma_px is not None:
            self.ref_sigma_px = check_positive(sigma_px, "sigma_px")
        if kappa is not None:
            self.ref_kappa = check_positive(kappa, "kappa")

    # -- noise ---------------------------------------------------------------
    def noise(self, extra):
        """Noise levels from the inferred log-noise entries.

        Parameters
        ----------
        extra : ndarray, shape (..., n_noise)
            ``log sigma_px`` then ``log kappa`` (only those inferred).

        Returns
        -------
        sigma_px : ndarray, shape (...)
        w_scene : ndarray, shape (..., N, 3)
            Inverse scene standard deviations (0 on unused axes).
        log_norm : ndarray, shape (..., N)
            ``-log`` of the Gaussian normalisers per point.
        """
        extra = np.asarray(extra, dtype=float)
        lead = extra.shape[:-1]
        k = 0
        if self.infer_px:
            sig = np.exp(extra[..., k])
            k += 1
        else:
            sig = np.full(lead, self.sigma_px)
        if self.infer_scene:
            kappa = np.exp(extra[..., k])
            w = 1.0 / (kappa[..., None, None] * self.rho[:, None])
            w = np.broadcast_to(w, lead + (self.n, 3))
        else:
            w = np.broadcast_to(self.w_scene, lead + (self.n, 3))
        if self.infer_scene:
            log_w = np.log(w).sum(axis=-1)                      # every axis used
        else:
            log_w = self._log_w_given                           # constant: computed once
        log_norm = -2.0 * np.log(sig)[..., None] + log_w - 0.5 * self._n_rows * _LOG2PI
        return sig, w, log_norm

    @property
    def extra_names(self):
        """Names of the sampled coordinates after theta, in order (the "extra globals").

        The collapsed sampler works on ``psi = (theta, extra)``; any likelihood
        it samples provides ``n``, ``extra_names``, :meth:`log_prior_extra`,
        :meth:`laplace`, :meth:`point_log_density` and :meth:`points_3d`.
        Here the extras are ``log sigma_px`` and ``log kappa`` where inferred.
        """
        return tuple(n for n, on in (("sigma_px", self.infer_px), ("kappa", self.infer_scene))
                     if on)

    def log_prior_extra(self, extra):
        """Log prior density of the extra globals, shape (...); ``-inf`` outside the support.

        Each inferred noise level has a log-uniform prior on :data:`NOISE_BOUNDS`
        (flat in the sampled ``log`` value, up to a constant).
        """
        extra = np.asarray(extra, dtype=float)
        lp = np.zeros(extra.shape[:-1])
        for k, name in enumerate(self.extra_names):
            lo, hi = np.log(NOISE_BOUNDS[name])
            x = extra[..., k]
            lp = np.where((x > lo) & (x < hi), lp, -np.inf)
        return lp

    def points_3d(self, psi, q):
        """3D points (..., N, 3), mm, of the scene coordinates ``q`` (..., N, 2) under ``psi``."""
        theta = np.asarray(psi, dtype=float)[..., :7]
        return cone_point_theta(theta[..., None, :], q)

    def split(self, psi):
        """Split a sampled vector ``(..., 7 + n_noise)`` into theta and noise entries."""
        psi = np.asarray(psi, dtype=float)
        return psi[..., :7], psi[..., 7:]

    # -- residuals -----------------------------------------------------------
    def residuals(self, theta, q, sigma_px, w_scene, *, jacobian=False):
        """Whitened residuals of every point.

        Parameters
        ----------
        theta : ndarray, shape (..., 7)
        q : ndarray, shape (..., N, 2)
            Scene coordinates (x, y) of the points, mm.
        sigma_px : ndarray, shape (...)
        w_scene : ndarray, shape (..., N, 3)
        jacobian : bool

        Returns
        -------
        R : ndarray, shape (..., N, 5)
            Two pixel rows then three scene rows (zero where unused); NaN
            where a point leaves the projection's domain.
        J_theta : ndarray, shape (..., N, 5, 7)
            Only with ``jacobian=True``.
        J_q : ndarray, shape (..., N, 5, 2)
            Only with ``jacobian=True``.
        """
        th = np.asarray(theta)[..., None, :]
        if not jacobian:
            P = cone_point_theta(th, q)
            uv, _ = project_theta(th, P)
        else:
            P, dxy, dthc = cone_point_theta(th, q, jacobian=True)
            uv, _, dPp, dthp = project_theta(th, P, jacobian=True)
        inv_s = 1.0 / np.asarray(sigma_px)[..., None, None]
        shape = uv.shape[:-1]
        R = np.empty(shape + (5,))
        R[..., :2] = (uv - self.pixels) * inv_s
        R[..., 2:] = (P - self.approx) * w_scene
        if not jacobian:
            return R
        Jq = np.empty(shape + (5, 2))
        Jq[..., :2, :] = (dPp[..., :, :2] + dPp[..., :, 2:3] * dxy[..., 2:3, :]) * inv_s[..., None]
        Jq[..., 2:, :] = dxy * w_scene[..., :, None]
        Jt = np.empty(shape + (5, 7))
        Jt[..., :2, :] = (dthp + dPp[..., :, 2:3] * dthc[..., 2:3, :]) * inv_s[..., None]
        Jt[..., 2:, :] = dthc * w_scene[..., :, None]
        return R, Jt, Jq

    # -- per-point Laplace step ----------------------------------------------
    def initial_q(self, theta):
        """A starting value of the scene coordinates: the approximate points' (x, y),
        or the triangulated pixels where no scene information is given in x/y."""
        q = self.approx[:, :2].copy()
        if not self.infer_scene:
            blind = ~self._scene_mask[:, :2].all(axis=1)
            if np.any(blind):
                P, ok = triangulate_theta(np.asarray(theta, float), self.pixels[blind])
                q[blind] = np.where(ok[:, None], P[:, :2], q[blind])
        return q

    def _point_terms(self, theta, x, y, sig, w):
        """Hot path of :meth:`laplace`: residuals and q-normal equations, elementwise.

        Same quantities as :meth:`residuals` (tested against it), written out
        for 2x2 blocks so that walkers x points cost a few dozen array ops.
        Returns ``(rr, Cp, Cs, g0, g1)``: ``rr = |R|^2``, the pixel and scene
        parts of ``J_q^T J_q`` as ``(C00, C01, C11)`` triples, and the gradient.
        """
        xi, gu, gv, u0, v0, h, beta = (theta[..., k, None] for k in range(7))
        T = np.tan(beta)
        rho = np.sqrt(x * x + y * y)
        gx, gy = x / (rho * T), y / (rho * T)
        z = rho / T - h
        r = np.sqrt(rho * rho + z * z)
        D = xi * r - z
        iD = np.where(D > 0, 1.0 / D, np.nan)
        mx, my = x * iD, y * iD
        inv_s = 1.0 / sig[..., None]
        ru = (gu * mx + u0 - self.pixels[:, 0]) * inv_s
        rv = (gv * my + v0 - self.pixels[:, 1]) * inv_s
        xr = xi / r
        dDx = xr * (x + z * gx) - gx
        dDy = xr * (y + z * gy) - gy
        a, b = gu * iD * inv_s, gv * iD * inv_s
        ux, uy = a * (1.0 - mx * dDx), -a * mx * dDy
        vx, vy = -b * my * dDx, b * (1.0 - my * dDy)
        wx, wy, wz = w[..., 0], w[..., 1], w[..., 2]
        rx, ry, rz = (x - self.approx[:, 0]) * wx, (y - self.approx[:, 1]) * wy, \
            (z - self.approx[:, 2]) * wz
        wz2 = wz * wz
        Cp = (ux * ux + vx * vx, ux * uy + vx * vy, uy * uy + vy * vy)
        Cs = (wx * wx + wz2 * gx * gx, wz2 * gx * gy, wy * wy + wz2 * gy * gy)
        g0 = ux * ru + vx * rv + wx * rx + wz * gx * rz
        g1 = uy * ru + vy * rv + wy * ry + wz * gy * rz
        rr = ru * ru + rv * rv + rx * rx + ry * ry + rz * rz
        return rr, Cp, Cs, g0, g1

    def _log_point_prior(self, extra, sig, Cp, Cs):
        """log of the points' prior density at the current q, shape (..., N).

        Flat prior: 0. Jeffreys prior: ``log |C_ref|^(1/2)`` with ``C_ref`` the
        points' information at the reference noise levels.
        """
        if self.point_prior == "flat":
            return 0.0
        sp = (np.asarray(sig) / self.ref_sigma_px)[..., None] ** 2
        if self.infer_scene:
            kappa = np.exp(extra[..., -1])
            ss = (kappa / self.ref_kappa)[..., None] ** 2
        else:
            ss = 1.0
        c00, c01, c11 = (p * sp + q * ss for p, q in zip(Cp, Cs, strict=True))
        return 0.5 * np.log(c00 * c11 - c01 * c01)

    def laplace(self, psi, q0, *, n_iter=4):
        """Integrate each point's scene coordinates out by a Gauss-Newton/Laplace step.

        Parameters
        ----------
        psi : ndarray, shape (..., 7 + n_noise)
        q0 : ndarray, shape (..., N, 2) or (N, 2)
            Starting scene coordinates.
        n_iter : int
            Gauss-Newton iterations (the start is usually the MAP's, so a few
            suffice); the value returned also includes the quadratic model's
            remaining gain ``g^T C^-1 g / 2``, so it is accurate one step early.

        Returns
        -------
        log_marginal : ndarray, shape (...)
            Sum over points of ``log int p(pixels_i, approx_i | theta, q_i)
            pi(q_i | theta) dq_i`` (Laplace approximation with the Gauss-Newton
            Hessian; exact for a model linear in q); ``-inf`` outside the
            model's domain. With the Jeffreys point prior and given noise this
            is the profile likelihood plus a constant.
        q : ndarray, shape (..., N, 2)
            Conditional modes.
        C : ndarray, shape (..., N, 2, 2)
            Conditional precision matrices ``J_q^T J_q`` (inverse = covariance).
        """
        theta, extra = self.split(psi)
        sig, w, log_norm = self.noise(extra)
        q = np.broadcast_to(q0, theta.shape[:-1] + (self.n, 2))
        x, y = q[..., 0].copy(), q[..., 1].copy()
        with np.errstate(invalid="ignore", divide="ignore"):
            for it in range(n_iter + 1):
                rr, Cp, Cs, g0, g1 = self._point_terms(theta, x, y, sig, w)
                C00, C01, C11 = (p + q for p, q in zip(Cp, Cs, strict=True))
                det = C00 * C11 - C01 * C01
                d0 = (C11 * g0 - C01 * g1) / det
                d1 = (C00 * g1 - C01 * g0) / det
                if it == n_iter:
                    break
                x = x - d0
                y = y - d1
            per_point = (-0.5 * rr + 0.5 * (g0 * d0 + g1 * d1) - 0.5 * np.log(det) + _LOG2PI
                         + log_norm + self._log_point_prior(extra, sig, Cp, Cs))
        total = per_point.sum(axis=-1)
        C = np.stack([np.stack([C00, C01], -1), np.stack([C01, C11], -1)], -2)
        return np.where(np.isfinite(total), total, -np.inf), np.stack([x, y], -1), C

    def grad_log_marginal(self, psi, q0, *, n_iter=4):
        """:meth:`laplace`'s log marginal and its gradient in ``psi`` (envelope theorem).

        With the Jeffreys point prior and given noise ``C = C_ref``: the log
        marginal is the profile likelihood ``-|R(theta, q*)|^2 / 2 + const``, its
        gradient ``-sum_i J_theta_i^T R_i`` at the modes ``q*``. Inferred noise
        adds its analytic derivatives; where ``C != C_ref`` (noise away from the
        reference levels, flat point prior) the log-determinants' theta-dependence
        is left out: approximate, fine for HMC whose acceptance test uses the value.

        Parameters
        ----------
        psi : ndarray, shape (..., 7 + n_noise)
        q0 : ndarray, shape (..., N, 2) or (N, 2)
        n_iter : int
            Gauss-Newton iterations of :meth:`laplace`.

        Returns
        -------
        log_marginal : ndarray, shape (...)
            Exactly :meth:`laplace`'s value.
        grad : ndarray, shape (..., 7 + n_noise)
            NaN where the value is ``-inf``.
        """
        psi = np.asarray(psi, dtype=float)
        value, q, _ = self.laplace(psi, q0, n_iter=n_iter)
        theta, extra = self.split(psi)
        sig, w, _ = self.noise(extra)
        with np.errstate(invalid="ignore", divide="ignore"):
            x, y = q[..., 0], q[..., 1]
            _, Cp, Cs, g0, g1 = self._point_terms(theta, x, y, sig, w)
            C00, C01, C11 = (a + b for a, b in zip(Cp, Cs, strict=True))
            det = C00 * C11 - C01 * C01
            x = x - (C11 * g0 - C01 * g1) / det            # one more step: the modes
            y = y - (C00 * g1 - C01 * g0) / det
            grad = grad_terms(self, theta, x, y, sig, w)
        grad = np.where(np.isfinite(value)[..., None], grad, np.nan)
        return value, grad

    def _exact_terms(self, psi, q):
        theta, extra = self.split(psi)
        sig, w, log_norm = self.noise(extra)
        with np.errstate(invalid="ignore", divide="ignore"):
            rr, Cp, Cs, _, _ = self._point_terms(theta, q[..., 0], q[..., 1], sig, w)
            per_point = -0.5 * rr + self._log_point_prior(extra, sig, Cp, Cs)
        return per_point, log_norm

    def log_joint(self, psi, q):
        """Exact log density of ``(psi, q)`` (likelihood times point prior), shape (...).

        Used by the brute-force joint sampler that validates the collapsed one.
        """
        per_point, log_norm = self._exact_terms(psi, q)
        total = np.sum(per_point + log_norm, axis=-1)
        return np.where(np.isfinite(total), total, -np.inf)

    def point_log_density(self, psi, q):
        """Per-point exact log density of ``q`` given ``psi`` (up to constants), (..., N)."""
        out, _ = self._exact_terms(psi, q)
        return np.where(np.isfinite(out), out, -np.inf)


def draw_points(lik, psi, q_start, rng, *, n_mh, n_iter, batch=256):
    """Draw every point's latent coordinates given each sample of the globals.

    Each point is drawn from its Laplace Gaussian ``N(q*, C^-1)`` (from
    ``lik.laplace``), then corrected by ``n_mh`` independence Metropolis-Hastings
    steps against the exact conditional ``lik.point_log_density`` (the Gaussian
    as proposal), so a non-Gaussian conditional is still sampled correctly.
    Works for any likelihood of the collapsed-sampler protocol and any per-point
    latent dimension k.

    Parameters
    ----------
    lik : likelihood
        Provides ``n``, ``laplace`` and ``point_log_density``.
    psi : ndarray, shape (S, d)
        Samples of the globals (theta then extras).
    q_start : ndarray, shape (N, k)
        Start of the Gauss-Newton steps.
    rng : numpy.random.Generator
    n_mh : int
        Independence Metropolis-Hastings corrections per draw.
    n_iter : int
        Gauss-Newton iterations.
    batch : int, optional
        Samples per vectorized call (memory: batch x N x k x k floats).

    Returns
    -------
    q : ndarray, shape (S, N, k)
    acceptance : float
        Mean acceptance of the corrections (NaN when ``n_mh = 0``).
    """
    S = len(psi)
    k = np.shape(q_start)[-1]
    out = np.empty((S, lik.n, k))
    acc = []
    for lo in range(0, S, batch):
        p = psi[lo:lo + batch]
        _, qm, C = lik.laplace(p, q_start, n_iter=n_iter)
        L = np.linalg.cholesky(np.linalg.inv(C))                         # (b, N, k, k)
        q, lg = _gauss_draw(qm, L, rng)
        lp = lik.point_log_density(p, q)
        for _ in range(n_mh):
            q2, lg2 = _gauss_draw(qm, L, rng)
            lp2 = lik.point_log_density(p, q2)
            log_r = (lp2 - lg2) - (lp - lg)
            accept = np.log(rng.random(log_r.shape)) < log_r
            q = np.where(accept[..., None], q2, q)
            lp = np.where(accept, lp2, lp)
            lg = np.where(accept, lg2, lg)
            acc.append(accept.mean())
        out[lo:lo + batch] = q
    return out, float(np.mean(acc)) if acc else float("nan")


def _gauss_draw(mean, L, rng):
    """Draw from N(mean, L L^T) per point; returns the draw and its log density + const."""
    z = rng.standard_normal(mean.shape)
    return mean + np.einsum("...ij,...j->...i", L, z), -0.5 * np.sum(z * z, axis=-1)
