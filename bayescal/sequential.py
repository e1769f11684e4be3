"""Sequential calibration (paper, section II): camera first, then the laser.

Stage 1 (sec. II-A) fits the camera intrinsics and the pose of the calibration
patterns to the measured pattern points and their pixels; stage 2 (sec. II-B)
back-projects the laser pixels seen on the calibration planes with the stage-1
camera, intersects the rays with those planes and fits the laser cone (eq. 3)
or plane (eq. 2) to the 3D points so obtained. ``docs/calibration.md``
describes the method, the covariance and what is and is not included in it.

Stage-1 unknowns, in this order::

    p1 = (xi, gamma_u, gamma_v, u0, v0, angle_x, angle_y, angle_z, t_x, t_y, t_z)

``phi`` is held fixed (``fix_phi``): the pixels depend on ``phi``, ``alpha_u``
and ``alpha_v`` only through ``gamma_u = alpha_u (xi + phi)`` and
``gamma_v = alpha_v (xi + phi)``, so fitting all three is degenerate (fact 1,
``docs/model.md``, "Measured facts"). The pattern pose maps the world frame W of the measured points to
frame C: ``P_C = R P_W + t`` with ``R = rotation_matrix(angles)``.
"""

from __future__ import annotations

import numpy as np
from scipy.linalg import solve_triangular
from scipy.optimize import least_squares

from ._validation import as_finite_array, as_pixels, check_positive, resolve_rng
from .camera import backproject_theta, project_theta
from .laser import cone_distance, triangulate, triangulate_plane
from .parameters import PARAM_NAMES, SensorParams
from .results import (
    CalibrationResult,
    ConvergenceError,
    covariance_8_from_identifiable,
    identifiability_report,
    identifiable_to_paper_jacobian,
)
from .scenes import CalibrationData, Dataset

__all__ = ["calibrate_sequential", "POSE_NAMES", "fit_plane"]

POSE_NAMES = ("angle_x", "angle_y", "angle_z", "t_x", "t_y", "t_z")
_N1 = 11          # stage-1 unknowns: 5 camera + 6 pose
_FITS = ("cone", "plane")
_METHODS = ("lm", "trf")
_TOL = 1e-12


# --------------------------------------------------------------------------- pose
def _rotation_and_jacobian(angles):
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
def _stage1_residuals(p1, grid_w, grid_pix, *, jacobian=False):
    """Pixel residuals (2M,) of the pattern points and, optionally, d/d p1 (2M, 11)."""
    R, dR = _rotation_and_jacobian(p1[5:8])
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


def _laplace_covariance(J, sigma):
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
        raise ValueError(f"points must have shape (K, 3) with K >= 3, got {P.shape}")
    c = P.mean(axis=0)
    _, s, vt = np.linalg.svd(P - c, full_matrices=False)
    if s[1] <= 1e-12 * max(s[0], 1e-300):
        raise ValueError("points lie on a line (or coincide): the plane is undetermined")
    n = vt[2]
    d = -n @ c
    if d < 0:
        n, d = -n, -d
    rms = float(s[2] / np.sqrt(P.shape[0]))
    return np.append(n, d), rms


def _laser_points(p1, planes_w, pix, plane_idx, *, jacobian=False):
    """Laser points on the calibration planes in C, from the stage-1 estimate.

    Returns ``P`` (K, 3), ``valid`` (K,) and with ``jacobian=True`` also
    ``dP/d pix`` (K, 3, 2) and ``dP/d p1`` (K, 3, 11).
    """
    R, dR = _rotation_and_jacobian(p1[5:8])
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


def _cone_jacobians(hb, P):
    """d r / d (h, beta) (K, 2) and d r / d P (K, 3) of the cone distance."""
    h, b = hb
    rho = np.hypot(P[:, 0], P[:, 1])
    A = np.column_stack([np.full(len(P), -np.sin(b)),
                         -rho * np.sin(b) - (P[:, 2] + h) * np.cos(b)])
    with np.errstate(divide="ignore", invalid="ignore"):
        dr = np.column_stack([np.cos(b) * P[:, 0] / rho, np.cos(b) * P[:, 1] / rho,
                              np.full(len(P), -np.sin(b))])
    return A, dr


# --------------------------------------------------------------------------- input
def _unpack(dataset):
    """Return (CalibrationData, room pixels or None, true params or None)."""
    if isinstance(dataset, Dataset):
        calib = dataset.calibration
        if calib is None:
            raise ValueError("dataset has no calibration data (dataset.calibration is None); "
                             "the sequential method needs calibration patterns")
        return calib, as_pixels(dataset.pixels, "dataset.pixels")
    if isinstance(dataset, CalibrationData):
        return dataset, None
    raise TypeError(f"dataset must be a bayescal.Dataset or a bayescal.CalibrationData, "
                    f"got {type(dataset).__name__}")


def _check_calibration(calib):
    pre = "dataset.calibration."
    grid_w = as_finite_array(calib.grid_points, pre + "grid_points", last_dim=3)
    grid_pix = as_pixels(calib.grid_pixels, pre + "grid_pixels")
    grid_plane = np.asarray(calib.grid_plane)
    laser_pix = as_pixels(calib.laser_pixels, pre + "laser_pixels")
    laser_plane = np.asarray(calib.laser_plane)
    if grid_w.ndim != 2 or grid_pix.shape != (len(grid_w), 2) or grid_plane.shape != (
            len(grid_w),):
        raise ValueError(f"{pre}grid_points (M, 3), grid_pixels (M, 2) and grid_plane (M,) "
                         f"must have matching lengths, got shapes {grid_w.shape}, "
                         f"{grid_pix.shape}, {grid_plane.shape}")
    if laser_pix.ndim != 2 or laser_plane.shape != (len(laser_pix),):
        raise ValueError(f"{pre}laser_pixels (K, 2) and laser_plane (K,) must have matching "
                         f"lengths, got shapes {laser_pix.shape}, {laser_plane.shape}")
    if 2 * len(grid_w) <= _N1 + 1:
        raise ValueError(f"too few grid points: {pre}grid_points has {len(grid_w)}, need at "
                         f"least {(_N1 + 2) // 2 + 1} for {_N1} unknowns and a noise estimate")
    if len(laser_pix) < 3:
        raise ValueError(f"too few laser pixels: {pre}laser_pixels has {len(laser_pix)}, "
                         "need at least 3")
    for name, idx in (("grid_plane", grid_plane), ("laser_plane", laser_plane)):
        if not np.issubdtype(idx.dtype, np.integer) or (idx.size and idx.min() < 0):
            raise ValueError(f"{pre}{name} must hold non-negative integer plane indices, "
                             f"got dtype {idx.dtype}")
    return grid_w, grid_pix, grid_plane, laser_pix, laser_plane


def _fit_calibration_planes(grid_w, grid_plane, laser_plane):
    """Fit one plane (W frame) per plane index used by the laser pixels."""
    planes = np.full((int(max(grid_plane.max(), laser_plane.max())) + 1, 4), np.nan)
    for j in np.unique(laser_plane):
        pts = grid_w[grid_plane == j]
        if len(pts) < 3:
            raise ValueError(f"calibration plane {j} carries laser pixels but only {len(pts)} "
                             "grid points; at least 3 (not on a line) are needed to fit it")
        planes[j], _ = fit_plane(pts)
    return planes


def _check_options(init, init_pose, fix_phi, sigma_px):
    init = SensorParams.paper() if init is None else init
    if not isinstance(init, SensorParams):
        raise TypeError(f"init must be a SensorParams or None, got {type(init).__name__}")
    pose0 = np.zeros(6) if init_pose is None else as_finite_array(init_pose, "init_pose")
    if pose0.shape != (6,):
        raise ValueError(f"init_pose must have shape (6,) {POSE_NAMES}, got {pose0.shape}")
    try:
        fix_phi = float(fix_phi)
    except (TypeError, ValueError):
        raise TypeError(f"fix_phi must be a number, got {fix_phi!r}") from None
    if not np.isfinite(fix_phi) or init.xi + fix_phi <= 0:
        raise ValueError(f"fix_phi must be finite with xi + fix_phi > 0, got {fix_phi!r} "
                         f"(init.xi = {init.xi})")
    if sigma_px is not None:
        sigma_px = check_positive(sigma_px, "sigma_px")
    return init, pose0, fix_phi, sigma_px


def _check_count(value, name, *, minimum):
    if isinstance(value, bool) or not isinstance(value, (int, np.integer)) or value < minimum:
        raise ValueError(f"{name} must be an integer >= {minimum}, got {value!r}")
    return int(value)


# --------------------------------------------------------------------------- main
def calibrate_sequential(dataset, *, init=None, init_pose=None, fix_phi=0.0, fit="cone",
                         sigma_px=None, method="lm", max_nfev=2000, restarts=0, rng=None):
    """Sequential calibration of the paper's section II: camera, then laser.

    Parameters
    ----------
    dataset : Dataset or CalibrationData
        The calibration patterns: measured pattern points ``grid_points``
        (M, 3) in mm in the pattern frame W, taken as exact (approximate ones
        are used as given), their pixels ``grid_pixels`` (M, 2), the plane
        index of each point, and the laser pixels seen on those planes. With a
        :class:`Dataset`, its room pixels ``dataset.pixels`` (N, 2) are then
        reconstructed.
    init : SensorParams, optional
        Starting camera and laser values; default :meth:`SensorParams.paper`
        (the design values). Its ``phi`` is ignored (see ``fix_phi``).
    init_pose : array_like, shape (6,), optional
        Starting pose ``(angle_x, angle_y, angle_z, t_x, t_y, t_z)`` (rad, mm)
        of W in C; default the identity (zeros).
    fix_phi : float, optional
        Value at which ``phi`` is held: the data cannot determine it (only
        ``alpha * (xi + phi)`` is seen), so ``alpha_u``, ``alpha_v`` are
        reported for this ``phi`` and ``phi``'s variance is 0.
    fit : {"cone", "plane"}, optional
        Laser model fitted in stage 2: the cone of eq. (3) (default), or the
        plane of eq. (2). With ``"plane"``, ``h`` and ``beta`` are not
        estimated: ``params.h`` and ``params.beta`` are copied from ``init``
        and their rows of the covariance are NaN; the plane ``(a, b, c, d)``
        is ``result.extras["laser_plane"]`` and the room pixels are
        reconstructed on it.
    sigma_px : float, optional
        Pixel noise (px) used for the covariance; default: estimated from the
        stage-1 residuals, ``RMS / sqrt(1 - 11 / (2 M))``.
    method : {"lm", "trf"}, optional
        :func:`scipy.optimize.least_squares` method (Levenberg-Marquardt as in
        the paper, or trust-region reflective).
    max_nfev : int, optional
        Maximum residual evaluations per least-squares solve.
    restarts : int, optional
        Extra stage-1 starts from the camera part of ``init`` perturbed by
        +-10 % (uniform), drawn from ``rng``; the lowest cost wins.
    rng : numpy.random.Generator, int or None
        Randomness for ``restarts`` (unused when ``restarts == 0``).

    Returns
    -------
    CalibrationResult
        ``method="sequential"``; ``points`` are the reconstructed room points
        (None for a bare CalibrationData); ``extras`` holds ``"pose"`` (6,),
        ``"pose_covariance"`` (6, 6), ``"stage1_covariance"`` (11, 11) of
        ``(xi, gamma_u, gamma_v, u0, v0, pose)``, ``"laser_points"`` (K, 3)
        in C, ``"calibration_planes"`` (P, 4) in W, ``"sigma_px_used"``,
        ``"laser_model"`` and per-stage statistics.

    Raises
    ------
    ConvergenceError
        If a least-squares stage fails, ends non-finite or ends outside the
        model (``h <= 0``, ``beta`` outside (0, pi/2)); ``.result`` holds the
        flagged result (None if none can be formed).
    ValueError, TypeError
        For bad input, naming the argument: non-finite pixels or points,
        mismatched lengths, too few grid points (fewer than 7) or laser pixels
        (fewer than 3), a plane with laser pixels but fewer than 3 grid points,
        a dataset without calibration data, bad options.
    """
    calib, room_pixels = _unpack(dataset)
    grid_w, grid_pix, grid_plane, laser_pix, laser_plane = _check_calibration(calib)
    init, pose0, fix_phi, sigma_px = _check_options(init, init_pose, fix_phi, sigma_px)
    if fit not in _FITS:
        raise ValueError(f"fit must be one of {_FITS}, got {fit!r}")
    if method not in _METHODS:
        raise ValueError(f"method must be one of {_METHODS}, got {method!r}")
    max_nfev = _check_count(max_nfev, "max_nfev", minimum=1)
    restarts = _check_count(restarts, "restarts", minimum=0)
    planes_w = _fit_calibration_planes(grid_w, grid_plane, laser_plane)

    s1 = _run_stage1(grid_w, grid_pix, init, pose0, method=method, max_nfev=max_nfev,
                     restarts=restarts, rng=rng)
    theta = np.concatenate([s1.x[:5], [init.h, init.beta]])
    n_res1 = grid_pix.size
    rms1 = float(np.sqrt(np.mean(s1.fun**2)))
    sigma_est = rms1 / np.sqrt(1.0 - _N1 / n_res1)
    sigma = sigma_est if sigma_px is None else sigma_px
    info = {"grid_w": grid_w, "grid_pix": grid_pix, "laser_pix": laser_pix,
            "laser_plane": laser_plane, "planes_w": planes_w, "fix_phi": fix_phi,
            "sigma": sigma, "sigma_est": sigma_est, "rms1": rms1, "n_res1": n_res1,
            "nfev": s1.nfev, "init": init, "room_pixels": room_pixels}
    if not (s1.success and np.all(np.isfinite(s1.x)) and np.isfinite(rms1)):
        _fail(f"stage 1 (camera) did not converge: {s1.message}", theta, s1, info)
    C1 = _laplace_covariance(_stage1_residuals(s1.x, grid_w, grid_pix, jacobian=True), sigma)

    P, valid = _laser_points(s1.x, planes_w, laser_pix, laser_plane)
    if not np.all(valid):
        bad = np.flatnonzero(~valid)
        _fail(f"{bad.size} laser pixels (first index {bad[0]}) do not meet their calibration "
              "plane with the stage-1 camera", theta, s1, info, C1=C1)
    if fit == "cone":
        return _finish_cone(s1, C1, theta, P, info, method=method, max_nfev=max_nfev)
    return _finish_plane(s1, C1, theta, P, info)


def _run_stage1(grid_w, grid_pix, init, pose0, *, method, max_nfev, restarts, rng):
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
        r0 = _stage1_residuals(x, grid_w, grid_pix)
        if not np.all(np.isfinite(r0)):
            continue                           # this start puts pattern points off the model
        sol = _solve(lambda p: _stage1_residuals(p, grid_w, grid_pix),
                     lambda p: _stage1_residuals(p, grid_w, grid_pix, jacobian=True), x,
                     method=method, max_nfev=max_nfev)
        nfev += sol.nfev
        finite = np.all(np.isfinite(sol.fun))
        if finite and (best is None or sol.cost < best.cost or not best.success):
            best = sol
    if best is None:
        raise ValueError("init/init_pose project some calibration grid points outside the "
                         "camera model (xi * r - z <= 0); give a starting point closer to "
                         "the sensor")
    best.nfev = nfev
    return best


def _stage2_cone(P, hb0, *, method, max_nfev):
    def fun(hb):
        return cone_distance(hb[0], hb[1], P)

    def jac(hb):
        return _cone_jacobians(hb, P)[0]

    return _solve(fun, jac, np.asarray(hb0, float), method=method, max_nfev=max_nfev)


def _finish_cone(s1, C1, theta, P, info, *, method, max_nfev):
    s2 = _stage2_cone(P, theta[5:], method=method, max_nfev=max_nfev)
    info["nfev"] += s2.nfev
    theta = np.concatenate([s1.x[:5], s2.x])
    if not (s2.success and np.all(np.isfinite(s2.x)) and np.all(np.isfinite(s2.fun))):
        _fail(f"stage 2 (laser cone) did not converge: {s2.message}", theta, s1, info, C1=C1)
    if not (0 < s2.x[1] < np.pi / 2 and s2.x[0] > 0):
        hint = (" (beta >= pi/2: the laser points look like a plane; try fit='plane')"
                if s2.x[1] >= np.pi / 2 else "")
        _fail(f"stage 2 ended outside the model (h = {s2.x[0]:.4g} mm, beta = "
              f"{s2.x[1]:.4g} rad){hint}", theta, s1, info, C1=C1)
    # first-order covariance of (h, beta): laser-pixel noise + stage-1 uncertainty
    _, _, dPpix, dPp1 = _laser_points(s1.x, info["planes_w"], info["laser_pix"],
                                      info["laser_plane"], jacobian=True)
    A, dr = _cone_jacobians(s2.x, P)
    g_pix = np.einsum("ki,kij->kj", dr, dPpix)                   # (K, 2)
    B1 = np.einsum("ki,kij->kj", dr, dPp1)                       # (K, 11)
    Minv = np.linalg.inv(A.T @ A)
    w = np.sum(g_pix**2, axis=1)                                 # var(r_k) / sigma^2
    G1 = -Minv @ A.T @ B1
    cov_hb_pix = info["sigma"] ** 2 * Minv @ (A.T * w) @ A @ Minv
    C13 = np.zeros((13, 13))
    C13[:11, :11] = C1
    C13[11:, 11:] = cov_hb_pix + G1 @ C1 @ G1.T
    C13[:11, 11:] = C1 @ G1.T
    C13[11:, :11] = C13[:11, 11:].T
    keep = [0, 1, 2, 3, 4, 11, 12]
    cov7 = C13[np.ix_(keep, keep)]
    rms2 = float(np.sqrt(np.mean(s2.fun**2)))
    # identifiability of both stages together, whitened, w.r.t. the 8 paper params + pose
    params = _params(theta, info["fix_phi"])
    T = identifiable_to_paper_jacobian(params)                     # (7, 8)
    J1 = _stage1_residuals(s1.x, info["grid_w"], info["grid_pix"], jacobian=True)
    J2 = np.zeros((len(P), 13))
    J2[:, :11] = B1
    J2[:, 11:] = A
    J2 /= np.sqrt(w)[:, None]          # whitened up to the common factor 1 / sigma
    Jall = np.vstack([np.column_stack([J1, np.zeros((len(J1), 2))]), J2])
    J8 = np.column_stack([Jall[:, keep] @ T, Jall[:, 5:11]])
    report = identifiability_report(J8, PARAM_NAMES + POSE_NAMES)
    chi2 = _stage2_chi2(s2.fun, A, info["sigma"] ** 2 * w, B1, C1)
    extras = {"laser_model": "cone", "stage2_covariance_hb": C13[11:, 11:],
              "stage2": {"n_residuals": len(P), "n_unknowns": 2, "nfev": s2.nfev,
                         "rms_mm": rms2, "chi2_per_dof": chi2}}
    points = None
    if info["room_pixels"] is not None:
        points = triangulate(params, info["room_pixels"])
    return _result(params, theta, cov7, points, {"cone_mm": rms2}, s1, C1, P, info, report,
                   extras, n_res=info["n_res1"] + len(P), n_unk=_N1 + 2,
                   message=f"stage 1: {s1.message} | stage 2: {s2.message}")


def _stage2_chi2(r, A, var_pix, B1, C1):
    """Goodness of fit of stage 2 per degree of freedom, about 1 when consistent.

    The first-order covariance of the stage-2 residuals under pixel noise and
    stage-1 uncertainty is ``S = diag(var_pix) + B1 C1 B1^T``. With ``r`` the
    least-squares residuals, ``min_d (r - A d)^T S^-1 (r - A d)`` is then
    chi-square with K - 2 degrees of freedom; it is returned divided by K - 2.
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
    return float(np.sum((x - Y @ d) ** 2) / max(len(r) - 2, 1))


def _finish_plane(s1, C1, theta, P, info):
    plane, rms2 = fit_plane(P)
    params = _params(theta, info["fix_phi"])
    cov7 = np.full((7, 7), np.nan)
    cov7[:5, :5] = C1[:5, :5]
    report = _stage1_report(s1.x, params, info)
    points = None
    if info["room_pixels"] is not None:
        points = triangulate_plane(params, info["room_pixels"], plane)
    extras = {"laser_model": "plane", "laser_plane": plane,
              "stage2": {"n_residuals": len(P), "n_unknowns": 3, "nfev": 0, "rms_mm": rms2}}
    return _result(params, theta, cov7, points, {"plane_mm": rms2}, s1, C1, P, info, report,
                   extras, n_res=info["n_res1"] + len(P), n_unk=_N1 + 3,
                   message=f"stage 1: {s1.message} | stage 2: total least squares plane")


def _stage1_report(p1, params, info):
    """Identifiability of stage 1 w.r.t. the six camera paper parameters and the pose."""
    T = identifiable_to_paper_jacobian(params)[:5, :6]              # camera rows/columns
    J1 = _stage1_residuals(p1, info["grid_w"], info["grid_pix"], jacobian=True)
    J8 = np.column_stack([J1[:, :5] @ T, J1[:, 5:]])        # whitening 1/sigma: irrelevant
    if not np.all(np.isfinite(J8)):
        J8 = np.zeros_like(J8)
    return identifiability_report(J8, PARAM_NAMES[:6] + POSE_NAMES)


def _params(theta, phi):
    try:
        return SensorParams.from_identifiable(theta, phi)
    except ValueError as exc:
        raise ValueError(f"the estimate is not a valid sensor for fix_phi = {phi}: {exc}") from None


def _result(params, theta, cov7, points, rms_extra, s1, C1, P, info, report, extras, *,
            n_res, n_unk, message, converged=True):
    cov8 = covariance_8_from_identifiable(theta, info["fix_phi"], cov7, 0.0)
    extras.update({
        "pose": s1.x[5:].copy(), "pose_covariance": C1[5:, 5:].copy(),
        "stage1_covariance": C1, "laser_points": P,
        "calibration_planes": info["planes_w"], "sigma_px_used": info["sigma"],
        "stage1": {"n_residuals": info["n_res1"], "n_unknowns": _N1, "nfev": s1.nfev,
                   "rms_px": info["rms1"], "status": s1.status},
    })
    return CalibrationResult(
        method="sequential", params=params, points=points, covariance=cov8,
        covariance_identifiable=cov7, residual_rms={"pixel_px": info["rms1"], **rms_extra},
        sigma_px_estimated=float(info["sigma_est"]), n_residuals=int(n_res),
        n_unknowns=int(n_unk), converged=converged, message=message, nfev=int(info["nfev"]),
        identifiability=report, extras=extras)


def _fail(message, theta, s1, info, *, C1=None):
    """Raise ConvergenceError carrying the best result that can still be formed.

    If the last iterate is not a valid sensor (e.g. ``beta >= pi/2``), the flagged
    result reports the stage-1 camera with ``h``, ``beta`` from ``init`` and keeps the
    raw iterate in ``extras["theta_raw"]``.
    """
    init = info["init"]
    result = None
    for th in (theta, np.concatenate([theta[:5], [init.h, init.beta]])):
        if not np.all(np.isfinite(th)):
            continue
        try:
            params = SensorParams.from_identifiable(th, info["fix_phi"])
        except ValueError:
            continue
        cov7 = np.full((7, 7), np.nan)
        if C1 is not None:
            cov7[:5, :5] = C1[:5, :5]
        C1_ = np.full((_N1, _N1), np.nan) if C1 is None else C1
        report = _stage1_report(s1.x, params, info)
        result = _result(params, th, cov7, None, {}, s1, C1_, None, info, report,
                         {"theta_raw": np.asarray(theta, float)}, n_res=info["n_res1"],
                         n_unk=_N1, message=message, converged=False)
        break
    raise ConvergenceError(message, result)
