"""Priors on the eight sensor parameters, and the same prior in identifiable coordinates.

A prior is one :mod:`scipy.stats` frozen distribution per paper parameter
(``xi, phi, alpha_u, alpha_v, u0, v0, h, beta``), independent. The defaults are
the design value plus or minus a tolerance (:func:`default_prior`); any of them
is overridden by name.

The data see only ``theta = (xi, gamma_u, gamma_v, u0, v0, h, beta)``: scaling
``alpha_u``, ``alpha_v`` by ``k`` with ``phi' = (xi + phi) / k - xi`` changes no
pixel (fact 1, ``docs/model.md``, "Measured facts"). The sampler therefore
works with the prior of ``theta`` with ``phi`` integrated out::

    p(theta) = p_xi p_u0 p_v0 p_h p_beta
               * int p_phi(phi) p_au(gu / s) p_av(gv / s) / s^2 dphi,   s = xi + phi

(``1/s^2`` is the Jacobian of ``(gu, gv) -> (alpha_u, alpha_v)``), computed by
quadrature over the quantiles of ``p_phi``; ``phi`` is then drawn from its
exact conditional given each ``theta`` sample.

A camera calibrated beforehand (``Prior(camera=...)``, e.g. the result of
:func:`bayescal.calibrate_camera`) replaces the priors of the five camera
coordinates ``(xi, gamma_u, gamma_v, u0, v0)`` by one correlated normal, its
intrinsics and their covariance. ``phi`` keeps its own prior, independent of
``theta`` (it still fixes the phi/alpha ridge), so that::

    p(theta, phi) = N(theta_cam; m, C) p_h p_beta p_phi(phi),   xi + phi > 0

and ``alpha_u = gamma_u / (xi + phi)``, ``alpha_v`` likewise, follow from them.
"""

from __future__ import annotations

import numpy as np
from scipy import stats

from .._validation import resolve_rng
from ..errors import FitError, InvalidTypeError, InvalidValueError
from ..sensor.parameters import (
    CAMERA_PARAM_NAMES,
    PARAM_NAMES,
    SensorParams,
    camera_moments,
    camera_whitener,
    from_identifiable,
    identifiable_jacobian,
    to_identifiable,
)
from ..sensor.pose import POSE_NAMES
from ..stats.densities import independent_log_density, log_density, log_survival, logsumexp_last

__all__ = ["default_prior", "default_pose_prior", "Prior", "POSE_TOLERANCES", "as_prior"]

#: default tolerances (one standard deviation) around the design values
DEFAULT_TOLERANCES = {
    "xi": 0.05,          # parabolic mirror by design
    "phi": 0.1,
    "alpha_u": 0.1,      # relative: 10 % of the design focal scale
    "alpha_v": 0.1,
    "u0": 10.0,          # px
    "v0": 10.0,          # px
    "h": 0.1,            # relative: 10 % of the design baseline
    "beta": 0.05,        # rad (about 3 degrees)
}
_RELATIVE = ("alpha_u", "alpha_v", "h")

#: default tolerances (one standard deviation, around zero) of the laser cone's pose,
#: used by the misaligned model: a hand-assembled prototype's tilt (rad) and offset (mm)
POSE_TOLERANCES = {
    "tilt_x": float(np.radians(2.0)),
    "tilt_y": float(np.radians(2.0)),
    "offset_x": 5.0,
    "offset_y": 5.0,
}


def default_pose_prior():
    """Default priors of the laser cone's pose (misaligned model): zero +- tolerance.

    ============  ==========  ============================
    parameter     default     standard deviation
    ============  ==========  ============================
    tilt_x        0 rad       2 degrees (0.0349 rad)
    tilt_y        0 rad       2 degrees
    offset_x      0 mm        5 mm
    offset_y      0 mm        5 mm
    ============  ==========  ============================

    Returns
    -------
    dict
        ``{name: scipy.stats frozen distribution}`` for the four names of
        :data:`~bayescal.sensor.pose.POSE_NAMES`.

    Examples
    --------
    >>> import bayescal as bc
    >>> round(float(bc.default_pose_prior()["offset_x"].std()), 3)
    5.0
    """
    return {name: stats.norm(loc=0.0, scale=sd) for name, sd in POSE_TOLERANCES.items()}


def default_prior(nominal=None):
    """Default priors: independent normals, design value +- tolerance.

    ============  ==========================  =====================
    parameter     default (paper design)      standard deviation
    ============  ==========================  =====================
    xi            1                           0.05
    phi           0                           0.1
    alpha_u       55 px                       10 % (5.5 px)
    alpha_v       -55 px                      10 % (5.5 px)
    u0, v0        400, 300 px                 10 px
    h             200 mm                      10 % (20 mm)
    beta          pi/3 rad                    0.05 rad
    ============  ==========================  =====================

    Parameters
    ----------
    nominal : SensorParams, optional
        Design values (default :meth:`SensorParams.paper`).

    Returns
    -------
    dict
        ``{name: scipy.stats frozen distribution}`` for the eight names.

    Examples
    --------
    >>> import bayescal as bc
    >>> prior = bc.default_prior()
    >>> float(prior["h"].mean()), float(prior["h"].std())       # design value +- tolerance
    (200.0, 20.0)
    """
    nominal = SensorParams.paper() if nominal is None else nominal
    out = {}
    for name, value in nominal.as_dict().items():
        tol = DEFAULT_TOLERANCES[name]
        sd = tol * abs(value) if name in _RELATIVE else tol
        out[name] = stats.norm(loc=value, scale=sd)
    return out


def as_prior(prior=None, camera=None, *, nominal=None):
    """``prior`` as a :class:`Prior`, with the camera's prior when ``camera`` is given.

    Parameters
    ----------
    prior : dict or Prior, optional
    camera : object or tuple, optional
        A camera calibration (:func:`~bayescal.sensor.parameters.camera_moments`).
    nominal : SensorParams, optional
    """
    if isinstance(prior, Prior) and camera is None:
        return prior
    return Prior(prior, nominal=nominal, camera=camera)


def _camera_marginals(mean, cov, phi):
    """Normal marginals of ``xi, alpha_u, alpha_v, u0, v0`` implied by the camera's normal
    and ``phi``'s prior (alpha to first order, at phi's mean): for summaries and starts."""
    mp, vp = float(phi.mean()), float(phi.var())
    s = mean[0] + mp
    out = {n: stats.norm(mean[k], np.sqrt(cov[k, k])) for n, k in (("xi", 0), ("u0", 3),
                                                                      ("v0", 4))}
    for name, k in (("alpha_u", 1), ("alpha_v", 2)):
        g = np.array([-mean[k] / s**2, 1.0 / s])          # d alpha / d (xi, gamma)
        sub = cov[np.ix_([0, k], [0, k])]
        var = g @ sub @ g + (mean[k] / s**2) ** 2 * vp
        out[name] = stats.norm(mean[k] / s, np.sqrt(var))
    return out


def _check_dist(name, dist):
    if isinstance(dist, (stats.rv_continuous, stats.rv_discrete)):
        raise InvalidTypeError(
            f"prior[{name!r}] must be a frozen scipy.stats distribution, got the "
            f"unfrozen {dist.name!r}: give its parameters, e.g. "
            f"scipy.stats.{dist.name}(loc=..., scale=...)")
    if not (hasattr(dist, "logpdf") and hasattr(dist, "ppf") and hasattr(dist, "rvs")):
        raise InvalidTypeError(
            f"prior[{name!r}] must be a scipy.stats frozen continuous distribution "
            f"(with logpdf, ppf, rvs), got {type(dist).__name__}")
    return dist


class Prior:
    """Independent priors on the eight parameters, usable in identifiable coordinates.

    Parameters
    ----------
    prior : dict, optional
        ``{name: frozen distribution}`` overriding any of the defaults: the eight
        parameters' names, or the laser pose's (``tilt_x, tilt_y, offset_x,
        offset_y``; used only by the misaligned model, :func:`default_pose_prior`).
    nominal : SensorParams, optional
        Design values for the defaults.
    n_phi : int, optional
        Quadrature nodes over ``phi`` (default 64).
    camera : object or tuple, optional
        A camera calibration (``bc.calibrate_camera(views)``, a camera posterior, or
        ``(mean, cov)``; :func:`~bayescal.sensor.parameters.camera_moments`): its
        intrinsics and covariance become one correlated normal prior on ``(xi,
        gamma_u, gamma_v, u0, v0)`` in place of the priors of ``xi, alpha_u, alpha_v,
        u0, v0`` (which ``prior`` must then leave out); ``phi``, ``h``, ``beta`` keep
        theirs.

    Attributes
    ----------
    dists : dict
        The eight frozen distributions, keyed by :data:`~bayescal.PARAM_NAMES`. With
        a camera, those of ``xi, alpha_u, alpha_v, u0, v0`` are the normal marginals
        the camera implies (alpha's to first order): summaries and starts read them,
        the densities use the camera's joint normal.
    pose_dists : dict
        The four of the laser pose, keyed by ``POSE_NAMES`` (misaligned model).
    camera : tuple or None
        ``(mean (5,), cov (5, 5))`` of the camera prior, order ``xi, gamma_u, gamma_v, u0, v0``.

    Examples
    --------
    >>> from scipy import stats
    >>> import bayescal as bc
    >>> prior = bc.Prior({"h": stats.norm(210.0, 5.0)})     # the other seven keep defaults
    >>> float(prior.dists["h"].mean()), float(prior.dists["xi"].mean())
    (210.0, 1.0)
    """

    def __init__(self, prior=None, *, nominal=None, n_phi=64, camera=None):
        dists = default_prior(nominal)
        pose = default_pose_prior()
        if isinstance(prior, Prior):
            camera = prior.camera if camera is None else camera
            skip = CAMERA_PARAM_NAMES if prior.camera is not None else ()
            prior = {**{k: v for k, v in prior.dists.items() if k not in skip},
                     **prior.pose_dists}
        if camera is not None:
            clash = sorted(set(prior or {}) & set(CAMERA_PARAM_NAMES))
            if clash:
                raise InvalidValueError(
                    f"prior gives {', '.join(clash)} and camera is given: the "
                    "camera's prior replaces those of xi, alpha_u, alpha_v, u0, "
                    "v0; leave them out of prior")
        if prior is not None:
            if not isinstance(prior, dict):
                raise InvalidTypeError(
                    f"prior must be a dict {{name: scipy.stats frozen distribution}}, "
                    f"got {type(prior).__name__}")
            unknown = set(prior) - set(PARAM_NAMES) - set(POSE_NAMES)
            if unknown:
                raise InvalidValueError(f"prior has unknown parameter name(s) {sorted(unknown)}; "
                                        f"expected any of {PARAM_NAMES + POSE_NAMES}")
            for k, v in prior.items():
                (pose if k in POSE_NAMES else dists)[k] = _check_dist(k, v)
        self.camera = None
        if camera is not None:
            mean, cov = camera_moments(camera)
            self.camera = (mean, cov)
            self._cam_white = camera_whitener(cov)    # r = W (x - m)
            self._cam_norm = -0.5 * (np.linalg.slogdet(cov)[1] + 5 * np.log(2 * np.pi))
            dists.update(_camera_marginals(mean, cov, dists["phi"]))
        self.dists = dists
        self.pose_dists = pose
        # normal priors are evaluated in closed form (scipy's per-call overhead dominated
        # the sampler's prior cost); the common others too (bayescal.stats.densities)
        self._normal = {n: (float(d.mean()), float(d.std()))
                        for n, d in {**dists, **pose}.items()
                        if getattr(getattr(d, "dist", None), "name", "") == "norm"}
        self._lp = {n: log_density(d) for n, d in {**dists, **pose}.items()}
        self._phi_logsf = log_survival(dists["phi"])
        # theta's columns with priors of their own (no camera): xi, u0, v0, h, beta
        self._theta_terms = independent_log_density(
            [dists[n] for n in ("xi", "u0", "v0", "h", "beta")], [0, 3, 4, 5, 6])
        # quadrature over phi: equal-probability nodes (midpoint rule in quantile space)
        u = (np.arange(n_phi) + 0.5) / n_phi
        self._phi_nodes = np.asarray(dists["phi"].ppf(u), dtype=float)
        self._log_w = -np.log(n_phi)

    def _logpdf(self, name, x):
        """Log density of parameter ``name`` at ``x`` (closed form for the common ones)."""
        return self._lp[name](x)

    # -- laser pose (misaligned model) -------------------------------------
    def logpdf_pose(self, pose):
        """Log prior density of the laser pose, shape (..., 4) -> (...)."""
        pose = np.asarray(pose, dtype=float)
        return sum(self._logpdf(name, pose[..., k]) for k, name in enumerate(POSE_NAMES))

    def pose_residuals(self, pose, *, jacobian=False):
        """The pose prior as whitened residuals (4,) (and their diagonal Jacobian (4, 4)),
        as :meth:`residuals` does for the eight parameters."""
        return _whitened(self.pose_dists, POSE_NAMES, pose, jacobian, self._normal)

    # -- paper parameters -------------------------------------------------
    def logpdf(self, a):
        """Log prior density of paper parameters ``a``, shape (..., 8) -> (...)."""
        a = np.asarray(a, dtype=float)
        if self.camera is not None:       # the density of (theta, phi) times |d(theta, phi)/da|
            s = a[..., 0] + a[..., 1]
            with np.errstate(divide="ignore", invalid="ignore"):
                lp = (self._camera_logpdf(to_identifiable(a)) + self._logpdf("phi", a[..., 1])
                      + 2.0 * np.log(np.abs(s)))
            return np.where(s > 0, lp, -np.inf)
        out = np.zeros(a.shape[:-1])
        for k, name in enumerate(PARAM_NAMES):
            out = out + self._logpdf(name, a[..., k])
        return out

    def mean(self):
        """Prior means as a :class:`SensorParams`."""
        return SensorParams(**{n: float(d.mean()) for n, d in self.dists.items()})

    def std(self):
        """Prior standard deviations, shape (8,), order PARAM_NAMES."""
        return np.array([float(self.dists[n].std()) for n in PARAM_NAMES])

    def sample(self, size=None, *, rng=None):
        """Draw paper parameters from the prior, shape ``size + (8,)``.

        Draws with ``xi + phi <= 0``, ``h <= 0`` or ``beta`` outside (0, pi/2)
        are redrawn (the prior is truncated to the physical domain).
        """
        rng = resolve_rng(rng)
        shape = () if size is None else tuple(np.atleast_1d(size))
        n = int(np.prod(shape)) if shape else 1
        out = np.empty((n, 8))
        todo = np.arange(n)
        for _ in range(1000):
            for k, name in enumerate(PARAM_NAMES):
                out[todo, k] = self.dists[name].rvs(size=len(todo), random_state=rng)
            if self.camera is not None:       # the camera's five, jointly normal
                th = to_identifiable(out[todo])
                th[:, :5] = rng.multivariate_normal(*self.camera, size=len(todo))
                out[todo] = from_identifiable(th, out[todo, 1])
            ok = _physical(out[todo])
            todo = todo[~ok]
            if todo.size == 0:
                break
        else:
            raise FitError("prior puts almost no mass on physical parameters")
        return out.reshape(shape + (8,))

    # -- identifiable coordinates ------------------------------------------
    def _alpha_terms(self, theta, phi):
        """``log p_au(gu/s) + log p_av(gv/s) - 2 log s`` at nodes ``phi``, shape (..., K)."""
        s = theta[..., 0:1] + phi
        with np.errstate(divide="ignore", invalid="ignore"):
            r = 1.0 / s
            lp = (self._lp["alpha_u"](theta[..., 1:2] * r)
                  + self._lp["alpha_v"](theta[..., 2:3] * r) + 2.0 * np.log(r))
        return np.where(s > 0, lp, -np.inf)

    def logpdf_theta(self, theta):
        """Log prior of the identifiable coordinates with ``phi`` integrated out.

        Parameters
        ----------
        theta : ndarray, shape (..., 7)

        Returns
        -------
        ndarray, shape (...)
        """
        theta = np.asarray(theta, dtype=float)
        if self.camera is not None:
            # phi independent of theta: integrating it out leaves P(xi + phi > 0)
            out = self._camera_logpdf(theta) + self._phi_logsf(-theta[..., 0])
        else:
            out = self._theta_terms(theta)
            # E_phi[p_au p_av / s^2] over equal-probability nodes of p_phi
            out = out + (logsumexp_last(self._alpha_terms(theta, self._phi_nodes))
                         + self._log_w)
        ok = (theta[..., 5] > 0) & (theta[..., 6] > 0) & (theta[..., 6] < np.pi / 2)
        return np.where(ok & np.isfinite(out), out, -np.inf)

    def sample_phi(self, theta, *, rng=None):
        """Draw ``phi`` from its conditional given ``theta`` (shape (S, 7) -> (S,)).

        Exact up to the quadrature grid: a node is chosen with its conditional
        weight, then ``phi`` is drawn uniformly in probability space within the
        node's quantile cell (piecewise-constant density ratio).
        """
        rng = resolve_rng(rng)
        theta = np.atleast_2d(np.asarray(theta, dtype=float))
        if self.camera is not None:          # phi's own prior, truncated to xi + phi > 0
            lo = np.asarray(self.dists["phi"].cdf(-theta[:, 0]), dtype=float)
            u = lo + (1.0 - lo) * rng.random(len(theta))
            return np.asarray(self.dists["phi"].ppf(u), dtype=float)
        phi = self._phi_nodes
        lp = self._alpha_terms(theta, phi)
        lp = lp - lp.max(axis=-1, keepdims=True)
        w = np.exp(lp)
        w /= w.sum(axis=-1, keepdims=True)
        cdf = np.cumsum(w, axis=-1)
        k = (rng.random((len(theta), 1)) > cdf).sum(axis=-1)
        k = np.minimum(k, len(phi) - 1)
        n = len(phi)
        u = (k + rng.random(len(theta))) / n
        return np.asarray(self.dists["phi"].ppf(u), dtype=float)

    # -- least-squares form ------------------------------------------------
    def residuals(self, a, *, jacobian=False):
        """Prior as whitened residuals on paper parameters (for least squares).

        Normal priors give ``(a - mu) / sd`` exactly; any other distribution
        gives ``sign(a - m) sqrt(2 (log p(m) - log p(a)))`` with ``m`` its
        median, an approximation good near the mode.

        Parameters
        ----------
        a : ndarray, shape (8,)

        Returns
        -------
        r : ndarray, shape (8,)
        J : ndarray, shape (8, 8), diagonal (only with ``jacobian=True``; with a
            camera, full: its rows are those of :meth:`theta_residuals`)
        """
        if self.camera is None:
            return _whitened(self.dists, PARAM_NAMES, a, jacobian, self._normal)
        a = np.asarray(a, dtype=float)
        theta, phi = to_identifiable(a), a[1]
        if not jacobian:
            return self.theta_residuals(theta, phi)
        r, J = self.theta_residuals(theta, phi, jacobian=True)
        return r, J @ np.linalg.inv(identifiable_jacobian(theta, phi))

    def theta_residuals(self, theta, phi, *, jacobian=False):
        """The prior as eight whitened residuals at ``(theta, phi)`` (for least squares).

        Without a camera, :meth:`residuals` at the paper parameters; with one, the
        camera's five rows ``W (theta[:5] - m)`` (``W`` the inverse Cholesky factor of
        its covariance, so that their squares sum to the Mahalanobis distance), then
        ``phi``, ``h``, ``beta``.

        Parameters
        ----------
        theta : ndarray, shape (7,)
        phi : float

        Returns
        -------
        r : ndarray, shape (8,)
        J : ndarray, shape (8, 8)
            ``dr / d(theta, phi)`` (``phi`` last; only with ``jacobian=True``).
        """
        theta = np.asarray(theta, dtype=float)
        if self.camera is None:
            a = from_identifiable(theta, phi)
            if not jacobian:
                return self.residuals(a)
            r, D = self.residuals(a, jacobian=True)
            return r, D @ identifiable_jacobian(theta, phi)
        rc = self._cam_white @ (theta[:5] - self.camera[0])
        rest = _whitened(self.dists, ("phi", "h", "beta"), [phi, theta[5], theta[6]], jacobian,
                         self._normal)
        if not jacobian:
            return np.concatenate([rc, rest])
        J = np.zeros((8, 8))
        J[:5, :5] = self._cam_white
        J[5, 7], J[6, 5], J[7, 6] = np.diag(rest[1])
        return np.concatenate([rc, rest[0]]), J

    def _camera_logpdf(self, theta):
        """``log N(theta[..., :5]; m, C) + log p_h + log p_beta``, shape (..., 7) -> (...)."""
        z = (theta[..., :5] - self.camera[0]) @ self._cam_white.T
        return (self._cam_norm - 0.5 * np.sum(z * z, axis=-1)
                + self._logpdf("h", theta[..., 5]) + self._logpdf("beta", theta[..., 6]))


def _whitened(dists, names, a, jacobian, normal=None):
    """Whitened prior residuals of independent priors ``dists`` at ``a`` (len(names),);
    ``normal``: ``{name: (mean, sd)}`` of the normal ones, read instead of scipy's."""
    a = np.asarray(a, dtype=float)
    r = np.empty(len(names))
    d = np.empty(len(names))
    normal = {} if normal is None else normal
    for k, name in enumerate(names):
        dist = dists[name]
        if name in normal or getattr(dist.dist, "name", "") == "norm":
            mu, sd = normal[name] if name in normal else (dist.mean(), dist.std())
            r[k] = (a[k] - mu) / sd
            d[k] = 1.0 / sd
        else:
            m = float(dist.median())
            diff = max(float(dist.logpdf(m) - dist.logpdf(a[k])), 0.0)
            r[k] = np.sign(a[k] - m) * np.sqrt(2 * diff)
            eps = 1e-6 * max(abs(a[k]), float(dist.std()), 1e-12)
            dlp = (dist.logpdf(a[k] + eps) - dist.logpdf(a[k] - eps)) / (2 * eps)
            d[k] = -dlp / r[k] if abs(r[k]) > 1e-8 else 1.0 / float(dist.std())
    if not jacobian:
        return r
    return r, np.diag(d)


def _physical(a):
    return ((a[..., 0] + a[..., 1] > 0) & (a[..., 0] >= 0) & (a[..., 6] > 0)
            & (a[..., 7] > 0) & (a[..., 7] < np.pi / 2)
            & (a[..., 2] != 0) & (a[..., 3] != 0))

