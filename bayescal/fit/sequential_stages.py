"""The two stages of the sequential calibration: residuals, Jacobians and solvers.

Stage 1 (paper sec. II-A): the pixel residuals of the calibration pattern
points and their Jacobian with respect to

    p1 = (xi, gamma_u, gamma_v, u0, v0, angle_x, angle_y, angle_z, t_x, t_y, t_z)

(camera in identifiable coordinates, then the pose of the pattern frame W in C,
``P_C = R P_W + t``). Stage 2 (sec. II-B): laser pixels back-projected onto the
calibration planes, the cone distance of eq. (3) and its Jacobians, the
first-order covariance of ``(h, beta)`` and the standardized residuals of both
stages. :mod:`bayescal.fit.sequential` runs them and assembles the result;
``docs/calibration.md`` describes the method.
"""

from __future__ import annotations

import numpy as np
from scipy.linalg import solve_triangular
from scipy.optimize import least_squares

from .._validation import as_finite_array, resolve_rng
from ..errors import InvalidValueError
from ..sensor.camera import backproject_theta, project_theta
from ..sensor.laser import cone_distance
from ..sensor.pose import cone_distance_pose

__all__ = ["fit_plane", "N_STAGE1", "rotation_and_jacobian", "stage1_residuals",
           "laplace_covariance", "laser_points", "cone_jacobians", "run_stage1", "run_pose_stage",
           "camera_stage1_covariance", "camera_second_order", "with_camera_part", "stage1_noise",
           "stage2_cone",
           "stage2_chi2", "cone_covariance", "plane_residual_jacobians", "standardized_stage1",
           "standardized_stage2"]

#: stage-1 unknowns: 5 camera + 6 pose
N_STAGE1 = 11
_N1 = N_STAGE1
_TOL = 1e-12

# --------------------------------------------------------------------------- pose
def rotation_and_jacobian(angles):
    """``R = Rz(c) Ry(b) Rx(a)`` (as :func:`rotation_matrix`) and ``dR[k] = dR/d angle_k``.

    Returns
    -------
    R : ndarray, shape (3, 3)
    dR : ndarray, shape (3, 3, 3)
    """
    a, b, c = angles
    ca, sa, cb, sb, cc, sc = np.cos(a), np.sin(a), np.cos(b), np.sin(b), np.cos(c), np.sin(c)
    Rx = np.array([[1, 0, 0], [0, ca, -sa], [0, sa, ca]])
    Ry = np.array([[cb, 0, sb], [0, 1, 0], [-sb, 0, cb]])
    Rz = np.array([[cc, -sc, 0], [sc, cc, 0], [0, 0, 1]])
    dRx = np.array([[0, 0, 0], [0, -sa, -ca], [0, ca, -sa]])
    dRy = np.array([[-sb, 0, cb], [0, 0, 0], [-cb, 0, -sb]])
    dRz = np.array([[-sc, -cc, 0], [cc, -sc, 0], [0, 0, 0]])
    R = Rz @ Ry @ Rx
    dR = np.stack([Rz @ Ry @ dRx, Rz @ dRy @ Rx, dRz @ Ry @ Rx])
    return R, dR


def _theta7(cam5):
    """Pad the 5 camera coordinates to a theta of shape (7,) (h, beta unused)."""
    return np.concatenate([cam5, [1.0, 1.0]])


# --------------------------------------------------------------------------- stage 1
def stage1_residuals(p1, grid_w, grid_pix, *, jacobian=False):
    """Pixel residuals (2M,) of the pattern points and, optionally, d/d p1 (2M, 11)."""
    R, dR = rotation_and_jacobian(p1[5:8])
    P = grid_w @ R.T + p1[8:11]
    if not jacobian:
        uv, _ = project_theta(_theta7(p1[:5]), P)
        return (uv - grid_pix).ravel()
    _, _, dP, dth = project_theta(_theta7(p1[:5]), P, jacobian=True)
    J = np.empty(grid_w.shape[:1] + (2, _N1))
    J[..., :5] = dth[..., :5]
    dP_dang = np.einsum("kij,mj->mik", dR, grid_w)          # (M, 3, 3): column k = dR_k P_W
    J[..., 5:8] = dP @ dP_dang
    J[..., 8:11] = dP
    return J.reshape(-1, _N1)


def laplace_covariance(J, sigma):
    """``sigma^2 (J^T J)^-1`` through the SVD of J (shape (n, p) -> (p, p))."""
    _, s, vt = np.linalg.svd(J, full_matrices=False)
    with np.errstate(divide="ignore"):
        inv = np.where(s > s[0] * 1e-14, 1.0 / s**2, np.inf)
    return sigma**2 * (vt.T * inv) @ vt


def _solve(fun, jac, x0, *, method, max_nfev, x_scale="jac"):
    kw = {"ftol": _TOL, "xtol": _TOL, "gtol": _TOL}
    return least_squares(fun, x0, jac=jac, method=method, max_nfev=max_nfev, x_scale=x_scale,
                         **kw)


# --------------------------------------------------------------------------- planes
def fit_plane(points):
    """Total-least-squares plane ``a x + b y + c z + d = 0`` through 3D points.

    Parameters
    ----------
    points : array_like, shape (K, 3)
        At least 3 points not on one line, mm.

    Returns
    -------
    plane : ndarray, shape (4,)
        ``(a, b, c, d)`` with ``(a, b, c)`` a unit normal oriented so that
        ``d >= 0`` (the origin is on the positive side); ``d`` is the distance
        from the origin in mm.
    rms : float
        RMS distance of the points from the plane, mm.
    """
    P = as_finite_array(points, "points", last_dim=3)
    if P.ndim != 2 or P.shape[0] < 3:
        raise InvalidValueError(f"points must have shape (K, 3) with K >= 3, got {P.shape}")
    c = P.mean(axis=0)
    _, s, vt = np.linalg.svd(P - c, full_matrices=False)
    if s[1] <= 1e-12 * max(s[0], 1e-300):
        raise InvalidValueError("points lie on a line (or coincide): the plane is undetermined")
    n = vt[2]
    d = -n @ c
    if d < 0:
        n, d = -n, -d
    rms = float(s[2] / np.sqrt(P.shape[0]))
    return np.append(n, d), rms


def laser_points(p1, planes_w, pix, plane_idx, *, jacobian=False):
    """Laser points on the calibration planes in C, from the stage-1 estimate.

    Returns ``P`` (K, 3), ``valid`` (K,) and with ``jacobian=True`` also
    ``dP/d pix`` (K, 3, 2) and ``dP/d p1`` (K, 3, 11).
    """
    R, dR = rotation_and_jacobian(p1[5:8])
    t = p1[8:11]
    nw, dw = planes_w[plane_idx, :3], planes_w[plane_idx, 3]     # nw.P_W + dw = 0
    nc = nw @ R.T
    oc = -dw + nc @ t                                             # nc.P_C = oc
    out = backproject_theta(_theta7(p1[:5]), pix, jacobian=jacobian)
    d = out[0]
    den = np.sum(nc * d, axis=-1)
    with np.errstate(divide="ignore", invalid="ignore"):
        s = oc / den
    valid = out[1] & np.isfinite(s) & (s > 0)
    P = s[:, None] * d
    if not jacobian:
        return P, valid
    ddpix, ddth = out[2], out[3]
    eye = np.eye(3)
    dP_dd = s[:, None, None] * (eye - d[:, :, None] * nc[:, None, :] / den[:, None, None])
    dP_dn = -(s / den)[:, None, None] * d[:, :, None] * d[:, None, :]
    dP_do = d / den[:, None]
    dn_dang = np.einsum("kij,mj->mik", dR, nw)                    # (K, 3, 3)
    do_dang = np.einsum("mik,i->mk", dn_dang, t)                  # (K, 3)
    J = np.empty(P.shape + (_N1,))
    J[..., :5] = dP_dd @ ddth[..., :5]
    J[..., 5:8] = dP_dn @ dn_dang + dP_do[:, :, None] * do_dang[:, None, :]
    J[..., 8:11] = dP_do[:, :, None] * nc[:, None, :]
    return P, valid, dP_dd @ ddpix, J


def cone_jacobians(hb, P):
    """d r / d (h, beta) (K, 2) and d r / d P (K, 3) of the cone distance; with ``hb`` of
    six numbers ``(h, beta, tilt_x, tilt_y, offset_x, offset_y)`` those of the tilted,
    offset cone (:func:`~bayescal.sensor.pose.cone_distance_pose`), d r / d params (K, 6)."""
    if len(hb) > 2:
        return cone_distance_pose(hb, P, jacobian=True)[1:]
    h, b = hb
    rho = np.hypot(P[:, 0], P[:, 1])
    A = np.column_stack([np.full(len(P), -np.sin(b)),
                         -rho * np.sin(b) - (P[:, 2] + h) * np.cos(b)])
    with np.errstate(divide="ignore", invalid="ignore"):
        dr = np.column_stack([np.cos(b) * P[:, 0] / rho, np.cos(b) * P[:, 1] / rho,
                              np.full(len(P), -np.sin(b))])
    return A, dr


def run_stage1(grid_w, grid_pix, init, pose0, *, method, max_nfev, restarts, rng):
    x0 = np.concatenate([init.to_identifiable()[:5], pose0])
    starts = [x0]
    if restarts:
        gen = resolve_rng(rng)
        for _ in range(restarts):
            x = x0.copy()
            x[:5] *= 1.0 + gen.uniform(-0.1, 0.1, 5)
            starts.append(x)
    best, nfev = None, 0
    for x in starts:
        r0 = stage1_residuals(x, grid_w, grid_pix)
        if not np.all(np.isfinite(r0)):
            continue                           # this start puts pattern points off the model
        sol = _solve(lambda p: stage1_residuals(p, grid_w, grid_pix),
                     lambda p: stage1_residuals(p, grid_w, grid_pix, jacobian=True), x,
                     method=method, max_nfev=max_nfev)
        nfev += sol.nfev
        finite = np.all(np.isfinite(sol.fun))
        if finite and (best is None or sol.cost < best.cost or not best.success):
            best = sol
    if best is None:
        raise InvalidValueError("init/init_pose project some calibration grid points outside the "
                                "camera model (xi * r - z <= 0); give a starting point closer to "
                                "the sensor")
    best.nfev = nfev
    return best


def run_pose_stage(grid_w, grid_pix, cam5, pose0, *, method, max_nfev):
    """Stage 1 with the camera given (a camera calibrated beforehand): the pattern's pose
    alone, the camera held at ``cam5`` (5,). Returns the solver's result with ``x`` the
    eleven numbers ``p1`` (camera, then the fitted pose)."""
    cam5 = np.asarray(cam5, float)

    def fun(p):
        return stage1_residuals(np.r_[cam5, p], grid_w, grid_pix)

    if not np.all(np.isfinite(fun(pose0))):
        raise InvalidValueError("init_pose projects some calibration grid points outside the "
                                "camera model (xi * r - z <= 0); give a starting pose closer to "
                                "the patterns")
    sol = _solve(fun, lambda p: stage1_residuals(np.r_[cam5, p], grid_w, grid_pix,
                                                 jacobian=True)[:, 5:],
                 np.asarray(pose0, float), method=method, max_nfev=max_nfev)
    sol.x = np.r_[cam5, sol.x]
    return sol


def camera_stage1_covariance(p1, grid_w, grid_pix, cov5, sigma):
    """Covariance (11, 11) of ``p1`` when the camera comes with its covariance ``cov5``.

    The pose fitted with the camera held is ``pose(camera, pixels)``; to first order
    ``d pose = -(Jp^T Jp)^-1 Jp^T (Jc d camera + d pixels)`` (``Jc``, ``Jp`` the pixel
    residuals' Jacobians in the camera and the pose), so the camera's covariance reaches
    the pose, and through both the laser stage, beside the pattern pixels' noise
    ``sigma`` (px).
    """
    J = stage1_residuals(p1, grid_w, grid_pix, jacobian=True)
    Jc, Jp = J[:, :5], J[:, 5:]
    M = np.linalg.inv(Jp.T @ Jp)
    G = -M @ Jp.T @ Jc
    C = np.zeros((_N1, _N1))
    C[:5, :5] = cov5
    C[5:, :5] = G @ cov5
    C[:5, 5:] = C[5:, :5].T
    C[5:, 5:] = G @ cov5 @ G.T + sigma**2 * M
    return C


def camera_second_order(p1, hb, data, cov5, *, method, max_nfev):
    """The camera's share of the laser parameters' covariance, to second order.

    The laser stage is refitted (pose, then cone) with the camera moved one sd either
    way along each principal axis ``a_i`` of ``cov5``: with ``f(+-a_i)`` the results,
    ``g_i = (f+ - f-) / 2`` and ``q_i = (f+ + f-) / 2 - f(0)``, the covariance of
    ``f`` is ``sum g_i g_i^T + 2 q_i q_i^T`` (exact for a quadratic in a normal camera)
    and its covariance with the camera ``sum a_i g_i^T``. The height ``h`` bends with
    the camera: in the 2500 mm room of ``tests/validation/test_camera_laser.py`` one sd
    along the camera's main axis moved it by -1.2 and +12.9 mm against +-6.3 mm to first
    order; the first-order intervals of h covered 77 % at the 90 % level (300 rooms),
    these 97 % (150): conservative, since h's error is skewed (a plug-in h centred on the
    camera's mean is not at the mean of h over the camera, and moving it there by the
    ``q_i`` made the coverage worse, 82 %).

    Parameters
    ----------
    p1 : ndarray, shape (11,)
        The camera and the pattern pose fitted on it.
    hb : ndarray, shape (p,)
        The fitted laser parameters (``h, beta`` and, misaligned, the pose).
    data : tuple
        ``(grid_w, grid_pix, planes_w, laser_pix, laser_plane)``.
    cov5 : ndarray, shape (5, 5)
        The camera's covariance.

    Returns
    -------
    cov : ndarray, shape (p, p)
    cross : ndarray, shape (5, p)
        Covariance of the camera with the laser parameters.
    """
    grid_w, grid_pix, planes_w, laser_pix, laser_plane = data

    def refit(cam):
        s1 = run_pose_stage(grid_w, grid_pix, cam, p1[5:], method=method, max_nfev=max_nfev)
        P, _ = laser_points(s1.x, planes_w, laser_pix, laser_plane)
        return stage2_cone(P, hb, method=method, max_nfev=max_nfev).x

    w, V = np.linalg.eigh(cov5)
    A = V * np.sqrt(np.clip(w, 0.0, None))               # columns: one-sd principal axes
    f = [(refit(p1[:5] + a), refit(p1[:5] - a)) for a in A.T]
    G = np.array([(fp - fm) / 2 for fp, fm in f])
    Q = np.array([(fp + fm) / 2 - hb for fp, fm in f])
    return G.T @ G + 2 * Q.T @ Q, A @ G


def stage1_noise(p1, r, grid_w, grid_pix):
    """Pixel noise (px) of the pattern points from the residuals ``r`` (2M,) at ``p1`` with
    the directions of all eleven unknowns projected out (to first order, the residuals
    of a full stage 1): with the camera held at a calibration's values, the part of
    ``r`` its error explains is not noise (it measured 3x the noise in the 2500 mm room
    of ``tests/validation/test_camera_laser.py``)."""
    J = stage1_residuals(p1, grid_w, grid_pix, jacobian=True)
    rr = r - J @ np.linalg.lstsq(J, r, rcond=None)[0]
    return float(np.sqrt(rr @ rr / (len(r) - _N1)))


def stage2_cone(P, hb0, *, method, max_nfev):
    """The laser cone through the laser points ``P`` (K, 3): ``(h, beta)``, or with six
    starting values the tilted, offset cone (misaligned model)."""
    def fun(hb):
        return cone_distance_pose(hb, P) if len(hb) > 2 else cone_distance(hb[0], hb[1], P)

    def jac(hb):
        return cone_jacobians(hb, P)[0]

    return _solve(fun, jac, np.asarray(hb0, float), method=method, max_nfev=max_nfev)


def stage2_chi2(r, A, var_pix, B1, C1):
    """Goodness of fit of stage 2 per degree of freedom, about 1 when consistent.

    The first-order covariance of the stage-2 residuals under pixel noise and
    stage-1 uncertainty is ``S = diag(var_pix) + B1 C1 B1^T``. With ``r`` the
    least-squares residuals, ``min_d (r - A d)^T S^-1 (r - A d)`` is then
    chi-square with K - p degrees of freedom (p = 2 cone parameters, 6 for the tilted
    cone); it is returned divided by K - p.
    Values far above 1 mean the laser points are off the fitted planes or cone by
    more than that explains (e.g. errors of the measured pattern points, which the
    method does not model), and the (h, beta) covariance is then too small.
    """
    S = np.diag(var_pix) + B1 @ C1 @ B1.T
    try:
        L = np.linalg.cholesky(S)
    except np.linalg.LinAlgError:
        return float("nan")                # zero noise (exact data): undefined
    x = solve_triangular(L, r, lower=True)
    Y = solve_triangular(L, A, lower=True)
    d = np.linalg.lstsq(Y, x, rcond=None)[0]
    return float(np.sum((x - Y @ d) ** 2) / max(len(r) - A.shape[1], 1))


# --------------------------------------------------------------------------- covariance
def cone_covariance(p1, C1, hb, P, planes_w, laser_pix, laser_plane, sigma):
    """First-order covariance of the camera, the pose and ``(h, beta)`` together (and of
    the laser cone's tilt and offset when ``hb`` has their six numbers).

    ``(h, beta) = G_pix d(pixels) + G_1 d(p1)`` with ``G = -(A^T A)^-1 A^T B``
    (implicit-function theorem at the stage-2 solution): laser-pixel noise
    ``sigma`` (px) and the stage-1 covariance ``C1`` (11, 11).

    Returns
    -------
    C13 : ndarray, shape (13, 13) or (17, 17)
        Order ``p1`` then ``(h, beta)`` (mm, rad), then the laser pose.
    A : ndarray, shape (K, 2) or (K, 6)
        d cone distance / d (h, beta[, pose]).
    B1 : ndarray, shape (K, 11)
        d cone distance / d p1.
    w : ndarray, shape (K,)
        Variance of each cone distance under pixel noise, divided by ``sigma^2``.
    """
    _, _, dPpix, dPp1 = laser_points(p1, planes_w, laser_pix, laser_plane, jacobian=True)
    A, dr = cone_jacobians(hb, P)
    g_pix = np.einsum("ki,kij->kj", dr, dPpix)                   # (K, 2)
    B1 = np.einsum("ki,kij->kj", dr, dPp1)                       # (K, 11)
    Minv = np.linalg.inv(A.T @ A)
    w = np.sum(g_pix**2, axis=1)
    G1 = -Minv @ A.T @ B1
    cov_hb_pix = sigma**2 * Minv @ (A.T * w) @ A @ Minv
    C13 = np.zeros((11 + len(hb),) * 2)
    C13[:11, :11] = C1
    C13[11:, 11:] = cov_hb_pix + G1 @ C1 @ G1.T
    C13[:11, 11:] = C1 @ G1.T
    C13[11:, :11] = C13[:11, 11:].T
    return C13, A, B1, w


def plane_residual_jacobians(p1, plane, P, planes_w, laser_pix, laser_plane):
    """Jacobians of the fitted laser plane's residuals ``n . P_k + d`` (mm).

    Returns
    -------
    A : ndarray, shape (K, 3)
        d residual / d (two tilts of the normal, d).
    g_pix : ndarray, shape (K, 2)
        d residual / d laser pixel, mm/px.
    B1 : ndarray, shape (K, 11)
        d residual / d p1.
    """
    n = plane[:3]
    _, _, vt = np.linalg.svd(n[None, :])
    e1, e2 = vt[1], vt[2]                                        # orthonormal, normal to n
    A = np.column_stack([P @ e1, P @ e2, np.ones(len(P))])
    _, _, dPpix, dPp1 = laser_points(p1, planes_w, laser_pix, laser_plane, jacobian=True)
    return A, np.einsum("i,kij->kj", n, dPpix), np.einsum("i,kij->kj", n, dPp1)


# --------------------------------------------------------------------------- residuals
def standardized_stage1(r, J, sigma):
    """Stage-1 pixel residuals, each divided by its own sd ``sigma sqrt(1 - h_i)``.

    ``h_i`` is the leverage (diagonal of ``J (J^T J)^-1 J^T``): a fit absorbs
    part of the noise, ``sum h_i = 11``.

    Parameters
    ----------
    r : ndarray, shape (2M,)
        px.
    J : ndarray, shape (2M, 11)
        d r / d p1.
    sigma : float
        Pixel noise used, px.

    Returns
    -------
    ndarray, shape (2M,)
        Dimensionless; about N(0, 1) when the model holds at ``sigma``.
    """
    U, s, _ = np.linalg.svd(J, full_matrices=False)
    U = U[:, s > s[0] * 1e-12] if s[0] > 0 else U[:, :0]
    h = np.sum(U**2, axis=1)
    return r / (sigma * np.sqrt(np.clip(1.0 - h, 1e-12, 1.0)))


def standardized_stage2(r, A, var_pix, B1, C1):
    """Stage-2 residuals (mm), each divided by its first-order sd.

    The unweighted fit leaves ``r = (I - H) e`` with ``H = A (A^T A)^-1 A^T``
    and ``e`` the residuals' errors, of covariance
    ``S = diag(var_pix) + B1 C1 B1^T`` (laser-pixel noise and stage-1
    uncertainty); each ``r_k`` is divided by ``sqrt(((I - H) S (I - H))_kk)``.

    Parameters
    ----------
    r : ndarray, shape (K,)
        mm.
    A : ndarray, shape (K, p)
        d r / d laser-model parameters.
    var_pix : ndarray, shape (K,)
        Variance of each residual under pixel noise, mm^2.
    B1 : ndarray, shape (K, 11)
    C1 : ndarray, shape (11, 11)

    Returns
    -------
    ndarray, shape (K,)
        Dimensionless; about N(0, 1) when the model holds.
    """
    S = np.diag(var_pix) + B1 @ C1 @ B1.T
    Q, _ = np.linalg.qr(A)
    M = np.eye(len(r)) - Q @ Q.T
    var = np.einsum("ij,jk,ik->i", M, S, M)
    with np.errstate(divide="ignore", invalid="ignore"):
        return np.where(var > 0, r / np.sqrt(np.where(var > 0, var, 1.0)), np.nan)


def with_camera_part(p1, hb, P, info, C13, **kw):
    """``C13`` (:func:`cone_covariance`) with the laser block's share of the camera taken
    to second order (:func:`camera_second_order`), beside the pixel noise's first-order
    share; ``info`` holds the sequential fit's data, pattern noise and camera."""
    data = tuple(info[k] for k in ("grid_w", "grid_pix", "planes_w", "laser_pix",
                                   "laser_plane"))
    C1n = camera_stage1_covariance(p1, data[0], data[1], np.zeros((5, 5)), info["sigma"])
    out = C13.copy()
    out[11:, 11:] = cone_covariance(p1, C1n, hb, P, *data[2:], info["sigma"])[0][11:, 11:]
    S, X = camera_second_order(p1, hb, data, info["camera"][1], **kw)
    out[11:, 11:] += S
    out[:5, 11:], out[11:, :5] = X, X.T
    return out
