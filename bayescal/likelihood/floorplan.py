"""The floor-plan likelihood: laser pixels of points on uncertain walls.

Unknowns: the identifiable parameters ``theta`` (7), the wall parameters ``(d_k, a_k)`` of a
:class:`~bayescal.scene.floorplan.FloorPlan` (``2W``) and, per laser point, its azimuth
``t_i`` (one coordinate: the point lies on its wall *and* on the cone)::

    P_i = (rho cos t_i, rho sin t_i, rho / tan(beta) - h),  rho = d_k / cos(t_i - a_k)
    pixels_i ~ N(project(theta, P_i), sigma_px^2 I_2)   (or sigma_px^2 pixel_cov_i)

**Which wall.** Corner ``j`` (the intersection of wall lines ``j`` and
``j + 1``) sits at azimuth ``c_j(d, a)``; a point at azimuth ``t < c_j`` is on
wall ``j``, beyond it on wall ``j + 1``. Each point is given the two walls
around the plan corner nearest to its pixel's azimuth, and its latent azimuth
is integrated over *both* pieces with the corner where the current wall
parameters put it::

    p(pixel_i | psi) = int_{t < c_j} p_j(pixel_i | t) pi(t) dt + int_{t > c_j} p_{j+1}(...)

Each piece is a Laplace integral truncated at the corner (a normal CDF): a point near
a corner moves to the neighbouring wall smoothly as the walls move; the exact model to
the Laplace approximation's order, not a mixture with arbitrary weights (``docs/floorplan.md``).

**Point prior.** Jeffreys, ``pi(t | psi) ∝ |J_t^T J_t|^(1/2)`` (at a reference noise
when ``sigma_px`` is inferred), as in :class:`~bayescal.likelihood.points.LaserLikelihood`
(a flat prior biases, Neyman-Scott, ``docs/bayes.md``); the Laplace step is then the
profile likelihood.

**Per-point pixel covariances** (``pixel_cov``, e.g. from
:func:`bayescal.extract_laser`): the noise of pixel i is ``sigma_px^2 pixel_cov_i``;
each point's two pixel rows (residuals and derivatives) are whitened by ``L_i`` with
``L_i^T L_i = pixel_cov_i^-1`` (:func:`~bayescal.likelihood.point_algebra.pixel_whitening`)
and ``log det L_i`` joins the normaliser; ``sigma_px`` is then a scale on them.

**Outliers** (``outliers=True``): each point is an inlier with probability ``1 - w``
or an outlier whose pixel rows have ``c`` times the noise, ``log[(1 - w) L_in + w L_out]``;
the outlier reuses each piece's ``rr*``, ``H / C`` and ``C``, untruncated and weighted by
the inlier's piece shares (the formula and why: ``docs/robustness.md``, "Floor plans").

The class follows the collapsed sampler's protocol: ``psi = (theta, d_0, a_0, ..., d_{W-1},
a_{W-1}[, log sigma_px][, logit w])``, ``q`` of shape ``(..., N, 1)``; with a misaligned cone,
the pose after theta (:mod:`bayescal.likelihood.plan_misaligned`).
"""

from __future__ import annotations

import numpy as np
from scipy.special import log_ndtr

from .._validation import as_pixels, check_positive
from ..errors import InvalidTypeError, InvalidValueError
from ..scene.floorplan import FloorPlan, corner_azimuths, plan_point, wrap_angle
from ..sensor.camera import project_theta
from ..sensor.laser import pixel_azimuth
from ..sensor.parameters import SensorParams
from .outliers import (
    OUTLIER_PRIOR,
    OUTLIER_SCALE,
    check_outlier_options,
    combine,
    log_prior_logit_frac,
)
from .point_algebra import pixel_whitening, whiten, whiten_pair
from .points import NOISE_BOUNDS

__all__ = ["PlanLikelihood"]

_LOG2PI = np.log(2 * np.pi)
MAX_STEP = 0.1     #: largest Gauss-Newton step of a point's azimuth, rad


class PlanLikelihood:
    """Pixel likelihood of N laser points on the walls of a rough floor plan.

    Parameters
    ----------
    pixels : array_like, shape (N, 2)
        Laser pixels ``(u, v)``, px.
    plan : FloorPlan
    sigma_px : float or None
        Pixel noise sd, px; ``None`` = inferred (``log sigma_px`` is the last
        sampled coordinate, log-uniform prior on ``NOISE_BOUNDS["sigma_px"]``).
        With ``pixel_cov``, a scale on the covariances (1.0: as they are).
    pixel_cov : array_like, shape (N, 2, 2), optional
        Per-point pixel covariances, px^2 (symmetric positive definite); noise
        ``sigma_px^2 pixel_cov_i``, each point's pixel rows whitened by ``L_i``.
    azimuth_params : SensorParams, optional
        Sensor used to compute the pixels' azimuths that pick each point's
        candidate walls (only ``u0``, ``v0`` and the signs of ``alpha`` matter);
        default the paper's design values. The choice is robust: a point's
        candidates only need to contain its wall.
    outliers : bool
        Per-point outlier mixture (default False here; the calibration and
        sampling functions default to True); ``logit w`` is then the last
        sampled coordinate (``"outlier_frac"``, Beta prior ``outlier_prior``).
    outlier_scale : float
        Noise inflation ``c > 1`` of the outlier component (default 100).
    outlier_prior : tuple of float
        Beta(a, b) prior of the outlier fraction ``w`` (default (1, 19)).

    Attributes
    ----------
    n : int
        Number of points N.
    wall_pair : ndarray of int, shape (N, 2)
        The two candidate walls ``(j, j + 1)`` of each point.
    corner : ndarray of int, shape (N,)
        The corner ``j`` between them.
    reference_range : float or None
        Median horizontal range (mm) of the MAP's points, set by
        :func:`bayescal.fit.plan_start.plan_map_start` (``docs/floorplan.md`` section 8).
    em_weights : ndarray, shape (N,), or None
        The least squares' EM weights ``(1 - r) + r / c^2`` of each point's pixel
        rows (set by :mod:`bayescal.fit.floorplan`; None = unit weights).
    """

    n_geo = 7      #: geometric unknowns at the start of psi (11 with the laser pose)

    def __init__(self, pixels, plan, *, sigma_px, azimuth_params=None, outliers=False,
                 outlier_scale=OUTLIER_SCALE, outlier_prior=OUTLIER_PRIOR, pixel_cov=None):
        if not isinstance(plan, FloorPlan):
            raise InvalidTypeError(f"plan must be a FloorPlan, got {type(plan).__name__}")
        self.pixels = as_pixels(pixels, "pixels")
        if self.pixels.ndim != 2:
            raise InvalidValueError(f"pixels must have shape (N, 2), got {self.pixels.shape}")
        self.plan = plan
        self.n = len(self.pixels)
        self.n_walls = plan.n_walls
        self.px_white, self._px_log_det = pixel_whitening(pixel_cov, self.n)
        self.pixel_cov = None if pixel_cov is None else np.asarray(pixel_cov, float)
        self.infer_px = sigma_px is None
        self.sigma_px = None if self.infer_px else check_positive(sigma_px, "sigma_px")
        self.ref_sigma_px = 1.0 if self.infer_px else self.sigma_px
        ap = SensorParams.paper() if azimuth_params is None else azimuth_params
        self.assign(ap)
        self._prior_mu, self._prior_sd = plan.param_nominal, plan.param_sd
        self.reference_range = None
        self.primary, self.near = None, None
        self.outliers, self.outlier_scale, self.outlier_prior = check_outlier_options(
            outliers, outlier_scale, outlier_prior)
        self.em_weights = None

    def assign(self, params, walls=None):
        """(Re)choose each point's candidate walls from its pixel azimuth under ``params``.

        ``walls`` (W, 2) places the corners (default: the plan's); the least
        squares re-assigns at its MAP, where the corners are known far better
        than from the plan.
        """
        az = pixel_azimuth(params, self.pixels)
        corners = (self.plan.corner_azimuths() if walls is None
                   else corner_azimuths(walls[:, 0], walls[:, 1]))
        j = np.argmin(np.abs(wrap_angle(az[:, None] - corners[None, :])), axis=1)
        self.corner = j
        self.wall_pair = np.stack([j, (j + 1) % self.n_walls], axis=1)
        self.primary, self.near = None, None            # both pieces for every point

    def restrict_pieces(self, psi, *, log_tol=-40.0):
        """Integrate only the wall a point is on, except for points near a corner.

        A point far from its corner has, on the other wall, a piece whose share of
        ``p(pixel_i | psi)`` is below ``exp(log_tol)`` at every ``psi`` (..., d) given
        (draws spanning the posterior well beyond its spread); :meth:`laplace` then
        skips that piece (a relative error below ``exp(log_tol)`` in the point's
        likelihood), which halves the sampler's cost. Points whose other piece
        matters anywhere in ``psi`` keep both.

        Sets ``primary`` (N,) of 0/1 (the dominant piece) and ``near`` (indices of the
        points that keep both); returns the number of such points.
        """
        self.primary, self.near = None, None
        logm = self._pieces(np.atleast_2d(psi), n_iter=2)[0]
        share = logm[1] - logm[0]                                  # (S, N)
        primary = (np.nanmedian(share, axis=0) > 0).astype(int)
        other = np.where(primary == 1, -share, share)
        other = np.where(np.isnan(other), -np.inf, other)     # psi outside the model's domain
        near = np.flatnonzero(np.max(other, axis=0) > log_tol)
        self.primary, self.near = primary, near
        return len(near)

    def set_reference_noise(self, *, sigma_px=None):
        """Pixel noise at which the Jeffreys prior is evaluated (inferred noise only)."""
        if sigma_px is not None:
            self.ref_sigma_px = check_positive(sigma_px, "sigma_px")

    # -- protocol --------------------------------------------------------------
    @property
    def extra_names(self):
        """Sampled coordinates after theta: the wall parameters, then ``sigma_px`` if inferred,
        then ``outlier_frac`` (sampled as ``logit w``) with the mixture."""
        return (self.plan.param_names + (("sigma_px",) if self.infer_px else ())
                + (("outlier_frac",) if self.outliers else ()))

    def split(self, psi):
        """``psi (..., n_geo + 2W [+1] [+1])`` -> theta (..., n_geo: 7, or 11 with the pose),
        walls (..., W, 2), sigma_px (...)."""
        psi = np.asarray(psi, dtype=float)
        theta, k = psi[..., :self.n_geo], self.n_geo + 2 * self.n_walls
        walls = psi[..., self.n_geo:k].reshape(psi.shape[:-1] + (self.n_walls, 2))
        sig = np.exp(psi[..., k]) if self.infer_px else np.full(psi.shape[:-1], self.sigma_px)
        return theta, walls, sig

    def logit_frac(self, psi):
        """``logit w`` (...) of ``psi`` (the last coordinate); needs ``outliers=True``."""
        if not self.outliers:
            raise InvalidValueError("the outlier fraction needs a likelihood with outliers=True")
        return np.asarray(psi, dtype=float)[..., -1]

    def log_prior_extra(self, extra):
        """Log prior of the extras (walls normal from the plan, noise log-uniform), (...)."""
        extra = np.asarray(extra, dtype=float)
        w = extra[..., :2 * self.n_walls]
        z = (w - self._prior_mu) / self._prior_sd
        lp = np.sum(-0.5 * z * z - np.log(self._prior_sd) - 0.5 * _LOG2PI, axis=-1)
        lp = np.where(np.all(w[..., 0::2] > 0, axis=-1), lp, -np.inf)
        if self.infer_px:
            lo, hi = np.log(NOISE_BOUNDS["sigma_px"])
            x = extra[..., 2 * self.n_walls]
            lp = np.where((x > lo) & (x < hi), lp, -np.inf)
        if self.outliers:
            lp = lp + log_prior_logit_frac(extra[..., -1], self.outlier_prior)
        return lp

    # -- geometry ----------------------------------------------------------------
    def _pair_walls(self, walls):
        """Candidate walls' (d, a), each (..., N, 2), and the corner azimuth (..., N)."""
        d, a = walls[..., 0], walls[..., 1]
        c = corner_azimuths(d, a)[..., self.corner]
        dd, aa = d[..., self.wall_pair], a[..., self.wall_pair]
        return dd, aa, c

    def _side(self, t, c):          # 0 where azimuth t is before corner c (first wall), 1 after
        return (wrap_angle(t - c) > 0).astype(int)

    def points_3d(self, psi, q):
        """3D points (..., N, 3), mm, of azimuths ``q`` (..., N, 1) under ``psi``."""
        theta, walls, _ = self.split(psi)
        dd, aa, c = self._pair_walls(walls)
        t = np.asarray(q, dtype=float)[..., 0]
        s = self._side(t, c) == 1
        d, a = np.where(s, dd[..., 1], dd[..., 0]), np.where(s, aa[..., 1], aa[..., 0])
        return plan_point(theta[..., None, :], t, d, a)

    def wall_index(self, psi, q):
        """Wall (0..W-1) each point lies on under ``psi``, shape (..., N)."""
        _, walls, _ = self.split(psi)
        _, _, c = self._pair_walls(walls)
        s = self._side(np.asarray(q, dtype=float)[..., 0], c)
        return np.where(s == 0, self.wall_pair[:, 0], self.wall_pair[:, 1])

    # -- hot path ------------------------------------------------------------------
    def _pixel_terms(self, theta, t, d, ca, sa):
        """Predicted pixel (u, v) and d(u, v)/dt, elementwise, each (..., N).

        The wall enters by ``d`` and ``cos a``, ``sin a`` (computed once per wall, not
        per point): ``cos(t - a)`` and ``sin(t - a)`` by the angle-addition formulas,
        two transcendental calls per evaluation instead of four.
        """
        xi, gu, gv, u0, v0 = (theta[..., k, None] for k in range(5))
        ct, st = np.cos(t), np.sin(t)
        c = ct * ca + st * sa                                  # cos(t - a)
        ic = np.where(c > 0, 1.0 / c, np.nan)                  # NaN: the ray misses the wall
        rho = d * ic
        r_t = rho * (st * ca - ct * sa) * ic                   # rho tan(t - a)
        x, y = rho * ct, rho * st
        dx, dy = r_t * ct - y, r_t * st + x
        z, dz = self._height(theta, rho, r_t, x, y, dx, dy)
        r = np.sqrt(x * x + y * y + z * z)
        D = xi * r - z
        iD = np.where(D > 0, 1.0 / D, np.nan)
        mx, my = x * iD, y * iD
        dD = xi * (x * dx + y * dy + z * dz) / r - dz
        return (gu * mx + u0, gv * my + v0, gu * (dx - mx * dD) * iD,
                gv * (dy - my * dD) * iD)

    def _height(self, theta, rho, r_t, x, y, dx, dy):
        """The cone's height ``z`` (..., N) over the wall point and ``dz/dt``: aligned cone."""
        it = 1.0 / np.tan(theta[..., 6, None])
        return rho * it - theta[..., 5, None], r_t * it

    def _fit_piece(self, theta, t, d, ca, sa, n_iter, h=1e-5, sel=slice(None)):
        """Gauss-Newton on each point's azimuth on one wall (unit noise).

        Returns ``rr*`` (squared residual at the mode), ``t*``, ``C = J^T J`` and
        ``log(H / C)``, ``H = C + r . r''`` the full Hessian (second derivative by
        a forward difference of step ``h`` rad): Gauss-Newton's ``C`` alone left
        a 0.003-nat error per point, the full Hessian's Laplace step ~1e-4. Steps are
        clipped at ``MAX_STEP`` rad (loose along-ring ``pixel_cov``: ``docs/images.md``).
        """
        pu, pv = self.pixels[sel, 0], self.pixels[sel, 1]
        white = None if self.px_white is None else self.px_white[sel]
        for it in range(n_iter + 1):
            u, v, du, dv = self._pixel_terms(theta, t, d, ca, sa)
            ru, rv = whiten_pair(white, u - pu, v - pv)
            du, dv = whiten_pair(white, du, dv)
            C = du * du + dv * dv
            g = du * ru + dv * rv
            full = g / C
            step = np.clip(full, -MAX_STEP, MAX_STEP)
            if it == n_iter:
                break
            t = t - step
        # remaining gain of the quadratic model (of the clipped step where clipped)
        rr = ru * ru + rv * rv + np.where(step == full, -g * step, (C * step - 2 * g) * step)
        du2, dv2 = whiten_pair(white, *self._pixel_terms(theta, t + h, d, ca, sa)[2:])
        H = C + (ru * (du2 - du) + rv * (dv2 - dv)) / h
        return rr, t - step, C, np.log(np.where(H > 0, H / C, 1.0))

    def _start(self, theta):
        """Pixel azimuth under each walker's theta (exact for noise-free pixels), (..., N)."""
        xi, gu, gv, u0, v0 = (theta[..., k, None] for k in range(5))
        return np.arctan2((self.pixels[:, 1] - v0) / gv, (self.pixels[:, 0] - u0) / gu)

    def laplace(self, psi, q0=None, *, n_iter=2):
        """Integrate each point's azimuth out (two truncated Laplace pieces per point).

        Parameters
        ----------
        psi : ndarray, shape (..., 7 + 2W [+ 1])
        q0 : ignored
            Accepted for the protocol; the start is each pixel's azimuth under
            the walker's theta, which is exact up to pixel noise.
        n_iter : int
            Gauss-Newton iterations per piece.

        Returns
        -------
        log_marginal : ndarray, shape (...)
            ``sum_i log p(pixels_i | psi)`` with the azimuths integrated out;
            ``-inf`` outside the model's domain.
        q : ndarray, shape (..., N, 1)
            Mode of the dominant piece, rad.
        C : ndarray, shape (..., N, 1, 1)
            Its precision ``J_t^T J_t / sigma_px^2``, rad^-2; with outliers, that of
            the moment-matched scale mixture, ``C / ((1 - r) + r c^2)`` with ``r``
            the point's outlier probability.
        """
        per_point, q, C, r = self._mixture(psi, n_iter)
        if r is not None:
            C = C / ((1.0 - r) + r * self.outlier_scale**2)
        total = per_point.sum(axis=-1)
        return np.where(np.isfinite(total), total, -np.inf), q, C[..., None, None]

    def laplace_per_point(self, psi, *, n_iter=2):
        """Per-point terms of :meth:`laplace`: ``log p(pixels_i | psi)`` (..., N), q, C.

        With outliers the term is the mixture's and ``C`` the inlier precision.
        """
        per_point, q, C, _ = self._mixture(psi, n_iter)
        return per_point, q, C[..., None, None]

    def outlier_prob(self, psi, q=None, *, n_iter=2):
        """Probability that each point is an outlier given ``psi``, shape (..., N).

        ``w L_out / ((1 - w) L_in + w L_out)`` with the azimuths integrated out (as
        in :meth:`laplace`); NaN where a point leaves the model's domain. ``q`` is
        accepted for the protocol and ignored (the start is the pixel's azimuth).
        Requires ``outliers=True``.
        """
        if not self.outliers:
            raise InvalidValueError("outlier_prob needs a likelihood built with outliers=True")
        return self._mixture(psi, n_iter)[-1]

    def _mixture(self, psi, n_iter, pieces=None):
        """Per-point log marginal (..., N), dominant mode (..., N, 1), its inlier precision
        (..., N) and the outlier probability (..., N) (None without the mixture)."""
        _, _, sig = self.split(psi)
        logm, ts, Cs, lo = self._pieces(psi, n_iter=n_iter) if pieces is None else pieces
        # Laplace: sqrt(2 pi / C); Jeffreys prior: sqrt(C_ref); pixel normaliser
        norm = (-np.log(sig[..., None]) - np.log(self.ref_sigma_px) - 0.5 * _LOG2PI
                + self._px_log_det)
        with np.errstate(invalid="ignore"):
            m = np.logaddexp(logm[0], logm[1])
            per_point, r = m + norm, None
            if self.outliers:
                # untruncated outlier pieces weighted by the inlier's piece shares (module doc)
                lout = (np.logaddexp(logm[0] - m + lo[0], logm[1] - m + lo[1])
                        - np.log(self.outlier_scale) + norm)
                per_point, r = combine(self.logit_frac(psi)[..., None], per_point, lout)
        pick = logm[1] > logm[0]
        return per_point, np.where(pick, ts[1], ts[0])[..., None], np.where(pick, Cs[1], Cs[0]), r

    def _pieces(self, psi, *, n_iter):
        """Each point's two truncated Laplace pieces: log masses, modes, precisions, and the
        outlier's untruncated log masses (up to the shared constants).

        Each is a pair (piece on wall ``wall_pair[:, 0]``, on ``wall_pair[:, 1]``) of
        arrays (..., N). After :meth:`restrict_pieces`, the non-primary piece is
        computed for the ``near`` points only (``-inf`` mass elsewhere).
        """
        theta, walls, sig = self.split(psi)
        dd, aa, c = self._pair_walls(walls)
        ca, sa = (f(walls[..., 1])[..., self.wall_pair] for f in (np.cos, np.sin))
        t0 = self._start(theta)
        inv_s2 = (1.0 / sig**2)[..., None]
        if self.primary is None:
            return self._piece_pair(theta, t0, dd, ca, sa, c, inv_s2, n_iter)
        idx = np.arange(self.n)
        p, near = self.primary, self.near
        out = self._piece(theta, t0, dd[..., idx, p], ca[..., idx, p], sa[..., idx, p], c,
                          inv_s2, n_iter, sign=2 * p - 1, sel=slice(None))
        q = 1 - p[near]
        other = self._piece(theta, t0[..., near], dd[..., near, q], ca[..., near, q],
                            sa[..., near, q], c[..., near], inv_s2, n_iter, sign=2 * q - 1,
                            sel=near)
        full = [np.full_like(out[0], -np.inf), np.full_like(out[0], np.nan),
                np.full_like(out[0], np.nan), np.full_like(out[0], -np.inf)]
        for f, o in zip(full, other, strict=True):
            f[..., near] = o
        return tuple((np.where(p == 0, a, b), np.where(p == 0, b, a))
                     for a, b in zip(out, full, strict=True))

    def _piece_pair(self, theta, t0, dd, ca, sa, c, inv_s2, n_iter):
        both = [self._piece(theta, t0, dd[..., s], ca[..., s], sa[..., s], c, inv_s2, n_iter,
                            sign=2 * s - 1, sel=slice(None)) for s in (0, 1)]
        return tuple(zip(*both, strict=True))

    def _piece(self, theta, t0, d, ca, sa, c, inv_s2, n_iter, *, sign, sel):
        """One truncated Laplace piece per point (pixels ``sel``): log mass, mode, precision,
        and the outlier's untruncated log mass ``-rr / (2 c^2 sigma^2) - log(H / C) / 2``."""
        with np.errstate(invalid="ignore", divide="ignore"):
            rr, ts_, C, lhc = self._fit_piece(theta, t0, d, ca, sa, n_iter, sel=sel)
            side = wrap_angle(ts_ - c) * sign                       # > 0 inside the piece
            lm = (-0.5 * rr * inv_s2 - 0.5 * lhc
                  + log_ndtr(side * np.sqrt(C * np.exp(lhc) * inv_s2)))
            # the outlier's mass only with the mixture (the sampler's hot path otherwise)
            lo = (-0.5 * rr * inv_s2 / self.outlier_scale**2 - 0.5 * lhc) if self.outliers \
                else lm
        return (np.where(np.isfinite(lm), lm, -np.inf), ts_, C * inv_s2,
                np.where(np.isfinite(lm), lo, -np.inf))

    def point_log_density(self, psi, q):
        """Exact per-point log density of the azimuths ``q`` (..., N, 1) given ``psi`` (..., N).

        Likelihood times Jeffreys prior, up to a constant per point (used by the
        sampler's independence Metropolis-Hastings correction of point draws). With
        outliers, the mixture ``(1 - w) N(sigma) + w N(c sigma)`` of the two pixel
        rows (the outlier's normaliser ``c^-2`` included).
        """
        theta, walls, sig = self.split(psi)
        dd, aa, c = self._pair_walls(walls)
        t = np.asarray(q, dtype=float)[..., 0]
        s = self._side(t, c) == 1
        d, a = np.where(s, dd[..., 1], dd[..., 0]), np.where(s, aa[..., 1], aa[..., 0])
        with np.errstate(invalid="ignore", divide="ignore"):
            u, v, du, dv = self._pixel_terms(theta, t, d, np.cos(a), np.sin(a))
            ru, rv = whiten_pair(self.px_white, u - self.pixels[:, 0], v - self.pixels[:, 1])
            du, dv = whiten_pair(self.px_white, du, dv)
            rr = ru * ru + rv * rv
            lin = -0.5 * rr / sig[..., None] ** 2
            if self.outliers:
                c = self.outlier_scale
                lin = combine(self.logit_frac(psi)[..., None], lin, lin / c**2 - 2 * np.log(c))[0]
            out = lin + 0.5 * np.log((du * du + dv * dv)) - np.log(self.ref_sigma_px)
        return np.where(np.isfinite(out), out, -np.inf)

    # -- least-squares form ----------------------------------------------------------
    def residuals(self, theta, walls, t, wall_idx, sigma_px, *, jacobian=False):
        """Whitened pixel residuals of points at azimuths ``t`` on walls ``wall_idx``.

        Parameters
        ----------
        theta : ndarray, shape (n_geo,)
        walls : ndarray, shape (W, 2)
            ``(d_k, a_k)`` per wall.
        t : ndarray, shape (N,)
            Azimuths, rad.
        wall_idx : ndarray of int, shape (N,)
        sigma_px : float
        jacobian : bool

        Returns
        -------
        R : ndarray, shape (N, 2)
            ``(project - pixels) / sigma_px``, whitened per point with ``pixel_cov``.
        J_theta : ndarray, shape (N, 2, n_geo)
            Only with ``jacobian=True``.
        J_wall : ndarray, shape (N, 2, 2)
            Only with ``jacobian=True``: w.r.t. the point's own wall ``(d, a)``.
        J_t : ndarray, shape (N, 2)
            Only with ``jacobian=True``.
        """
        d, a = walls[wall_idx, 0], walls[wall_idx, 1]
        if not jacobian:
            P = plan_point(theta, t, d, a)
            uv, _ = project_theta(theta[:7], P)
            return whiten(self.px_white, (uv - self.pixels) / sigma_px)
        P, dPt, dPth, dPw = plan_point(theta, t, d, a, jacobian=True)
        uv, _, G, Gth = project_theta(theta[:7], P, jacobian=True)
        wh, Jth = self.px_white, G @ dPth
        Jth[..., :7] += Gth
        R = whiten(wh, (uv - self.pixels) / sigma_px)
        Jth = whiten(wh, Jth / sigma_px, axis=-2)
        Jw = whiten(wh, (G @ dPw) / sigma_px, axis=-2)
        Jt = whiten(wh, np.einsum("nij,nj->ni", G, dPt) / sigma_px)
        return R, Jth, Jw, Jt

    def hard_wall_index(self, walls, t):
        """Wall of each point at azimuths ``t`` (N,) under walls (W, 2), shape (N,)."""
        c = corner_azimuths(walls[:, 0], walls[:, 1])[self.corner]
        return np.where(self._side(t, c) == 0, self.wall_pair[:, 0], self.wall_pair[:, 1])
