"""The eight sensor parameters and their seven identifiable combinations.

The paper's parameters are ``(xi, phi, alpha_u, alpha_v, u0, v0, h, beta)``:

* ``xi``, ``phi``: mirror shape (parabolic mirror: ``xi = 1``, ``phi = 0``);
* ``alpha_u``, ``alpha_v`` (px), ``u0``, ``v0`` (px): camera intrinsics;
* ``h`` (mm): distance from the mirror focus down to the laser-cone apex;
* ``beta`` (rad): half-angle of the laser cone, measured from the vertical axis.

``phi``, ``alpha_u`` and ``alpha_v`` enter the model only through
``gamma_u = alpha_u * (xi + phi)`` and ``gamma_v = alpha_v * (xi + phi)``
(see ``docs/model.md``), so only seven combinations are identifiable::

    theta = (xi, gamma_u, gamma_v, u0, v0, h, beta)

Functions here convert between the two, vectorized over leading axes.
"""

from __future__ import annotations

from dataclasses import astuple, dataclass, fields

import numpy as np

from ..errors import InvalidTypeError, InvalidValueError

__all__ = [
    "PARAM_NAMES",
    "IDENTIFIABLE_NAMES",
    "CAMERA_NAMES",
    "CAMERA_PARAM_NAMES",
    "camera_moments",
    "camera_whitener",
    "SensorParams",
    "as_param_array",
    "to_identifiable",
    "from_identifiable",
    "identifiable_jacobian",
    "offset_variance",
]

PARAM_NAMES = ("xi", "phi", "alpha_u", "alpha_v", "u0", "v0", "h", "beta")
IDENTIFIABLE_NAMES = ("xi", "gamma_u", "gamma_v", "u0", "v0", "h", "beta")
#: the camera coordinates a camera calibration gives: the first five identifiable ones
CAMERA_NAMES = IDENTIFIABLE_NAMES[:5]
#: the paper parameters whose priors a camera calibration replaces (phi stays its own)
CAMERA_PARAM_NAMES = ("xi", "alpha_u", "alpha_v", "u0", "v0")


@dataclass(frozen=True)
class SensorParams:
    """The eight parameters of the sensor (paper's notation).

    Parameters
    ----------
    xi : float
        Mirror parameter of the unified model (1 for a parabolic mirror).
    phi : float
        Mirror/scale parameter (0 for the paper's parabolic mirror).
    alpha_u, alpha_v : float
        Focal scale factors in pixels (``alpha_v < 0`` flips the image v axis).
    u0, v0 : float
        Principal point in pixels.
    h : float
        Height of the mirror focus above the laser-cone apex, in mm (> 0).
    beta : float
        Half-angle of the laser cone from the vertical axis, in radians,
        strictly between 0 and pi/2.

    Examples
    --------
    >>> p = SensorParams.paper()
    >>> SensorParams.from_array(p.to_array()) == p
    True
    """

    xi: float
    phi: float
    alpha_u: float
    alpha_v: float
    u0: float
    v0: float
    h: float
    beta: float

    def __post_init__(self):
        for f in fields(self):
            value = getattr(self, f.name)
            try:
                value = float(value)
            except (TypeError, ValueError):
                raise InvalidTypeError(
                    f"SensorParams.{f.name} must be a number, got {value!r}") from None
            if not np.isfinite(value):
                raise InvalidValueError(f"SensorParams.{f.name} must be finite, got {value!r}")
            object.__setattr__(self, f.name, value)
        if self.xi + self.phi <= 0:
            raise InvalidValueError(f"xi + phi must be positive, got xi={self.xi}, phi={self.phi}")
        if self.xi < 0:
            raise InvalidValueError(f"xi must be non-negative, got {self.xi}")
        if self.alpha_u == 0 or self.alpha_v == 0:
            raise InvalidValueError(
                f"alpha_u and alpha_v must be non-zero, got {self.alpha_u}, {self.alpha_v}"
            )
        if self.h <= 0:
            raise InvalidValueError(f"h must be positive (mm), got {self.h}")
        if not 0 < self.beta < np.pi / 2:
            raise InvalidValueError(f"beta must lie in (0, pi/2) radians, got {self.beta}")

    @classmethod
    def paper(cls):
        """The paper's simulated sensor: parabolic mirror, 55 px, h = 200 mm, beta = 60 deg."""
        return cls(xi=1.0, phi=0.0, alpha_u=55.0, alpha_v=-55.0, u0=400.0, v0=300.0,
                   h=200.0, beta=np.pi / 3)

    def to_array(self):
        """Return the parameters as an array of shape (8,), order :data:`PARAM_NAMES`."""
        return np.array(astuple(self), dtype=float)

    @classmethod
    def from_array(cls, a):
        """Build from an array of shape (8,) in the order of :data:`PARAM_NAMES`."""
        a = np.asarray(a, dtype=float)
        if a.shape != (8,):
            raise InvalidValueError(
                f"a must have shape (8,) in the order {PARAM_NAMES}, got {a.shape}")
        return cls(*a.tolist())

    def to_identifiable(self):
        """Return ``(xi, gamma_u, gamma_v, u0, v0, h, beta)``, shape (7,)."""
        return to_identifiable(self.to_array())

    @classmethod
    def from_identifiable(cls, theta, phi=0.0):
        """Build from the seven identifiable coordinates and a chosen ``phi``.

        Every ``phi`` gives the same pixels and reconstructions (the data cannot
        tell them apart); ``alpha_u``/``alpha_v`` are rescaled to match.
        """
        theta = np.asarray(theta, dtype=float)
        if theta.shape != (7,):
            raise InvalidValueError(
                f"theta must have shape (7,) in the order {IDENTIFIABLE_NAMES}, "
                f"got {theta.shape}")
        return cls.from_array(from_identifiable(theta, phi))

    def replace(self, **changes):
        """Return a copy with some parameters changed (names as in :data:`PARAM_NAMES`)."""
        unknown = set(changes) - set(PARAM_NAMES)
        if unknown:
            raise InvalidTypeError(
                f"unknown parameter name(s) {sorted(unknown)}; expected {PARAM_NAMES}")
        d = dict(zip(PARAM_NAMES, astuple(self), strict=True))
        d.update(changes)
        return SensorParams(**d)

    def as_dict(self):
        """Return ``{name: value}`` for the eight parameters."""
        return dict(zip(PARAM_NAMES, astuple(self), strict=True))


def as_param_array(params, name="params"):
    """Return parameters as an array of shape (..., 8).

    Accepts a :class:`SensorParams` or an array whose last axis has the 8
    parameters (for vectorized evaluation over walkers).
    """
    if isinstance(params, SensorParams):
        return params.to_array()
    try:
        a = np.asarray(params, dtype=float)
    except (TypeError, ValueError):
        raise InvalidTypeError(f"{name} must be a SensorParams or an array of shape (..., 8), "
                               f"got {type(params).__name__}") from None
    if a.ndim == 0 or a.shape[-1] != 8:
        raise InvalidValueError(f"{name} must be a SensorParams or an array of shape (..., 8), "
                                f"got shape {a.shape}")
    return a


def to_identifiable(a):
    """Map paper parameters (..., 8) to identifiable coordinates (..., 7)."""
    a = np.asarray(a, dtype=float)
    xi, phi, au, av, u0, v0, h, beta = np.moveaxis(a, -1, 0)
    s = xi + phi
    return np.stack([xi, au * s, av * s, u0, v0, h, beta], axis=-1)


def from_identifiable(theta, phi):
    """Map identifiable coordinates (..., 7) and ``phi`` (broadcastable) to (..., 8)."""
    theta = np.asarray(theta, dtype=float)
    xi, gu, gv, u0, v0, h, beta = np.moveaxis(theta, -1, 0)
    phi = np.broadcast_to(np.asarray(phi, dtype=float), xi.shape)
    s = xi + phi
    return np.stack([xi, phi, gu / s, gv / s, u0, v0, h, beta], axis=-1)


def identifiable_jacobian(theta, phi):
    """Jacobian of :func:`from_identifiable` with respect to ``(theta, phi)``.

    Returns
    -------
    ndarray, shape (..., 8, 8)
        ``J[..., i, j] = d a_i / d (theta_0..6, phi)_j``; used to map an 8x8
        covariance of ``(theta, phi)`` to the paper's eight parameters.
    """
    theta = np.asarray(theta, dtype=float)
    xi, gu, gv = theta[..., 0], theta[..., 1], theta[..., 2]
    phi = np.broadcast_to(np.asarray(phi, dtype=float), xi.shape)
    s = xi + phi
    J = np.zeros(theta.shape[:-1] + (8, 8))
    J[..., 0, 0] = 1.0                       # xi
    J[..., 1, 7] = 1.0                       # phi
    J[..., 2, 1] = 1.0 / s                   # alpha_u = gu / (xi + phi)
    J[..., 2, 0] = J[..., 2, 7] = -gu / s**2
    J[..., 3, 2] = 1.0 / s                   # alpha_v = gv / (xi + phi)
    J[..., 3, 0] = J[..., 3, 7] = -gv / s**2
    for k in (3, 4, 5, 6):                  # u0, v0, h, beta
        J[..., k + 1, k] = 1.0
    return J


def camera_moments(camera):
    """Mean and covariance of the camera intrinsics a camera calibration states.

    Parameters
    ----------
    camera : object or tuple
        A camera calibration: anything with ``intrinsics`` (a mapping with the keys
        ``xi, gamma_u, gamma_v, u0, v0``) and ``covariance`` (a method or an array,
        at least (5, 5), its first five rows and columns in that order, the board
        poses integrated out), such as :func:`bayescal.calibrate_camera`'s result
        or :func:`bayescal.sample_camera_posterior`'s; or a pair ``(mean, cov)``
        of shapes (5,) and (5, 5) in that order (px for gamma and the centre).

    Returns
    -------
    mean : ndarray, shape (5,)
    cov : ndarray, shape (5, 5)
        Symmetric and positive definite.

    Raises
    ------
    TypeError
        ``camera`` is none of these.
    ValueError
        A missing name, a non-finite value, a covariance of the wrong shape or not
        positive definite, or ``xi < 0`` or a zero ``gamma``.
    """
    if isinstance(camera, tuple) and len(camera) == 2:
        mean, cov = camera
    else:
        intr, cov = getattr(camera, "intrinsics", None), getattr(camera, "covariance", None)
        if intr is None or cov is None:
            raise InvalidTypeError("camera must be a camera calibration (with intrinsics and "
                                   "covariance(), e.g. bc.calibrate_camera(views)) or a pair "
                                   f"(mean (5,), cov (5, 5)), got {type(camera).__name__}")
        missing = [n for n in CAMERA_NAMES if n not in intr]
        if missing:
            raise InvalidValueError(f"camera.intrinsics has no {', '.join(missing)}; expected the "
                                    f"keys {', '.join(CAMERA_NAMES)}")
        mean = [intr[n] for n in CAMERA_NAMES]
        cov = cov() if callable(cov) else cov
    mean, cov = np.asarray(mean, dtype=float), np.asarray(cov, dtype=float)
    if mean.shape != (5,) or cov.ndim != 2 or cov.shape[0] < 5 or cov.shape[0] != cov.shape[1]:
        raise InvalidValueError(
            f"camera: expected a mean of shape (5,) and a covariance of at least "
            f"(5, 5), got {mean.shape} and {cov.shape}")
    cov = 0.5 * (cov[:5, :5] + cov[:5, :5].T)
    if not (np.all(np.isfinite(mean)) and np.all(np.isfinite(cov))):
        raise InvalidValueError("camera: the intrinsics and their covariance must be finite")
    try:
        np.linalg.cholesky(cov)
    except np.linalg.LinAlgError:
        raise InvalidValueError("camera: the covariance of (xi, gamma_u, gamma_v, u0, v0) is not "
                                f"positive definite (variances {np.diag(cov)})") from None
    if mean[0] < 0 or mean[1] == 0 or mean[2] == 0:
        raise InvalidValueError(f"camera: expected xi >= 0 and gamma_u, gamma_v nonzero, got "
                                f"{dict(zip(CAMERA_NAMES, mean.tolist(), strict=True))}")
    return mean, cov


def camera_whitener(cov):
    """``W`` with ``W cov W^T = I`` (the inverse of the lower Cholesky factor): the rows
    ``W (x - mean)`` of a camera prior, shape (5, 5)."""
    return np.linalg.inv(np.linalg.cholesky(np.asarray(cov, dtype=float)))


def offset_variance(names, offset_sd, *, size=None):
    """The covariance a translation of every pixel adds: ``offset_sd**2`` (px^2) on the
    ``(u0, v0)`` diagonal of a matrix over ``names`` (:data:`PARAM_NAMES` or
    :data:`IDENTIFIABLE_NAMES`, possibly followed by more parameters, which get nothing).

    A common shift of the pixels is a shift of the principal point in eq. (1), so it moves
    ``u0`` and ``v0`` and nothing else: with a flat prior on them, their posterior variance
    grows by exactly this much. With an informative prior on the principal point (a
    camera prior) only the data's share should grow, so adding it is conservative there.

    Parameters
    ----------
    names : sequence of str
        Names of the matrix's leading rows.
    offset_sd : float
        sd of the translation, px, each axis.
    size : int, optional
        The matrix's size, if larger than ``len(names)`` (a misaligned model's pose rows
        follow the sensor's).

    Returns
    -------
    ndarray, shape (size, size)
    """
    n = len(names) if size is None else int(size)
    out = np.zeros((n, n))
    i = list(names).index("u0")
    out[i, i] = out[i + 1, i + 1] = float(offset_sd) ** 2
    return out
