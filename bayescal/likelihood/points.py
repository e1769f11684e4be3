"""The likelihood of laser pixels and approximate 3D points (one model for all fitters).

Data: laser pixels ``pixels`` (N, 2) and approximate points ``approx_points`` (N, 3).
Unknowns: the identifiable parameters ``theta`` (7,) and, per laser point, its scene
coordinates ``q_i = (x_i, y_i)`` (the horizontal position where the ray meets the
wall); the cone gives ``P_i = (x_i, y_i, rho_i / tan(beta) - h)``. The model (``docs/bayes.md``)::

    pixels_i        ~ N(project(theta, P_i), sigma_px^2 I_2)   (or sigma_px^2 pixel_cov_i)
    approx_points_i ~ N(P_i, diag(sigma_scene_i^2))       (inf = axis not used)

Each point contributes five whitened residuals (two pixel, three scene rows), with
analytic Jacobians, vectorized over leading axes (walkers) and the N points; the
least squares and both samplers call it (a misaligned cone: ``misaligned.py``).

Noise levels are given or inferred: ``sigma_px = None`` adds ``log sigma_px`` to the sampled
vector, ``sigma_scene = None`` adds ``log kappa`` with ``sigma_scene_i = kappa * rho_i``.
"""

from __future__ import annotations

import numpy as np

from .._validation import as_pixels, as_points, check_positive
from ..errors import InvalidTypeError, InvalidValueError
from ..sensor.camera import project_theta
from ..sensor.laser import cone_points_geo, triangulate_geo
from .outliers import OUTLIER_PRIOR, OUTLIER_SCALE, check_outlier_options, log_prior_logit_frac, mix
from .point_algebra import grad_terms, marginal_block, pixel_whitening, point_terms, whiten
from .point_blocks import clear_blocks, concat_blocks, sum_blocks
from .point_draws import draw_points  # re-exported: the point draws live beside the likelihood
from .scene_noise import scene_range

__all__ = ["LaserLikelihood", "POINT_PRIORS", "NOISE_BOUNDS", "OUTLIER_SCALE",
           "OUTLIER_PRIOR", "draw_points"]

#: log-uniform prior bounds of the inferred noise levels
NOISE_BOUNDS = {"sigma_px": (1e-3, 10.0), "kappa": (1e-4, 1.0)}

#: priors of the latent scene coordinates: see :class:`LaserLikelihood`
POINT_PRIORS = ("jeffreys", "flat")


_LOG2PI = np.log(2 * np.pi)


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
    pixel_cov : array_like, shape (N, 2, 2), optional
        Per-point pixel covariances (px^2); noise ``sigma_px^2 pixel_cov_i``, residuals
        whitened per point by ``L_i^T L_i = pixel_cov_i^-1`` (``docs/images.md``).
    outliers : bool
        If True, each point (its pixel and approximate point together) is an
        inlier with probability ``1 - w`` and an outlier with probability
        ``w``; an outlier's residuals have ``outlier_scale`` times the model's
        noise (a heavy-tailed scale mixture, ``docs/robustness.md``). ``w`` is
        an extra global, sampled as ``logit w`` under the name
        ``"outlier_frac"`` (after the noise levels). Default False here (the
        pure model); :func:`~bayescal.calibrate_simultaneous` turns it on.
    outlier_scale : float
        Noise inflation ``c > 1`` of the outlier component (default 100).
    outlier_prior : tuple of float
        ``(a, b)`` of the Beta prior of ``w`` (default (1, 19): mean 5 %).

    Attributes
    ----------
    n_noise : int
        Number of inferred noise parameters appended to ``theta`` (0, 1 or 2).
    n_geo : int
        Geometric unknowns: 7 (theta; the misaligned model's 11 add the pose).
    """

    n_geo = 7

    def __init__(self, pixels, approx_points, *, sigma_px, sigma_scene, point_prior="jeffreys",
                 outliers=False, outlier_scale=OUTLIER_SCALE, outlier_prior=OUTLIER_PRIOR,
                 pixel_cov=None):
        if point_prior not in POINT_PRIORS:
            raise InvalidValueError(f"point_prior must be in {POINT_PRIORS}, got {point_prior!r}")
        self.point_prior = point_prior
        self.outliers, self.outlier_scale, self.outlier_prior = check_outlier_options(
            outliers, outlier_scale, outlier_prior)
        self.pixels = as_pixels(pixels, "pixels")
        self.approx = as_points(approx_points, "approx_points")
        if self.pixels.ndim != 2 or self.approx.ndim != 2:
            raise InvalidValueError(f"pixels must have shape (N, 2) and approx_points (N, 3), got "
                                    f"{self.pixels.shape} and {self.approx.shape}")
        if len(self.pixels) != len(self.approx):
            raise InvalidValueError(f"pixels and approx_points must have the same length N, got "
                                    f"{len(self.pixels)} and {len(self.approx)}")
        self.n = len(self.pixels)
        self.infer_px = sigma_px is None
        self.infer_scene = sigma_scene is None
        self.sigma_px = None if self.infer_px else check_positive(sigma_px, "sigma_px")
        self.rho = np.hypot(self.approx[:, 0], self.approx[:, 1])
        if self.infer_scene:
            self.rho = scene_range(self.approx)
            self.w_scene = None
            self._scene_mask = np.ones((self.n, 3), bool)
        else:
            try:
                s = np.asarray(sigma_scene, dtype=float)
            except (TypeError, ValueError):
                raise InvalidTypeError(f"sigma_scene must be a float, an array or None, got "
                                       f"{type(sigma_scene).__name__}") from None
            if np.any(np.isnan(s)) or np.any(s <= 0):
                raise InvalidValueError("sigma_scene must be positive everywhere (inf allowed: no "
                                        f"information on that axis), got min {np.min(s)}")
            try:
                s = np.broadcast_to(s, (self.n, 3))
            except ValueError:
                raise InvalidValueError(f"sigma_scene must be a float or broadcastable to (N, 3)"
                                        f", got shape {np.shape(sigma_scene)}") from None
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
        self.px_white, self._px_log_det = pixel_whitening(pixel_cov, self.n)

    def __getstate__(self):
        state = self.__dict__.copy()        # the point blocks are a cache of views: rebuilt
        state.pop("_point_block_cache", None), state.pop("_marginal_columns", None)
        return state

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
        clear_blocks(self)                  # the blocks copied the old levels

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
        # every axis used when inferred; else a constant computed once
        log_w = np.log(w).sum(axis=-1) if self.infer_scene else self._log_w_given
        log_norm = (-2.0 * np.log(sig)[..., None] + log_w - 0.5 * self._n_rows * _LOG2PI
                    + self._px_log_det)
        return sig, w, log_norm

    @property
    def extra_names(self):
        """Names of the sampled coordinates after theta, in order (the "extra globals").

        The collapsed sampler works on ``psi = (theta, extra)``; any likelihood
        it samples provides ``n``, ``extra_names``, :meth:`log_prior_extra`,
        :meth:`laplace`, :meth:`point_log_density` and :meth:`points_3d`.
        Here the extras are ``log sigma_px`` and ``log kappa`` where inferred,
        then ``logit w`` (``"outlier_frac"``) with ``outliers=True``.
        """
        return self._noise_names()

    def _noise_names(self):
        return tuple(n for n, on in (("sigma_px", self.infer_px), ("kappa", self.infer_scene),
                                     ("outlier_frac", self.outliers)) if on)

    def log_prior_extra(self, extra):
        """Log prior density of the extra globals, shape (...); ``-inf`` outside the support.

        Each inferred noise level has a log-uniform prior on :data:`NOISE_BOUNDS`
        (flat in the sampled ``log`` value, up to a constant). The outlier
        fraction's Beta(a, b) prior, in the sampled ``logit w``, is
        ``w^a (1 - w)^b`` (Jacobian included; normalised).
        """
        extra = np.asarray(extra, dtype=float)
        lp = np.zeros(extra.shape[:-1])
        for k, name in enumerate(self._noise_names()):
            x = extra[..., k]
            if name == "outlier_frac":
                lp = lp + log_prior_logit_frac(x, self.outlier_prior)
                continue
            lo, hi = np.log(NOISE_BOUNDS[name])
            lp = np.where((x > lo) & (x < hi), lp, -np.inf)
        return lp

    def points_3d(self, psi, q):
        """3D points (..., N, 3), mm, of the scene coordinates ``q`` (..., N, 2) under ``psi``."""
        return cone_points_geo(np.asarray(psi, dtype=float)[..., None, :self.n_geo], q)

    def split(self, psi):
        """Split a sampled vector ``(..., n_geo + n_extra)`` into the geometry and the rest."""
        psi = np.asarray(psi, dtype=float)
        return psi[..., :self.n_geo], psi[..., self.n_geo:]

    # -- residuals -----------------------------------------------------------
    def residuals(self, theta, q, sigma_px, w_scene, *, jacobian=False):
        """Whitened residuals of every point.

        Parameters
        ----------
        theta : ndarray, shape (..., n_geo)
            The geometry: theta (7), then the laser pose with the misaligned model.
        q : ndarray, shape (..., N, 2)
            Scene coordinates (x, y) of the points, mm.
        sigma_px : ndarray, shape (...)
        w_scene : ndarray, shape (..., N, 3)
        jacobian : bool

        Returns
        -------
        R : ndarray, shape (..., N, 5)
            Two pixel rows, three scene rows (0 where unused); NaN outside the domain.
        J_theta, J_q : ndarray, shapes (..., N, 5, n_geo) and (..., N, 5, 2)
            Only with ``jacobian=True``.
        """
        g = np.asarray(theta, dtype=float)[..., None, :]
        if not jacobian:
            P = cone_points_geo(g, q)
            uv, _ = project_theta(g[..., :7], P)
        else:
            P, dxy, dgc = cone_points_geo(g, q, jacobian=True)
            uv, _, dPp, dthp = project_theta(g[..., :7], P, jacobian=True)
        inv_s = 1.0 / np.asarray(sigma_px)[..., None, None]
        shape = uv.shape[:-1]
        R = np.empty(shape + (5,))
        R[..., :2] = whiten(self.px_white, (uv - self.pixels) * inv_s)
        R[..., 2:] = (P - self.approx) * w_scene
        if not jacobian:
            return R
        Jq = np.empty(shape + (5, 2))
        Jq[..., :2, :] = whiten(self.px_white, (dPp @ dxy) * inv_s[..., None], axis=-2)
        Jq[..., 2:, :] = dxy * w_scene[..., :, None]
        dpix = dPp @ dgc                                    # through the cone point
        dpix[..., :7] += dthp                               # and the camera directly
        Jt = np.empty(shape + (5, self.n_geo))
        Jt[..., :2, :] = whiten(self.px_white, dpix * inv_s[..., None], axis=-2)
        Jt[..., 2:, :] = dgc * w_scene[..., :, None]
        return R, Jt, Jq

    # -- per-point Laplace step ----------------------------------------------
    def initial_q(self, theta):
        """A starting value of the scene coordinates: the approximate points' (x, y),
        or the triangulated pixels where no scene information is given in x/y."""
        q = self.approx[:, :2].copy()
        if not self.infer_scene:
            blind = ~self._scene_mask[:, :2].all(axis=1)
            if np.any(blind):
                P, ok = triangulate_geo(np.asarray(theta, float), self.pixels[blind])
                q[blind] = np.where(ok[:, None], P[:, :2], q[blind])
        return q

    def _point_terms(self, theta, x, y, sig, w):
        """Hot path of :meth:`laplace` (:func:`~bayescal.likelihood.point_algebra.point_terms`)."""
        return point_terms(self, theta, x, y, sig, w)

    def _log_point_prior(self, extra, sig, Cp, Cs):
        """log of the points' prior density at the current q, shape (..., N).

        Flat prior: 0. Jeffreys prior: ``log |C_ref|^(1/2)`` with ``C_ref`` the
        points' information at the reference noise levels.
        """
        if self.point_prior == "flat":
            return 0.0
        sp = (np.asarray(sig) / self.ref_sigma_px)[..., None] ** 2
        if self.infer_scene:
            kappa = np.exp(extra[..., int(self.infer_px)])
            ss = (kappa / self.ref_kappa)[..., None] ** 2
        else:
            ss = 1.0
        c00, c01, c11 = (p * sp + q * ss for p, q in zip(Cp, Cs, strict=True))
        return 0.5 * np.log(c00 * c11 - c01 * c01)

    def laplace(self, psi, q0, *, n_iter=4):
        """Integrate each point's scene coordinates out by a Gauss-Newton/Laplace step.

        Parameters
        ----------
        psi : ndarray, shape (..., 7 + n_extra)
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
            is the profile likelihood plus a constant. With ``outliers=True``
            each point's term is ``log((1 - w) L_in + w L_out)``.
        q : ndarray, shape (..., N, 2)
            Conditional modes (both mixture components share them).
        C : ndarray, shape (..., N, 2, 2)
            Conditional precision matrices ``J_q^T J_q`` (inverse = covariance);
            with outliers, that of the moment-matched scale mixture,
            ``J_q^T J_q / ((1 - r) + r c^2)`` with ``r`` the outlier probability.
        """
        per_point, x, y, C00, C01, C11, r = self._laplace_points(psi, q0, n_iter)
        total = per_point.sum(axis=-1)
        if r is not None:
            f = 1.0 / ((1.0 - r) + r * self.outlier_scale**2)
            C00, C01, C11 = C00 * f, C01 * f, C11 * f
        C = np.stack([np.stack([C00, C01], -1), np.stack([C01, C11], -1)], -2)
        return np.where(np.isfinite(total), total, -np.inf), np.stack([x, y], -1), C

    def log_marginal(self, psi, q0, *, n_iter=4):
        """:meth:`laplace`'s first output alone, shape (...) for ``psi`` (..., 7 + n_extra)
        and ``q0`` (..., N, 2) or (N, 2): the sampler's target, without per-point arrays."""
        total = sum_blocks(self, "_marginal_block", psi, q0, n_iter)[0]
        return np.where(np.isfinite(total), total, -np.inf)

    def _marginal_block(self, psi, q0, n_iter):
        return marginal_block(self, psi, q0, n_iter)        # the aligned cone: fused passes

    def outlier_prob(self, psi, q0, *, n_iter=4):
        """Probability that each point is an outlier given ``psi``, shape (..., N).

        ``w L_out / ((1 - w) L_in + w L_out)`` with the points integrated out (the Laplace
        step of :meth:`laplace`); NaN outside the model's domain. Needs ``outliers=True``."""
        if not self.outliers:
            raise InvalidValueError("outlier_prob needs a likelihood built with outliers=True")
        return self._laplace_points(psi, q0, n_iter)[-1]

    def min_residual(self, psi, q0, *, n_iter=4):
        """Each point's squared whitened residual norm at its conditional mode, (..., N).

        ``min_q |R_i(theta, q)|^2`` (Gauss-Newton, the quadratic model's remaining decrease
        included): about chi-square with ``n_rows - 2`` degrees of freedom for an inlier at
        the true parameters; NaN outside the domain."""
        theta, extra = self.split(psi)
        sig, w, _ = self.noise(extra)
        with np.errstate(invalid="ignore", divide="ignore"):
            g = self._gauss_newton(theta, q0, sig, w, n_iter)
            return g["rr"] - g["gd"]

    def _gauss_newton(self, theta, q0, sig, w, n_iter):
        """Gauss-Newton on every point's q; the terms at the last iterate, as a dict."""
        q = np.broadcast_to(q0, theta.shape[:-1] + (self.n, 2))
        x, y = q[..., 0].copy(), q[..., 1].copy()
        for it in range(n_iter + 1):
            rr, Cp, Cs, g0, g1 = self._point_terms(theta, x, y, sig, w)
            C00, C01, C11 = (p + q for p, q in zip(Cp, Cs, strict=True))
            det = C00 * C11 - C01 * C01
            d0 = (C11 * g0 - C01 * g1) / det
            d1 = (C00 * g1 - C01 * g0) / det
            if it < n_iter:
                x, y = x - d0, y - d1
        return {"x": x, "y": y, "rr": rr, "Cp": Cp, "Cs": Cs, "C": (C00, C01, C11),
                "det": det, "gd": g0 * d0 + g1 * d1}

    def _laplace_points(self, psi, q0, n_iter):
        """Per-point terms of :meth:`laplace`, in cache-sized blocks of points."""
        return concat_blocks(self, "_laplace_block", psi, q0, n_iter)

    def _laplace_block(self, psi, q0, n_iter):
        theta, extra = self.split(psi)
        sig, w, log_norm = self.noise(extra)
        r = None
        with np.errstate(invalid="ignore", divide="ignore"):
            g = self._gauss_newton(theta, q0, sig, w, n_iter)
            per_point = (-0.5 * g["rr"] + 0.5 * g["gd"] - 0.5 * np.log(g["det"]) + _LOG2PI
                         + log_norm + self._log_point_prior(extra, sig, g["Cp"], g["Cs"]))
            if self.outliers:
                per_point, r = mix(extra[..., -1], per_point, g["rr"] - g["gd"], self._n_rows,
                                   self.outlier_scale, laplace=True)
        return (per_point, g["x"], g["y"]) + g["C"] + (r,)

    def grad_log_marginal(self, psi, q0, *, n_iter=4):
        """:meth:`laplace`'s log marginal and its gradient in ``psi`` (envelope theorem).

        With the Jeffreys point prior and given noise the log marginal is the
        profile likelihood, its gradient ``-sum_i J_theta_i^T R_i`` at the modes.
        Inferred noise adds its analytic derivatives, the mixture its weights
        (:func:`~bayescal.likelihood.point_algebra.grad_terms`); the log-determinants' theta
        dependence away from the reference noise is left out: approximate,
        fine for HMC, whose acceptance test uses the exact value.

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
        total, grad = sum_blocks(self, "_grad_block", psi, q0, n_iter)
        value = np.where(np.isfinite(total), total, -np.inf)
        return value, np.where(np.isfinite(value)[..., None], grad, np.nan)

    def _grad_block(self, psi, q0, n_iter):
        """One block's sum of the log marginal's per-point terms and its gradient (the
        aligned cone: fused, :func:`~.point_algebra.marginal_block`, the value __call__'s)."""
        fused = marginal_block(self, psi, q0, n_iter, gradient=True)
        if fused is not None:
            return fused
        per_point, x, y, *_, r = self._laplace_block(psi, q0, n_iter)   # one pass: laplace's
        theta, extra = self.split(psi)
        lw = extra[..., -1] if self.outliers else None
        sig, w, _ = self.noise(extra)
        with np.errstate(invalid="ignore", divide="ignore"):
            _, Cp, Cs, g0, g1 = self._point_terms(theta, x, y, sig, w)
            C00, C01, C11 = (a + b for a, b in zip(Cp, Cs, strict=True))
            det = C00 * C11 - C01 * C01
            x, y = x - (C11 * g0 - C01 * g1) / det, y - (C00 * g1 - C01 * g0) / det  # modes
            return per_point.sum(axis=-1), grad_terms(self, theta, x, y, sig, w,
                                                      outlier_resp=r, logit_w=lw)

    def _exact_terms(self, psi, q):
        """Per-point exact log density of (data, q) given psi, normalisers included."""
        return concat_blocks(self, "_exact_block", psi, q)[0]

    def _exact_block(self, psi, q):
        theta, extra = self.split(psi)
        sig, w, log_norm = self.noise(extra)
        with np.errstate(invalid="ignore", divide="ignore"):
            rr, Cp, Cs, _, _ = self._point_terms(theta, q[..., 0], q[..., 1], sig, w)
            per_point = -0.5 * rr + self._log_point_prior(extra, sig, Cp, Cs) + log_norm
            if self.outliers:
                per_point, _ = mix(extra[..., -1], per_point, rr, self._n_rows,
                                   self.outlier_scale, laplace=False)
        return (per_point,)

    def log_joint(self, psi, q):
        """Exact log density of ``(psi, q)`` (likelihood times point prior), shape (...).

        Used by the brute-force joint sampler that validates the collapsed one.
        """
        total = np.sum(self._exact_terms(psi, q), axis=-1)
        return np.where(np.isfinite(total), total, -np.inf)

    def point_log_density(self, psi, q):
        """Per-point exact log density of ``q`` given ``psi`` (up to constants), (..., N).

        With ``outliers=True`` it is the density of the mixture (both
        components over the same q), the target of the point draws.
        """
        out = self._exact_terms(psi, q)
        return np.where(np.isfinite(out), out, -np.inf)

