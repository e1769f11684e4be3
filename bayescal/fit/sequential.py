"""Sequential calibration (paper, section II): camera first, then the laser.

Stage 1 (sec. II-A) fits the camera intrinsics and the pose of the calibration
patterns to the measured pattern points and their pixels; stage 2 (sec. II-B)
back-projects the laser pixels seen on the calibration planes with the stage-1
camera, intersects the rays with those planes and fits the laser cone (eq. 3)
or plane (eq. 2) to the 3D points so obtained. The residuals, Jacobians and
covariance propagation of the stages are in :mod:`bayescal.fit.sequential_stages`;
this module checks the input, runs the stages and assembles the result.
``docs/calibration.md`` describes the method, the covariance and what is and is
not included in it.

Stage-1 unknowns, in this order::

    p1 = (xi, gamma_u, gamma_v, u0, v0, angle_x, angle_y, angle_z, t_x, t_y, t_z)

``phi`` is held fixed (``fix_phi``): the pixels depend on ``phi``, ``alpha_u``
and ``alpha_v`` only through ``gamma_u = alpha_u (xi + phi)`` and
``gamma_v = alpha_v (xi + phi)``, so fitting all three is degenerate (fact 1,
``docs/model.md``, "Measured facts"). The pattern pose maps the world frame W
of the measured points to frame C: ``P_C = R P_W + t`` with ``R = rotation_matrix(angles)``.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

from .._validation import as_finite_array, as_pixels, check_positive
from ..errors import InvalidTypeError, InvalidValueError
from ..results.calibration import (
    CalibrationResult,
    ConvergenceError,
    covariance_8_from_identifiable,
    identifiability_report,
    identifiable_to_paper_jacobian,
)
from ..scene.simulate import CalibrationData, Dataset
from ..sensor.laser import triangulate, triangulate_plane
from ..sensor.parameters import PARAM_NAMES, SensorParams, camera_moments, camera_whitener
from ..sensor.pose import POSE_NAMES as LASER_POSE_NAMES
from ..sensor.pose import LaserPose
from .sequential_stages import (
    N_STAGE1 as _N1,
)
from .sequential_stages import (
    camera_stage1_covariance,
    cone_covariance,
    fit_plane,
    laplace_covariance,
    laser_points,
    plane_residual_jacobians,
    run_pose_stage,
    run_stage1,
    stage1_noise,
    stage1_residuals,
    stage2_chi2,
    stage2_cone,
    standardized_stage1,
    standardized_stage2,
    with_camera_part,
)

__all__ = ["calibrate_sequential", "sequential_residuals", "SequentialResiduals", "POSE_NAMES",
           "fit_plane"]

POSE_NAMES = ("angle_x", "angle_y", "angle_z", "t_x", "t_y", "t_z")
_FITS = ("cone", "plane")
_METHODS = ("lm", "trf")


# --------------------------------------------------------------------------- input
def _unpack(dataset):
    """Return (CalibrationData, room pixels or None, true params or None)."""
    if isinstance(dataset, Dataset):
        calib = dataset.calibration
        if calib is None:
            raise InvalidValueError(
                "dataset has no calibration data (dataset.calibration is None); "
                "the sequential method needs calibration patterns")
        return calib, as_pixels(dataset.pixels, "dataset.pixels")
    if isinstance(dataset, CalibrationData):
        return dataset, None
    raise InvalidTypeError(f"dataset must be a bayescal.Dataset or a bayescal.CalibrationData, "
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
        raise InvalidValueError(f"{pre}grid_points (M, 3), grid_pixels (M, 2) and grid_plane (M,) "
                                f"must have matching lengths, got shapes {grid_w.shape}, "
                                f"{grid_pix.shape}, {grid_plane.shape}")
    if laser_pix.ndim != 2 or laser_plane.shape != (len(laser_pix),):
        raise InvalidValueError(f"{pre}laser_pixels (K, 2) and laser_plane (K,) must have matching "
                                f"lengths, got shapes {laser_pix.shape}, {laser_plane.shape}")
    if 2 * len(grid_w) <= _N1 + 1:
        raise InvalidValueError(
            f"too few grid points: {pre}grid_points has {len(grid_w)}, need at "
            f"least {(_N1 + 2) // 2 + 1} for {_N1} unknowns and a noise estimate")
    if len(laser_pix) < 3:
        raise InvalidValueError(f"too few laser pixels: {pre}laser_pixels has {len(laser_pix)}, "
                                "need at least 3")
    for name, idx in (("grid_plane", grid_plane), ("laser_plane", laser_plane)):
        if not np.issubdtype(idx.dtype, np.integer) or (idx.size and idx.min() < 0):
            raise InvalidValueError(f"{pre}{name} must hold non-negative integer plane indices, "
                                    f"got dtype {idx.dtype}")
    return grid_w, grid_pix, grid_plane, laser_pix, laser_plane


def _fit_calibration_planes(grid_w, grid_plane, laser_plane):
    """Fit one plane (W frame) per plane index used by the laser pixels."""
    planes = np.full((int(max(grid_plane.max(), laser_plane.max())) + 1, 4), np.nan)
    for j in np.unique(laser_plane):
        pts = grid_w[grid_plane == j]
        if len(pts) < 3:
            raise InvalidValueError(
                f"calibration plane {j} carries laser pixels but only {len(pts)} "
                "grid points; at least 3 (not on a line) are needed to fit it")
        planes[j], _ = fit_plane(pts)
    return planes


def _check_options(init, init_pose, fix_phi, sigma_px):
    init = SensorParams.paper() if init is None else init
    if not isinstance(init, SensorParams):
        raise InvalidTypeError(f"init must be a SensorParams or None, got {type(init).__name__}")
    pose0 = np.zeros(6) if init_pose is None else as_finite_array(init_pose, "init_pose")
    if pose0.shape != (6,):
        raise InvalidValueError(f"init_pose must have shape (6,) {POSE_NAMES}, got {pose0.shape}")
    try:
        fix_phi = float(fix_phi)
    except (TypeError, ValueError):
        raise InvalidTypeError(f"fix_phi must be a number, got {fix_phi!r}") from None
    if not np.isfinite(fix_phi) or init.xi + fix_phi <= 0:
        raise InvalidValueError(f"fix_phi must be finite with xi + fix_phi > 0, got {fix_phi!r} "
                                f"(init.xi = {init.xi})")
    if sigma_px is not None:
        sigma_px = check_positive(sigma_px, "sigma_px")
    return init, pose0, fix_phi, sigma_px


def _check_count(value, name, *, minimum):
    if isinstance(value, bool) or not isinstance(value, (int, np.integer)) or value < minimum:
        raise InvalidValueError(f"{name} must be an integer >= {minimum}, got {value!r}")
    return int(value)


# --------------------------------------------------------------------------- residuals
class SequentialResiduals(NamedTuple):
    """Raw and standardized residuals of a sequential calibration (:func:`sequential_residuals`)."""

    grid_px: np.ndarray
    grid_z: np.ndarray
    laser_mm: np.ndarray
    laser_z: np.ndarray


_RESIDUAL_KEYS = ("stage1_residuals_px", "stage1_residuals_std", "stage2_residuals_mm",
                  "stage2_residuals_std")


def sequential_residuals(result):
    """The residuals of both stages of a sequential result, for a residual plot.

    Kept in ``result.extras`` as plain arrays, so they survive
    :meth:`CalibrationResult.save` and :func:`bayescal.load_result`.

    Parameters
    ----------
    result : CalibrationResult
        From :func:`calibrate_sequential` (or loaded from its file).

    Returns
    -------
    SequentialResiduals
        ``grid_px`` (M, 2): stage-1 pixel residuals of the pattern points,
        ``observed - projected``, px. ``grid_z`` (M, 2): the same divided by
        ``sigma sqrt(1 - h_i)`` (``sigma`` the pixel noise used,
        ``extras["sigma_px_used"]``; ``h_i`` the leverage), dimensionless.
        ``laser_mm`` (K,): stage-2 residuals of the laser points on the
        calibration planes, mm (signed distance from the fitted cone, positive
        outside it, or from the fitted plane with ``fit="plane"``).
        ``laser_z`` (K,): the same divided by its first-order sd (laser-pixel
        noise and stage-1 uncertainty, less what the fit absorbs),
        dimensionless. Both standardized sets are about N(0, 1) when the model
        holds at the noise used; the pattern points' measurement errors, which
        the method does not model, widen them.

    Raises
    ------
    TypeError
        ``result`` is not a CalibrationResult.
    ValueError
        It is not a sequential result, or carries no residuals (a failed run,
        or a file written before they were kept).
    """
    if not isinstance(result, CalibrationResult):
        raise InvalidTypeError(f"result must be a CalibrationResult, got {type(result).__name__}")
    if result.method != "sequential":
        raise InvalidValueError(f"result must come from calibrate_sequential, got method "
                                f"{result.method!r}")
    missing = [k for k in _RESIDUAL_KEYS if result.extras.get(k) is None]
    if missing:
        raise InvalidValueError(
            f"result.extras has no {', '.join(missing)}: a failed run, or a file "
            "written before the residuals were kept")
    a, b, c, d = (np.asarray(result.extras[k], float) for k in _RESIDUAL_KEYS)
    return SequentialResiduals(a.reshape(-1, 2), b.reshape(-1, 2), c.ravel(), d.ravel())


# --------------------------------------------------------------------------- main
def calibrate_sequential(dataset, *, init=None, init_pose=None, fix_phi=0.0, fit="cone",
                         sigma_px=None, method="lm", max_nfev=2000, restarts=0, rng=None,
                         model="aligned", camera=None):
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
    model : {"aligned", "misaligned"}, optional
        Stage 2's cone: the paper's, coaxial with the camera (``h, beta``), or tilted
        and offset (``h, beta, tilt_x, tilt_y, offset_x, offset_y``, fitted to the laser
        points on the calibration planes; ``result.laser``, an (11, 11) identifiable
        covariance). With ``fit="cone"`` only.
    camera : object, optional
        A camera calibrated beforehand (``bc.calibrate_camera(views)``, a camera
        posterior, or ``(mean, cov)`` of ``xi, gamma_u, gamma_v, u0, v0``). Stage 1
        then fits only the patterns' pose, the camera held at its intrinsics, and the
        camera's covariance is carried through the pose into stage 2's covariance
        (``extras["stage1_covariance"]``: the camera's, and the pose's given it);
        ``restarts`` does not apply and ``init`` gives only ``h`` and ``beta``. The
        pattern pixels' noise is then estimated with the camera's directions
        projected out of their residuals too (its error is not their noise).

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

    Examples
    --------
    >>> import bayescal as bc
    >>> ds = bc.simulate_room(range_mm=1000, n_points=100, sigma_px=0.2, rng=0)
    >>> res = bc.calibrate_sequential(ds)
    >>> res.method, res.covariance().shape
    ('sequential', (8, 8))
    """
    calib, room_pixels = _unpack(dataset)
    grid_w, grid_pix, grid_plane, laser_pix, laser_plane = _check_calibration(calib)
    init, pose0, fix_phi, sigma_px = _check_options(init, init_pose, fix_phi, sigma_px)
    if fit not in _FITS:
        raise InvalidValueError(f"fit must be one of {_FITS}, got {fit!r}")
    if model not in ("aligned", "misaligned"):
        raise InvalidValueError(f"model must be one of ('aligned', 'misaligned'), got {model!r}")
    if model == "misaligned" and fit != "cone":
        raise InvalidValueError("model='misaligned' needs fit='cone' (a plane has no axis to tilt)")
    if method not in _METHODS:
        raise InvalidValueError(f"method must be one of {_METHODS}, got {method!r}")
    max_nfev = _check_count(max_nfev, "max_nfev", minimum=1)
    restarts = _check_count(restarts, "restarts", minimum=0)
    planes_w = _fit_calibration_planes(grid_w, grid_plane, laser_plane)

    cam = None if camera is None else camera_moments(camera)
    if cam is None:
        s1 = run_stage1(grid_w, grid_pix, init, pose0, method=method, max_nfev=max_nfev,
                        restarts=restarts, rng=rng)
    else:                                   # the camera given: stage 1 fits the pose alone
        s1 = run_pose_stage(grid_w, grid_pix, cam[0], pose0, method=method, max_nfev=max_nfev)
    n_fit1 = _N1 if cam is None else 6
    theta = np.concatenate([s1.x[:5], [init.h, init.beta]])
    n_res1 = grid_pix.size
    rms1 = float(np.sqrt(np.mean(s1.fun**2)))
    sigma_est = (rms1 / np.sqrt(1.0 - _N1 / n_res1) if cam is None
                 else stage1_noise(s1.x, s1.fun, grid_w, grid_pix))
    sigma = sigma_est if sigma_px is None else sigma_px
    info = {"grid_w": grid_w, "grid_pix": grid_pix, "laser_pix": laser_pix,
            "laser_plane": laser_plane, "planes_w": planes_w, "fix_phi": fix_phi,
            "sigma": sigma, "sigma_est": sigma_est, "rms1": rms1, "n_res1": n_res1,
            "nfev": s1.nfev, "init": init, "room_pixels": room_pixels, "model": model,
            "n_fit1": n_fit1, "camera": cam}
    if not (s1.success and np.all(np.isfinite(s1.x)) and np.isfinite(rms1)):
        _fail(f"stage 1 (camera) did not converge: {s1.message}", theta, s1, info)
    if cam is None:
        C1 = laplace_covariance(stage1_residuals(s1.x, grid_w, grid_pix, jacobian=True), sigma)
    else:
        C1 = camera_stage1_covariance(s1.x, grid_w, grid_pix, cam[1], sigma)

    P, valid = laser_points(s1.x, planes_w, laser_pix, laser_plane)
    if not np.all(valid):
        bad = np.flatnonzero(~valid)
        _fail(f"{bad.size} laser pixels (first index {bad[0]}) do not meet their calibration "
              "plane with the stage-1 camera", theta, s1, info, C1=C1)
    if fit == "cone":
        return _finish_cone(s1, C1, theta, P, info, method=method, max_nfev=max_nfev)
    return _finish_plane(s1, C1, theta, P, info)


def _finish_cone(s1, C1, theta, P, info, *, method, max_nfev):
    x0 = np.r_[theta[5:], np.zeros(4)] if info["model"] == "misaligned" else theta[5:]
    s2 = stage2_cone(P, x0, method=method, max_nfev=max_nfev)
    info["nfev"] += s2.nfev
    p2 = len(s2.x)                                   # 2, or 6 with the laser pose
    theta = np.concatenate([s1.x[:5], s2.x])
    if not (s2.success and np.all(np.isfinite(s2.x)) and np.all(np.isfinite(s2.fun))):
        _fail(f"stage 2 (laser cone) did not converge: {s2.message}", theta, s1, info, C1=C1)
    if not (0 < s2.x[1] < np.pi / 2 and s2.x[0] > 0):
        hint = (" (beta >= pi/2: the laser points look like a plane; try fit='plane')"
                if s2.x[1] >= np.pi / 2 else "")
        _fail(f"stage 2 ended outside the model (h = {s2.x[0]:.4g} mm, beta = "
              f"{s2.x[1]:.4g} rad){hint}", theta, s1, info, C1=C1)
    # first-order covariance of (h, beta): laser-pixel noise + stage-1 uncertainty
    C13, A, B1, w = cone_covariance(s1.x, C1, s2.x, P, info["planes_w"], info["laser_pix"],
                                    info["laser_plane"], info["sigma"])
    if info["camera"] is not None:      # the camera's part to second order (h bends with it)
        C13 = with_camera_part(s1.x, s2.x, P, info, C13, method=method, max_nfev=max_nfev)
    keep = [0, 1, 2, 3, 4] + list(range(11, 11 + p2))
    cov7 = C13[np.ix_(keep, keep)]
    rms2 = float(np.sqrt(np.mean(s2.fun**2)))
    # identifiability of both stages together, whitened, w.r.t. the 8 paper params + pose
    params = _params(theta[:7], info["fix_phi"])
    T = identifiable_to_paper_jacobian(params)                     # (7, 8)
    J1 = stage1_residuals(s1.x, info["grid_w"], info["grid_pix"], jacobian=True)
    J2 = np.zeros((len(P), 11 + p2))
    J2[:, :11] = B1
    J2[:, 11:] = A
    J2 /= np.sqrt(w)[:, None]          # whitened up to the common factor 1 / sigma
    Jall = np.vstack([np.column_stack([J1, np.zeros((len(J1), p2))]), J2])
    if info["camera"] is not None:           # the camera's information, in the same units
        W = camera_whitener(info["camera"][1])
        Jall = np.vstack([Jall, np.pad(info["sigma"] * W, ((0, 0), (0, 6 + p2)))])
    J8 = np.column_stack([Jall[:, keep[:7]] @ T, Jall[:, 5:11], Jall[:, 13:]])
    report = identifiability_report(J8, PARAM_NAMES + POSE_NAMES + LASER_POSE_NAMES[:p2 - 2])
    var_pix = info["sigma"] ** 2 * w
    chi2 = stage2_chi2(s2.fun, A, var_pix, B1, C1)
    laser = LaserPose.from_array(s2.x[2:], h=s2.x[0]) if p2 > 2 else None
    extras = {"laser_model": "cone", "stage2_covariance_hb": C13[11:, 11:],
              "stage2": {"n_residuals": len(P), "n_unknowns": p2, "nfev": s2.nfev,
                         "rms_mm": rms2, "chi2_per_dof": chi2},
              **_residual_extras(s1, J1, info, s2.fun, A, var_pix, B1, C1)}
    points = None
    if info["room_pixels"] is not None:
        points = triangulate(params, info["room_pixels"], laser=laser)
    return _result(params, theta[:7], cov7, points, {"cone_mm": rms2}, s1, C1, P, info,
                   report, extras, n_res=info["n_res1"] + len(P), n_unk=info["n_fit1"] + p2,
                   message=f"stage 1: {s1.message} | stage 2: {s2.message}", laser=laser)


def _finish_plane(s1, C1, theta, P, info):
    plane, rms2 = fit_plane(P)
    params = _params(theta[:7], info["fix_phi"])
    cov7 = np.full((7, 7), np.nan)
    cov7[:5, :5] = C1[:5, :5]
    report = _stage1_report(s1.x, params, info)
    points = None
    if info["room_pixels"] is not None:
        points = triangulate_plane(params, info["room_pixels"], plane)
    A, g_pix, B1 = plane_residual_jacobians(s1.x, plane, P, info["planes_w"], info["laser_pix"],
                                            info["laser_plane"])
    J1 = stage1_residuals(s1.x, info["grid_w"], info["grid_pix"], jacobian=True)
    extras = {"laser_model": "plane", "laser_plane": plane,
              "stage2": {"n_residuals": len(P), "n_unknowns": 3, "nfev": 0, "rms_mm": rms2},
              **_residual_extras(s1, J1, info, P @ plane[:3] + plane[3], A,
                                 info["sigma"] ** 2 * np.sum(g_pix**2, axis=1), B1, C1)}
    return _result(params, theta, cov7, points, {"plane_mm": rms2}, s1, C1, P, info, report,
                   extras, n_res=info["n_res1"] + len(P), n_unk=info["n_fit1"] + 3,
                   message=f"stage 1: {s1.message} | stage 2: total least squares plane")


def _residual_extras(s1, J1, info, r2, A, var_pix, B1, C1):
    """The residuals a residual plot needs, as plain arrays (see :func:`sequential_residuals`)."""
    z1 = standardized_stage1(s1.fun, J1, info["sigma"])
    return {"stage1_residuals_px": s1.fun.reshape(-1, 2).copy(),
            "stage1_residuals_std": z1.reshape(-1, 2),
            "stage2_residuals_mm": np.asarray(r2, float).copy(),
            "stage2_residuals_std": standardized_stage2(r2, A, var_pix, B1, C1)}


def _stage1_report(p1, params, info):
    """Identifiability of stage 1 w.r.t. the six camera paper parameters and the pose."""
    T = identifiable_to_paper_jacobian(params)[:5, :6]              # camera rows/columns
    J1 = stage1_residuals(p1, info["grid_w"], info["grid_pix"], jacobian=True)
    J8 = np.column_stack([J1[:, :5] @ T, J1[:, 5:]])        # whitening 1/sigma: irrelevant
    if not np.all(np.isfinite(J8)):
        J8 = np.zeros_like(J8)
    return identifiability_report(J8, PARAM_NAMES[:6] + POSE_NAMES)


def _params(theta, phi):
    try:
        return SensorParams.from_identifiable(theta, phi)
    except ValueError as exc:
        raise InvalidValueError(f"fix_phi = {phi} gives no valid sensor: {exc}") from None


def _result(params, theta, cov7, points, rms_extra, s1, C1, P, info, report, extras, *,
            n_res, n_unk, message, converged=True, laser=None):
    cov8 = covariance_8_from_identifiable(theta, info["fix_phi"], cov7[:7, :7], 0.0)
    extras.update({
        "pose": s1.x[5:].copy(), "pose_covariance": C1[5:, 5:].copy(),
        "stage1_covariance": C1, "laser_points": P,
        "calibration_planes": info["planes_w"], "sigma_px_used": info["sigma"],
        "stage1": {"n_residuals": info["n_res1"], "n_unknowns": info["n_fit1"],
                   "nfev": s1.nfev, "rms_px": info["rms1"], "status": s1.status},
        "camera_given": info["camera"] is not None,
    })
    return CalibrationResult(
        method="sequential", params=params, points=points, covariance=cov8,
        covariance_identifiable=cov7, residual_rms={"pixel_px": info["rms1"], **rms_extra},
        sigma_px_estimated=float(info["sigma_est"]), n_residuals=int(n_res),
        n_unknowns=int(n_unk), converged=converged, message=message, nfev=int(info["nfev"]),
        identifiability=report, extras=extras, laser=laser)


def _fail(message, theta, s1, info, *, C1=None):
    """Raise ConvergenceError carrying the best result that can still be formed.

    If the last iterate is not a valid sensor (e.g. ``beta >= pi/2``), the flagged
    result reports the stage-1 camera with ``h``, ``beta`` from ``init`` and keeps the
    raw iterate in ``extras["theta_raw"]``.
    """
    init = info["init"]
    result = None
    for th in (theta[:7], np.concatenate([theta[:5], [init.h, init.beta]])):
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
                         n_unk=info["n_fit1"], message=message, converged=False)
        break
    raise ConvergenceError(message, result)
