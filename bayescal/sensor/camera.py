"""The catadioptric camera: the unified projection model, eq. (1) of the paper.

Frame C has its origin at the mirror focus, z up along the mirror axis (see
``docs/conventions.md``). A point ``P = (x, y, z)`` in mm images at::

    u = gamma_u * x / (xi * r - z) + u0,    gamma_u = alpha_u * (xi + phi)
    v = gamma_v * y / (xi * r - z) + v0,    gamma_v = alpha_v * (xi + phi)

with ``r = |P|``. The model is valid where ``xi * r - z > 0``; outside it
(for ``xi = 1`` only the half-axis straight up, for ``xi < 1`` a cone around it)
:func:`project` returns NaN and reports the point invalid.

All functions broadcast parameters of shape ``(..., 8)`` (or a
:class:`~bayescal.SensorParams`) against points of shape ``(..., 3)``.
"""

from __future__ import annotations

import numpy as np

from .._validation import as_pixels, as_points
from .parameters import as_param_array, to_identifiable

__all__ = ["project", "backproject", "project_theta", "backproject_theta"]


def _split(theta):
    return np.moveaxis(np.asarray(theta, dtype=float), -1, 0)


def project_theta(theta, points, *, jacobian=False):
    """Project points with identifiable parameters (internal, unchecked).

    Parameters
    ----------
    theta : ndarray, shape (..., 7)
        ``(xi, gamma_u, gamma_v, u0, v0, h, beta)``.
    points : ndarray, shape (..., 3)
        Points in frame C, mm.
    jacobian : bool
        Also return derivatives.

    Returns
    -------
    uv : ndarray, shape (..., 2)
        Pixels; NaN where ``xi * r - z <= 0``.
    valid : ndarray of bool, shape (...)
    d_points : ndarray, shape (..., 2, 3)
        Only with ``jacobian=True``: d(u, v)/d(x, y, z).
    d_theta : ndarray, shape (..., 2, 7)
        Only with ``jacobian=True``: d(u, v)/d theta.
    """
    xi, gu, gv, u0, v0 = _split(theta)[:5]
    x, y, z = _split(points)
    r = np.sqrt(x * x + y * y + z * z)
    D = xi * r - z
    valid = D > 0
    with np.errstate(divide="ignore", invalid="ignore"):
        Dsafe = np.where(valid, D, np.nan)
        mx = x / Dsafe
        my = y / Dsafe
    u = gu * mx + u0
    v = gv * my + v0
    uv = np.stack(np.broadcast_arrays(u, v), axis=-1)
    valid = np.broadcast_to(valid, uv.shape[:-1])
    if not jacobian:
        return uv, valid
    with np.errstate(divide="ignore", invalid="ignore"):
        rinv = 1.0 / r
    # dD/dP = xi * P / r - e_z
    dDx, dDy, dDz = xi * x * rinv, xi * y * rinv, xi * z * rinv - 1.0
    shape = uv.shape[:-1]
    dP = np.empty(shape + (2, 3))
    a = gu / Dsafe
    b = gv / Dsafe
    dP[..., 0, 0] = a * (1.0 - mx * dDx)
    dP[..., 0, 1] = -a * mx * dDy
    dP[..., 0, 2] = -a * mx * dDz
    dP[..., 1, 0] = -b * my * dDx
    dP[..., 1, 1] = b * (1.0 - my * dDy)
    dP[..., 1, 2] = -b * my * dDz
    dth = np.zeros(shape + (2, 7))
    dth[..., 0, 0] = -gu * mx * r / Dsafe
    dth[..., 1, 0] = -gv * my * r / Dsafe
    dth[..., 0, 1] = mx
    dth[..., 1, 2] = my
    dth[..., 0, 3] = 1.0
    dth[..., 1, 4] = 1.0
    return uv, valid, dP, dth


def backproject_theta(theta, pixels, *, jacobian=False):
    """Closed-form inverse of eq. (1) onto the unit sphere (internal, unchecked).

    With ``m = ((u - u0) / gamma_u, (v - v0) / gamma_v)`` and ``rho2 = |m|^2``::

        f = (xi + sqrt(1 + (1 - xi^2) rho2)) / (1 + rho2)
        ray = (f * m_x, f * m_y, xi - f)

    Returns
    -------
    rays : ndarray, shape (..., 3)
        Unit vectors in frame C; NaN where ``1 + (1 - xi^2) rho2 < 0`` (pixels
        outside the image of the sphere when ``xi > 1``).
    valid : ndarray of bool, shape (...)
    d_pixels : ndarray, shape (..., 3, 2)
        Only with ``jacobian=True``: d ray / d (u, v).
    d_theta : ndarray, shape (..., 3, 7)
        Only with ``jacobian=True``: d ray / d theta.
    """
    xi, gu, gv, u0, v0 = _split(theta)[:5]
    u, v = _split(pixels)
    mx = (u - u0) / gu
    my = (v - v0) / gv
    rho2 = mx * mx + my * my
    disc = 1.0 + (1.0 - xi * xi) * rho2
    valid = disc >= 0
    with np.errstate(invalid="ignore"):
        sq = np.sqrt(np.where(valid, disc, np.nan))
    f = (xi + sq) / (1.0 + rho2)
    rays = np.stack(np.broadcast_arrays(f * mx, f * my, xi - f), axis=-1)
    valid = np.broadcast_to(valid, rays.shape[:-1])
    if not jacobian:
        return rays, valid
    # df/drho2
    with np.errstate(divide="ignore", invalid="ignore"):
        dsq = 0.5 * (1.0 - xi * xi) / sq
    df = (dsq * (1.0 + rho2) - (xi + sq)) / (1.0 + rho2) ** 2
    dm = np.empty(rays.shape[:-1] + (3, 2))  # d ray / d (mx, my)
    dm[..., 0, 0] = f + mx * df * 2 * mx
    dm[..., 0, 1] = mx * df * 2 * my
    dm[..., 1, 0] = my * df * 2 * mx
    dm[..., 1, 1] = f + my * df * 2 * my
    dm[..., 2, 0] = -df * 2 * mx
    dm[..., 2, 1] = -df * 2 * my
    dpix = np.empty_like(dm)
    dpix[..., 0] = dm[..., 0] / np.asarray(gu)[..., None]
    dpix[..., 1] = dm[..., 1] / np.asarray(gv)[..., None]
    dth = np.zeros(rays.shape[:-1] + (3, 7))
    with np.errstate(divide="ignore", invalid="ignore"):
        dfdxi = (1.0 - xi * rho2 / sq) / (1.0 + rho2)
    dth[..., 0, 0] = mx * dfdxi
    dth[..., 1, 0] = my * dfdxi
    dth[..., 2, 0] = 1.0 - dfdxi
    dth[..., :, 1] = -dpix[..., :, 0] * np.asarray(mx)[..., None]
    dth[..., :, 2] = -dpix[..., :, 1] * np.asarray(my)[..., None]
    dth[..., :, 3] = -dpix[..., :, 0]
    dth[..., :, 4] = -dpix[..., :, 1]
    return rays, valid, dpix, dth


def project(params, points, *, return_valid=False):
    """Project 3D points to pixels with eq. (1).

    Parameters
    ----------
    params : SensorParams or ndarray, shape (..., 8)
        Sensor parameters (order as :meth:`SensorParams.to_array`); an array
        broadcasts against the leading axes of ``points`` (e.g. walkers).
    points : array_like, shape (..., 3)
        Points in frame C, mm.
    return_valid : bool, optional
        Also return the mask of points inside the model's domain.

    Returns
    -------
    pixels : ndarray, shape (..., 2)
        ``(u, v)`` in px; NaN where ``xi * r - z <= 0`` (outside the domain).
    valid : ndarray of bool, shape (...)
        Only with ``return_valid=True``.

    Examples
    --------
    >>> import bayescal as bc
    >>> bc.project(bc.SensorParams.paper(), [1000.0, 0.0, 0.0])
    array([455., 300.])
    """
    theta = to_identifiable(as_param_array(params))
    points = as_points(points)
    uv, valid = project_theta(theta, points)
    return (uv, valid) if return_valid else uv


def backproject(params, pixels, *, return_valid=False):
    """Back-project pixels to unit rays in frame C (closed-form inverse of eq. (1)).

    Parameters
    ----------
    params : SensorParams or ndarray, shape (..., 8)
    pixels : array_like, shape (..., 2)
        ``(u, v)`` in px.
    return_valid : bool, optional
        Also return the mask of pixels that have a ray.

    Returns
    -------
    rays : ndarray, shape (..., 3)
        Unit vectors from the mirror focus (NaN where no ray exists).
    valid : ndarray of bool, shape (...)
        Only with ``return_valid=True``.

    Examples
    --------
    >>> import numpy as np
    >>> import bayescal as bc
    >>> ray = bc.backproject(bc.SensorParams.paper(), np.array([400.0, 300.0]))
    >>> np.round(ray, 12) + 0.0      # the principal point sees straight down
    array([ 0.,  0., -1.])
    """
    theta = to_identifiable(as_param_array(params))
    pixels = as_pixels(pixels)
    rays, valid = backproject_theta(theta, pixels)
    return (rays, valid) if return_valid else rays
