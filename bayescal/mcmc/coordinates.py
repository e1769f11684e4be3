"""The collapsed sampler's coordinates ``s`` of the globals ``psi``.

The data pin combinations of the sensor's parameters, not the parameters one by one;
the sampler works in coordinates where those combinations are single coordinates
(``docs/bayes.md`` section 3): the laser ring's pixel radii (:func:`ring_scale`) in place
of ``gamma_u``, ``gamma_v``, ``H = h * depth_scale`` in place of ``h``, ``w^(1/3)`` for
the outlier fraction and, with a misaligned cone, the *apparent* principal point
(:func:`pose_shift`) in place of ``u0``, ``v0``. Each map is triangular, so its inverse
and Jacobian are closed-form.
"""

from __future__ import annotations

import numpy as np
from scipy.special import expit, logit

from ..errors import InvalidValueError
from ..sensor.laser import cone_height

__all__ = ["ring_scale", "depth_scale", "pose_shift", "pose_scale", "Coordinates", "log_jacobian",
           "to_sampling", "from_sampling", "sampling_jacobian"]


def ring_scale(theta, rho_ref=np.inf):
    """The laser ring's pixel radius per unit gamma, seen at horizontal range ``rho_ref``.

    A laser point at horizontal range ``rho`` sits at elevation ``e`` with
    ``tan(e) = cot(beta) - h / rho`` and images at ``gamma cos(e) / (xi - sin(e))`` px
    from the principal point. The data pin this radius at the points' ranges, not
    gamma, xi and beta one by one, so the sampler works with ``R_u = gamma_u *
    ring_scale`` and ``R_v = gamma_v * ring_scale`` in place of ``gamma_u``,
    ``gamma_v``. ``rho_ref = inf`` gives the asymptotic ring,
    ``sin(beta) / (xi - cos(beta))`` (independent of h); a finite ``rho_ref`` (the
    points' median range) removes most of the ridge's curvature in small rooms
    (``docs/bayes.md`` section 3).
    """
    xi, h, beta = theta[..., 0], theta[..., 5], theta[..., 6]
    with np.errstate(divide="ignore", invalid="ignore"):
        if np.isinf(rho_ref):
            se, ce = np.cos(beta), np.sin(beta)
        else:
            te = 1.0 / np.tan(beta) - h / rho_ref
            ce = 1.0 / np.sqrt(1.0 + te * te)
            se = te * ce
        return np.where(xi - se > 0, ce / (xi - se), np.nan)


def depth_scale(theta):
    """``(1 - xi cos(beta)) sin(beta) / (xi - cos(beta))``: the ring radius' sensitivity to
    ``h / rho``.

    A point at horizontal range ``rho`` images at radius
    ``gamma * ring_scale * (1 - depth_scale * h / rho + ...)`` (asymptotic ring):
    after the ring radius, the data pin ``h * depth_scale``, a curved ridge in
    ``(xi, h, beta)``; the sampler uses it in place of ``h``. It depends on xi and
    beta only, so the change of coordinates stays triangular.
    """
    xi, beta = theta[..., 0], theta[..., 6]
    return (1.0 - xi * np.cos(beta)) * ring_scale(theta)


def _aligned(theta):
    """The geometry (..., 11) of ``theta`` with the pose set to zero (the aligned cone)."""
    th = np.array(theta[..., :11], dtype=float)
    th[..., 7:11] = 0.0
    return th


#: the entries of theta :func:`pose_shift` reads: xi, gamma_u, gamma_v, h, beta
_POSE_SHIFT_READS = [0, 1, 2, 5, 6]
#: azimuths of the reference ring on which :func:`pose_shift` is fitted, rad
POSE_RING = np.linspace(0.0, 2.0 * np.pi, 16, endpoint=False)


def pose_shift(theta, rho_ref):
    """The apparent principal point's shift per unit of the laser pose, (..., 2, 4).

    A tilt or an offset of the laser cone raises or lowers the laser points by a first
    harmonic of their azimuth; in the image that moves each point of the laser ring along
    its radius by a first harmonic, which is what a shift of the whole ring, of ``(u0,
    v0)``, does to the points' radii. The data see only that radial component (each
    point's place along the ring, its azimuth on its wall, is free), so what they pin is
    the *apparent* principal point ``(u0, v0) + k . pose``: the translation whose radial
    components fit the points' radial shifts best (least squares over the ring). On a
    circular ring a radial shift ``a cos(phi)`` is the translation ``a``, twice the mean
    pixel shift ``a cos^2(phi)``, which an earlier version took (sampling its ridge
    half-straightened, ``docs/floorplan.md`` section 13). ``k`` depends on ``xi``,
    ``gamma``, ``h`` and ``beta``: along the pose, the posterior of ``(u0, v0)`` bends
    with them. ``k`` is computed on a ring of laser points at horizontal range ``rho_ref``
    on the aligned cone of ``theta`` (rows u, v; columns tilt_x, tilt_y, offset_x,
    offset_y). It reads only ``xi``, ``gamma``, ``h`` and ``beta``, so the map stays
    triangular with a unit Jacobian.
    """
    th = _aligned(theta)
    x, y = rho_ref * np.cos(POSE_RING), rho_ref * np.sin(POSE_RING)
    with np.errstate(divide="ignore", invalid="ignore"):
        z, _, _, dz = cone_height(th, x, y, geometry=True)
        xi, gu, gv = (th[..., k, None] for k in range(3))
        r = np.sqrt(x * x + y * y + z * z)
        D = xi * r - z
        pu, pv = gu * x / D, gv * y / D                 # the ring's pixels about (u0, v0)
        nu, nv = pu / np.hypot(pu, pv), pv / np.hypot(pu, pv)      # their radial directions
        dlog = -(xi * z / r - 1.0) / D                 # d log(1 / D) / dz: pixels move radially
        # the radial shift of each point per unit pose, and the translation fitting it
        dr = np.stack([(pu * nu + pv * nv) * dlog * g for g in dz[2:]], axis=-1)   # (..., R, 4)
        n = np.stack([nu, nv], axis=-1)                                          # (..., R, 2)
        A = np.einsum("...ri,...rj->...ij", n, n)
        b = np.einsum("...ri,...rk->...ik", n, dr)
        return np.linalg.solve(A, b)


#: the entries of theta :func:`pose_scale` reads: xi, h, beta and the pose
_POSE_SCALE_READS = [0, 5, 6, 7, 8, 9, 10]


def pose_scale(theta, rho_ref):
    """The laser ring's relative change of scale ``(m_u, m_v)`` under the laser pose, (..., 2).

    To first order a tilt moves the ring (:func:`pose_shift`); to second order it also
    changes its size: the cone's generators leave the tilted axis at the half-angle, so
    seen from the vertical they open wider on average (``tilt^2 cot(beta) / 4`` in the
    polar angle, and three times that in the points' mean height, the first harmonic's
    square adding twice as much), which scales the ring's pixel radii by ``1 + m`` with
    ``m`` of order ``tilt^2``. The data pin the radii the ring shows, so the sampler takes
    ``R (1 + m)`` as the ring radius' coordinate (without it the sampled ring radii,
    ``xi`` and ``beta`` bend with ``tilt_x^2 + tilt_y^2``: ``docs/floorplan.md`` section
    13). ``m`` is exact, not expanded: the radial pixel shifts from the aligned to the
    posed cone of a ring of laser points at horizontal range ``rho_ref`` (unit ``gamma``:
    a circle) are fitted by least squares with a translation and the two axis scales
    (``u = m_u u_ring``, ``v = m_v v_ring``); the scales are returned. It reads ``xi``,
    ``h``, ``beta`` and the pose, never ``gamma``, so the map stays triangular.
    """
    posed = np.array(theta[..., :11], dtype=float)
    posed[..., 1:3] = 1.0
    x, y = rho_ref * np.cos(POSE_RING), rho_ref * np.sin(POSE_RING)
    with np.errstate(divide="ignore", invalid="ignore"):
        pixels = []
        for th in (_aligned(posed), posed):
            z = cone_height(th, x, y)[0]
            D = th[..., 0, None] * np.sqrt(x * x + y * y + z * z) - z
            pixels.append((x / D, y / D))
        (pu, pv), (qu, qv) = pixels
        rad = np.hypot(pu, pv)
        nu, nv = pu / rad, pv / rad
        shift = (qu - pu) * nu + (qv - pv) * nv                       # (..., R) radial
        X = np.stack([nu, nv, nu * pu, nv * pv], axis=-1)               # (..., R, 4)
        A = np.einsum("...ri,...rj->...ij", X, X)
        b = np.einsum("...ri,...r->...i", X, shift)
        return np.linalg.solve(A, b[..., None])[..., 2:, 0]


class Coordinates:
    """The sampler's coordinates ``s`` of the globals ``psi``.

    ``(gamma_u, gamma_v)`` are replaced by the ring radii ``R = gamma *
    ring_scale(theta, rho_ref)`` and ``h`` by ``H = h * depth_scale`` (``docs/bayes.md``
    section 3). The map is triangular (H from (xi, beta, h), then R from gamma and
    (xi, beta, h)), so its inverse and Jacobian are closed-form.

    Parameters
    ----------
    rho_ref : float, optional
        Horizontal range (mm) at which the ring radius is taken: the median range
        of the MAP's points; ``inf`` (default) is the asymptotic ring.
    frac_index : int, optional
        Index in psi of ``logit w``, the outlier fraction, if sampled. It is sampled
        as ``w^(1/3)``: with few or no outliers the posterior of w is close to a
        Gamma with shape ~1, whose cube root is nearly normal (Wilson-Hilferty),
        while ``logit w = log w + ...`` is skewed (skewness ~ -1.1) with an
        exponential left tail, which a fitted independence proposal matches badly
        (``docs/bayes.md`` section 3).
    pose : bool
        psi carries the laser pose at 7:11 (misaligned model): ``(u0, v0)`` are
        sampled as the apparent principal point ``(u0, v0) + pose_shift . pose``
        (:func:`pose_shift`; needs a finite ``rho_ref``).
    ring : bool
        Sample the ring radii and ``H`` (default); ``False`` keeps ``gamma_u``,
        ``gamma_v`` and ``h`` themselves: for a camera calibrated beforehand whose
        prior, not the laser data, holds ``(xi, gamma)``, the ring radius would then
        bend with ``(h, beta)`` (``docs/calibration.md``, "From a camera calibration
        to the laser").
    """

    def __init__(self, rho_ref=np.inf, frac_index=None, pose=False, ring=True):
        rho_ref = float(np.inf if rho_ref is None else rho_ref)
        if not rho_ref > 0:
            raise InvalidValueError(
                f"rho_ref must be a positive range in mm or inf, got {rho_ref!r}")
        if pose and np.isinf(rho_ref):
            raise InvalidValueError(
                "the pose's coordinates need a finite rho_ref (the points' range)")
        self.rho_ref = rho_ref
        self.frac_index = None if frac_index is None else int(frac_index)
        self.pose = bool(pose)
        self.ring = bool(ring)

    def __repr__(self):
        ring = "" if self.ring else ", ring=False"
        return (f"Coordinates(rho_ref={self.rho_ref:g}, frac_index={self.frac_index}, "
                f"pose={self.pose}{ring})")

    def _scales(self, psi):
        """``(ring_scale, depth_scale)`` of psi, or ones with ``ring=False``."""
        if not self.ring:
            return np.ones(psi.shape[:-1]), np.ones(psi.shape[:-1])
        return ring_scale(psi, self.rho_ref), depth_scale(psi)

    def _shift(self, psi):
        """``pose_shift . pose`` (..., 2) of psi (its xi, gamma, h, beta and pose).

        ``k`` is computed once per distinct ``(xi, gamma, h, beta)``: the sampler's
        gradient moves each coordinate in turn (central differences of the prior through
        this map), and all but those five leave ``k`` as it is (same floats), so most
        rows repeat (half the gradient's cost before)."""
        flat = psi.reshape(-1, psi.shape[-1])
        k = self._pose_k(flat)
        return np.einsum("nij,nj->ni", k, flat[:, 7:11]).reshape(psi.shape[:-1] + (2,))

    def _pose_m(self, psi):
        """:func:`pose_scale` (..., 2) of psi, once per distinct ``(xi, h, beta, pose)``;
        zeros without the pose or without the ring radii."""
        if not (self.pose and self.ring):
            return np.zeros(psi.shape[:-1] + (2,))
        flat = psi.reshape(-1, psi.shape[-1])
        keys, inverse = np.unique(flat[:, _POSE_SCALE_READS], axis=0, return_inverse=True)
        rows = np.zeros((len(keys), 11))
        rows[:, _POSE_SCALE_READS] = keys
        return pose_scale(rows, self.rho_ref)[inverse.ravel()].reshape(psi.shape[:-1] + (2,))

    def _pose_k(self, flat):
        """:func:`pose_shift` (n, 2, 4) of the rows of ``flat`` (n, d), once per distinct
        ``(xi, gamma, h, beta)``."""
        keys, inverse = np.unique(flat[:, _POSE_SHIFT_READS], axis=0, return_inverse=True)
        rows = np.zeros((len(keys), 11))
        rows[:, _POSE_SHIFT_READS] = keys
        return pose_shift(rows, self.rho_ref)[inverse.ravel()]

    def to_sampling(self, psi):
        """psi (..., d) -> s (..., d)."""
        s = np.array(psi, dtype=float)
        if self.pose:
            s[..., 3:5] += self._shift(s)
        k, c = self._scales(s)
        m = self._pose_m(s)
        s[..., 1] *= k * (1.0 + m[..., 0])
        s[..., 2] *= k * (1.0 + m[..., 1])
        s[..., 5] *= c
        if self.frac_index is not None:
            s[..., self.frac_index] = np.cbrt(expit(s[..., self.frac_index]))
        return s

    def from_sampling(self, s):
        """Inverse of :meth:`to_sampling` (NaN where ``w^(1/3)`` is outside (0, 1))."""
        return self._inverse(s)[0]

    def from_sampling_log_jacobian(self, s):
        """``(from_sampling(s), log_jacobian(from_sampling(s)))``, the same numbers, with the
        scales computed once (the sampler's target calls both for every walker)."""
        psi, k, c, m = self._inverse(s)
        return psi, self._log_jacobian(psi, k, c, m)

    def _inverse(self, s):
        """psi of ``s`` and the scales it used: ``(psi, ring_scale, depth_scale, m)`` (``m``
        None without the pose's ring scale)."""
        psi = np.array(s, dtype=float)
        if self.ring:         # depth_scale reads xi and beta only, ring_scale h too
            c = depth_scale(psi)
            psi[..., 5] /= c
            k = ring_scale(psi, self.rho_ref)
        else:
            k = c = np.ones(psi.shape[:-1])
        m = self._pose_m(psi) if self.pose and self.ring else None
        if m is None:                          # xi, h, beta and the pose are known here
            psi[..., 1] /= k
            psi[..., 2] /= k
        else:
            psi[..., 1] /= k * (1.0 + m[..., 0])
            psi[..., 2] /= k * (1.0 + m[..., 1])
        if self.pose:
            psi[..., 3:5] -= self._shift(psi)
        if self.frac_index is not None:
            y = psi[..., self.frac_index]
            with np.errstate(invalid="ignore", divide="ignore"):
                psi[..., self.frac_index] = np.where((y > 0) & (y < 1), logit(y**3), np.nan)
        return psi, k, c, m

    def inverse_jacobian(self, s, eps=1e-8, *, log_jacobian=False):
        """psi of ``s`` (W, d) and ``d psi / d s``, shape (W, d, d), entry ``[w, k, j] = d
        psi_j / d s_k``; with ``log_jacobian`` also :meth:`log_jacobian` at psi (W,) and its
        gradient in ``s`` (W, d), from the same shifted copies (it reads only the mixed
        entries and the outlier fraction, whose term is differentiated in closed form).

        Only ``xi``, the ring radii, ``H``, ``beta`` and the pose (entries 0, 1, 2, 5, 6,
        and 7-10 with the pose) move other entries of psi through the scales, the pose's
        ``k`` and its ring scale ``m``: their columns are forward differences (5 or 9
        shifted copies of every row, step ``eps * max(1, |s|)``, near the optimal step
        ``sqrt(machine eps)``: errors ~1e-8 relative; mapped in one call with the rows
        themselves). The rest is closed-form: the identity and the outlier fraction's ``d
        logit(y^3) / dy = 3 / (y (1 - y^3))``.
        """
        s = np.atleast_2d(np.asarray(s, float))
        W, d = s.shape
        J = np.broadcast_to(np.eye(d), (W, d, d)).copy()
        mixed = np.array([0, 1, 2, 5, 6] + ([7, 8, 9, 10] if self.pose else []))
        m = len(mixed)
        h = eps * np.maximum(1.0, np.abs(s[:, mixed]))                 # (W, m)
        E = np.zeros((m, W, d))
        E[np.arange(m), :, mixed] = h.T
        with np.errstate(invalid="ignore", divide="ignore"):
            out, k, c, m = self._inverse(np.concatenate([s[None], s[None] + E]))
            psi = out[0]
            J[:, mixed, :] = np.moveaxis((out[1:] - psi) / h.T[..., None], 0, 1)
            f = self.frac_index
            y = None if f is None else s[:, f]
            if f is not None:
                J[:, f, f] = np.where((y > 0) & (y < 1), 3.0 / (y * (1.0 - y**3)), np.nan)
            if not log_jacobian:
                return psi, J
            lj = self._log_jacobian(out, k, c, m)                        # (1 + m, W)
            dlj = np.zeros((W, d))
            dlj[:, mixed] = ((lj[1:] - lj[0]) / h.T).T
            if f is not None:               # log 3 - log y - log(1 - y^3), y = w^(1/3)
                dlj[:, f] = -1.0 / y + 3.0 * y * y / (1.0 - y**3)
        return psi, J, lj[0], dlj

    def log_jacobian(self, psi):
        """``log |d psi / d s|`` of :meth:`from_sampling` at psi (..., d)."""
        k, c = self._scales(psi)
        return self._log_jacobian(psi, k, c, self._pose_m(psi) if self.pose else None)

    def _log_jacobian(self, psi, k, c, m):
        """:meth:`log_jacobian` given psi's scales (``m`` None: no pose scale)."""
        with np.errstate(invalid="ignore", divide="ignore"):
            out = -2.0 * np.log(k) - np.log(np.abs(c))
            if m is not None:
                out = out - np.sum(np.log1p(m), axis=-1)
            if self.frac_index is not None:
                # x = logit(y^3): dx/dy = 3 y^2 / (w (1 - w)), w = y^3
                y = np.cbrt(expit(psi[..., self.frac_index]))
                out = out + np.log(3.0) - np.log(y) - np.log1p(-y**3)
        return out

    def jacobian(self, psi, eps=1e-7):
        """``d s / d psi`` at one psi (d,) by central differences, shape (d, d)."""
        psi = np.asarray(psi, float)
        d = len(psi)
        J = np.empty((d, d))
        for k in range(d):
            h = eps * max(1.0, abs(psi[k]))
            e = np.zeros(d)
            e[k] = h
            J[:, k] = (self.to_sampling(psi + e) - self.to_sampling(psi - e)) / (2 * h)
        return J


_ASYMPTOTIC = Coordinates()


def to_sampling(psi):
    """:meth:`Coordinates.to_sampling` with the asymptotic ring (``rho_ref = inf``)."""
    return _ASYMPTOTIC.to_sampling(psi)


def from_sampling(s):
    """Inverse of :func:`to_sampling`."""
    return _ASYMPTOTIC.from_sampling(s)


def log_jacobian(psi):
    """``log |d psi / d s|`` of :func:`from_sampling` at psi (..., d)."""
    return _ASYMPTOTIC.log_jacobian(psi)


def sampling_jacobian(psi, eps=1e-7):
    """``d to_sampling / d psi`` at one psi (d,) by central differences, shape (d, d)."""
    return _ASYMPTOTIC.jacobian(psi, eps)
