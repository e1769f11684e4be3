"""Simultaneous calibration (paper section III): camera and laser cone in one least squares.

Unknowns: the seven identifiable parameters ``theta`` and, by default, every
laser point through its scene coordinates ``q_i = (x_i, y_i)`` (the point is
``(x_i, y_i, rho_i / tan(beta) - h)`` on the cone), i.e. ``7 + 2N`` unknowns
against ``2N`` pixel rows, up to ``3N`` scene rows and 8 weak prior rows.
This is the paper's complete model (eqs. 1 and 6) with the cone written as a
hard constraint: the point's azimuth is the pixel's (eqs. 4-5) through eq. (1).

The solver is Levenberg-Marquardt with the points eliminated by a Schur
complement (each point couples only to ``theta``), so an iteration costs O(N)
and the 580-point room solves in a fraction of a second. The weak priors
(design value +- tolerance, :func:`bayescal.likelihood.priors.default_prior`) are what keep
the large room from collapsing to ``h -> 0``: without them a joint least squares
at 5000 mm ended at ``h = 1 mm``, ``alpha_u = 1`` (fact 3, ``docs/model.md``,
"Measured facts"); ``phi`` is fixed at its prior mean since the data cannot see
it (only ``alpha (xi + phi)`` is seen: fact 1, same section).
"""

from __future__ import annotations

import functools
import warnings

import numpy as np

from .._validation import check_positive
from ..checks.fit import (
    NoiseCollapseError,
    NoiseUndeterminedWarning,
    check_noise_levels,
    pixel_noise_ceiling,
)
from ..checks.inputs import check_calibration_input
from ..checks.misfit import ModelMisfitWarning, flag_misfit
from ..errors import InvalidTypeError, InvalidValueError, UnsupportedError
from ..likelihood.misaligned import MisalignedLikelihood
from ..likelihood.outliers import OUTLIER_PRIOR, OUTLIER_SCALE
from ..likelihood.points import LaserLikelihood
from ..results.calibration import (
    CalibrationResult,
    ConvergenceError,
    covariance_8_from_identifiable,
    identifiability_report,
)
from ..scene.floorplan import FloorPlan
from ..sensor.parameters import (
    IDENTIFIABLE_NAMES,
    PARAM_NAMES,
    SensorParams,
    from_identifiable,
    identifiable_jacobian,
    offset_variance,
    to_identifiable,
)
from ..sensor.pose import POSE_NAMES
from .em import _fit_map, _make_result
from .floorplan import calibrate_plan
from .schur import MapSolution, solve_map
from .start import data_prior, point_start

__all__ = ["calibrate_simultaneous", "solve_map", "MapSolution", "MODELS", "check_model",
           "point_likelihood"]

#: the laser models: the paper's aligned cone, or a cone tilted and offset (4 more unknowns)
MODELS = ("aligned", "misaligned")


def check_model(model):
    """``model`` as one of :data:`MODELS`, else a ValueError naming it."""
    if not isinstance(model, str) or model not in MODELS:
        raise InvalidValueError(f"model must be one of {MODELS}, got {model!r}")
    return model


def _resolve_init(init, prior):
    if init is None:
        return prior.mean()
    if isinstance(init, SensorParams):
        return init
    raise InvalidTypeError(f"init must be a SensorParams or None, got {type(init).__name__}")


_REQUIRED = object()      # sigma_scene: required with approximate points, absent with a plan


def _offset_on_failure(fit):
    """``fit`` whose ConvergenceError carries a result with the offset too, as a converged
    result does (the command line saves that result)."""
    @functools.wraps(fit)
    def wrapped(*args, **kwargs):
        try:
            return fit(*args, **kwargs)
        except ConvergenceError as exc:
            if exc.result is not None:
                _with_offset(exc.result, float(kwargs.get("offset_sd", 0.0)))
            raise
    return wrapped


@_offset_on_failure
def calibrate_simultaneous(pixels, approx_points, *, sigma_px, sigma_scene=_REQUIRED, prior=None,
                           init=None, estimate_points=True, absolute_sigma=True,
                           max_iter=200, raise_on_failure=True, outliers=True,
                           outlier_scale=OUTLIER_SCALE, outlier_prior=OUTLIER_PRIOR,
                           pixel_cov=None, model="aligned", camera=None, offset_sd=0.0,
                           ring_corr_deg=0.0):
    """Calibrate camera and laser cone together from laser pixels and approximate points.

    Parameters
    ----------
    pixels : array_like, shape (N, 2)
        Laser pixels ``(u, v)``, px.
    approx_points : array_like, shape (N, 3), or FloorPlan
        Approximate 3D positions of the laser points in frame C, mm; or a
        rough floor plan (:class:`~bayescal.FloorPlan`): the points are then on
        its uncertain walls (``docs/floorplan.md``), ``sigma_scene`` is not
        given and ``extras`` adds ``walls`` (W, 2) and ``wall_covariance``.
    sigma_px : float or None
        Pixel noise standard deviation, px; ``None`` estimates it (alternating
        with the fit, from the pixel residuals).
    sigma_scene : float, array_like broadcastable to (N, 3), or None
        Standard deviation of the approximate points' error, mm (``inf`` on
        an axis = no information, e.g. z derived from the nominal cone). A
        relative error is passed as e.g. ``0.05 * abs(approx_points)``.
        ``None`` estimates ``kappa`` in ``sigma_scene_i = kappa * rho_i``.
    pixel_cov : array_like, shape (N, 2, 2), optional
        Per-point pixel covariances, px^2 (``bc.extract_laser(...).covariance``). The
        noise of pixel i is then ``sigma_px^2 pixel_cov_i``: pass ``sigma_px=1.0`` to
        take the covariances as they are. With a FloorPlan ``sigma_px=None`` infers that
        scale; with approximate points it is refused (on an extractor's covariances,
        whose along-ring sd is overstated on purpose, one scale cannot fit both
        directions: ``docs/images.md``). Needs ``estimate_points=True``.
    offset_sd : float, optional
        Standard deviation (px, each axis) of an error shared by every pixel, a translation
        of them all (``bc.extract_laser(...).offset_sd``). A common translation is exactly
        a shift of ``(u0, v0)``, so the fit is unchanged and ``offset_sd**2`` is added to
        the variances of u0 and v0 (a nuisance translation with a Gaussian prior,
        marginalised). Exact when the prior on u0 and v0 is wide (the default); with an
        informative one (``camera=``) only the data's share should grow, so the
        intervals are then conservative (:func:`~bayescal.sensor.parameters.offset_variance`).
    ring_corr_deg : float, optional
        With a FloorPlan only: if > 0, the points' pixel errors along the ring's normal are
        taken as correlated between neighbours, ``exp(-lag / ring_corr_deg)`` in azimuth,
        each with the sd the fit gives it (an extractor's errors: 1 degree measured,
        :data:`~bayescal.fit.floorplan.RING_CORR_DEG`; ``docs/floorplan.md``, "Errors
        correlated along the ring"). The fit is unchanged; its covariance gains the
        first-order effect (:func:`~bayescal.fit.floorplan.ring_corr_cov`). Default 0.
    prior : dict, optional
        ``{name: scipy.stats frozen distribution}`` for any of the eight
        parameters; the rest keep :func:`~bayescal.likelihood.priors.default_prior`.
    init : SensorParams, optional
        Starting values (default: the prior means).
    estimate_points : bool, optional
        Estimate the N points with the parameters (default, the paper's
        ``3N + 8`` unknowns written as ``2N + 7`` identifiable ones). With
        False the points are taken as exact (``approx_points``), only their
        pixel rows enter, and the cone is fitted through them.
    absolute_sigma : bool, optional
        If True (default) the covariance uses the given noise levels as they
        are; if False it is scaled by the reduced chi-square (the classical
        least-squares convention).
    max_iter : int, optional
    raise_on_failure : bool, optional
        Raise :class:`~bayescal.ConvergenceError` (carrying the flagged result)
        when the solver does not converge; otherwise return it with
        ``converged=False``.
    outliers : bool, optional
        Per-point outlier mixture (default True): each point is an inlier with
        probability ``1 - w`` or an outlier whose residuals have
        ``outlier_scale`` times the noise; solved by EM (weighted Schur LM).
        ``result.outlier_prob`` (N,) gives each point's outlier probability.
        On clean data it changes nothing that matters (``docs/robustness.md``).
        Ignored with ``estimate_points=False``. With a FloorPlan the same mixture
        (``docs/robustness.md``, "Floor plans").
    outlier_scale : float, optional
        Noise inflation of the outlier component (default 100).
    outlier_prior : tuple of float, optional
        Beta(a, b) prior of the outlier fraction ``w`` (default (1, 19)).
    model : {"aligned", "misaligned"}, optional
        The laser cone: the paper's, coaxial with the camera (default), or tilted
        by ``(tilt_x, tilt_y)`` and offset by ``(offset_x, offset_y)``, four more
        unknowns with priors by name in ``prior`` (default zero +- 2 degrees and
        5 mm, :func:`~bayescal.likelihood.priors.default_pose_prior`;
        ``docs/model.md``, "A misaligned laser cone"). With approximate points
        and ``estimate_points=True``, or with a FloorPlan.
    camera : object, optional
        A camera calibrated beforehand (``bc.calibrate_camera(views)``, a camera
        posterior, or ``(mean, cov)`` of ``xi, gamma_u, gamma_v, u0, v0``): its
        intrinsics and their covariance become a correlated normal prior on those
        five in place of their default priors (``prior`` then sets ``phi``, ``h``,
        ``beta`` and the pose only; ``docs/calibration.md``, "From a camera
        calibration to the laser"). The start is the camera's intrinsics.

    Returns
    -------
    CalibrationResult
        ``params``; ``points`` (N, 3) the jointly estimated laser points
        (``estimate_points=True``) or the triangulated pixels; ``covariance``
        (8, 8) with ``phi``'s prior variance on the phi/alpha ridge;
        ``covariance(identifiable=True)`` (7, 7), or (11, 11) with the misaligned
        model (the pose after the seven); ``laser`` (:class:`~bayescal.LaserPose`);
        ``extras["point_covariance"]`` (N, 3, 3); ``extras["map"]``.

    Examples
    --------
    >>> import bayescal as bc
    >>> ds = bc.simulate_room(range_mm=1000, sigma_px=0.5, approx_error=0.01,
    ...                       approx_model="gaussian", rng=0)
    >>> res = bc.calibrate_simultaneous(ds.pixels, ds.approx_points, sigma_px=0.5,
    ...                                 sigma_scene=ds.sigma_scene)
    >>> res.converged
    True
    """
    model = check_model(model)
    offset_sd = check_positive(offset_sd, "offset_sd", allow_zero=True)
    ring_corr_deg = _ring_corr(ring_corr_deg, approx_points)
    from_data = init is None and camera is None
    prior, design = data_prior(prior, camera, pixels, approx_points)
    if model == "misaligned" and not estimate_points:
        raise UnsupportedError("model='misaligned' needs the points estimated "
                                  "(estimate_points=True, or a FloorPlan)")
    if pixel_cov is not None and not estimate_points:
        raise InvalidTypeError("pixel_cov needs estimate_points=True")
    if pixel_cov is not None and sigma_px is None and not isinstance(approx_points, FloorPlan):
        raise InvalidValueError(
            "with pixel_cov and approximate points, sigma_px is the scale on the "
            "covariances and must be given (1.0: as they are); it is inferred "
            "only with a FloorPlan (docs/images.md)")
    if isinstance(approx_points, FloorPlan):
        if sigma_scene is not _REQUIRED or not estimate_points:
            raise InvalidTypeError("with a FloorPlan, sigma_scene and estimate_points do not apply "
                                   "(the plan carries its own sds); leave them out")
        return _with_offset(calibrate_plan(
            pixels, approx_points, sigma_px=sigma_px, prior=prior, init=init,
            absolute_sigma=absolute_sigma, max_iter=max_iter, raise_on_failure=raise_on_failure,
            outliers=outliers, outlier_scale=outlier_scale, outlier_prior=outlier_prior,
            pixel_cov=pixel_cov, model=model, ring_corr_deg=ring_corr_deg), offset_sd)
    if sigma_scene is _REQUIRED:
        raise InvalidTypeError("calibrate_simultaneous() missing required keyword argument "
                               "'sigma_scene' (needed with approximate points)")
    init = _resolve_init(init, prior)
    if isinstance(max_iter, bool) or not isinstance(max_iter, (int, np.integer)) or max_iter < 1:
        raise InvalidValueError(f"max_iter must be a positive integer, got {max_iter!r}")
    pixels, approx_points = check_calibration_input(pixels, approx_points,
                                                    sigma_scene=sigma_scene,
                                                    center=(init.u0, init.v0))
    lik = point_likelihood(model, pixels, approx_points, prior, sigma_px=sigma_px,
                           sigma_scene=sigma_scene, outliers=outliers and estimate_points,
                           outlier_scale=outlier_scale, outlier_prior=outlier_prior,
                           pixel_cov=pixel_cov)
    if not estimate_points:
        return _with_offset(calibrate_fixed_points(lik, prior, init, absolute_sigma,
                                                   raise_on_failure), offset_sd)
    theta0 = to_identifiable(init.to_array())
    if lik.n_geo > 7:                                   # the pose starts at its prior mean
        theta0 = np.concatenate([theta0, [float(prior.pose_dists[n].mean())
                                          for n in POSE_NAMES]])
    if from_data:                 # the camera read off the data, not the design's
        theta0 = point_start(lik, theta0, prior)
    fit = _fit_map(lik, prior, theta0, lik.initial_q(theta0), max_iter)
    result, problem = _checked(lik, prior, fit, absolute_sigma)
    if isinstance(problem, NoiseCollapseError):
        result, problem = _at_ceiling(problem, lik, fit, prior, theta0, functools.partial(
            point_likelihood, model, pixels, approx_points, prior, sigma_scene=sigma_scene,
            outliers=outliers, outlier_scale=outlier_scale, outlier_prior=outlier_prior),
            sigma_px, pixel_cov, max_iter, absolute_sigma)
    result.extras["design"] = design
    if problem is not None and raise_on_failure:
        raise ConvergenceError(f"simultaneous calibration did not converge: {result.message}",
                               result=result)
    return _with_offset(result, offset_sd)


def _at_ceiling(problem, lik, fit, prior, theta0, make_lik, sigma_px, pixel_cov, max_iter,
                absolute_sigma):
    """``problem``, a collapsed noise level, raised; unless the inferred pixel noise collapsed
    to its lower bound and the data bound it from above
    (:func:`~bayescal.checks.fit.pixel_noise_ceiling`): then a
    :class:`~bayescal.checks.fit.NoiseUndeterminedWarning` and (result, problem) of the fit
    from the same start with ``sigma_px`` given at that bound (``make_lik(sigma_px=)``)."""
    ceiling = None
    if (problem.name == "sigma_px" and sigma_px is None and pixel_cov is None
            and problem.value <= 1.0):
        ceiling = pixel_noise_ceiling(lik, np.concatenate([fit.sol.theta, fit.extra(lik)]),
                                      fit.sol.q)
    if ceiling is None:
        raise problem
    warnings.warn(
        f"the pixel noise sigma_px is not determined by these data: their likelihood is flat "
        f"from its lower bound up to about {ceiling:.3g} px and falls beyond (the inferred "
        f"level collapsed to {problem.value:.3g} px); fitted with sigma_px = {ceiling:.3g} px, "
        "the largest the data allow, so the sds are on the safe side. Give sigma_px if you "
        "know it", NoiseUndeterminedWarning, stacklevel=4)
    lik = make_lik(sigma_px=ceiling)
    fit = _fit_map(lik, prior, theta0, lik.initial_q(theta0), max_iter)
    result, problem = _checked(lik, prior, fit, absolute_sigma)
    if isinstance(problem, NoiseCollapseError):
        raise problem
    result.extras["sigma_px_ceiling"] = ceiling
    return result, problem


def _ring_corr(deg, approx_points):
    """``deg`` checked: non-negative, and positive only with a FloorPlan."""
    deg = check_positive(deg, "ring_corr_deg", allow_zero=True)
    if deg > 0 and not isinstance(approx_points, FloorPlan):
        raise InvalidValueError(f"ring_corr_deg={deg!r} needs a FloorPlan (the points' azimuths); "
                                "with approximate points leave it 0")
    return deg


def _with_offset(result, offset_sd):
    """``result`` with ``offset_sd**2`` (px^2) added to the variances of u0 and v0: a
    translation shared by every pixel is a shift of the principal point, the rest of the fit
    unchanged (``extras["offset_sd"]`` records it)."""
    result.extras["offset_sd"] = offset_sd
    if offset_sd > 0:
        for names, attr in ((IDENTIFIABLE_NAMES, "covariance_identifiable"),
                            (PARAM_NAMES, "_covariance")):
            cov = getattr(result, attr)
            setattr(result, attr, cov + offset_variance(names, offset_sd, size=len(cov)))
    return result


def _checked(lik, prior, fit, absolute_sigma):
    """The result of a fit and what is wrong with it (None, a NoiseCollapseError, or
    ``"not converged"``: the result says why, a failed model check included)."""
    if lik.n_noise:
        try:
            check_noise_levels(lik, np.concatenate([fit.sol.theta, fit.extra(lik)]),
                               fit.sol.q)
        except NoiseCollapseError as exc:
            return None, exc
    result = _make_result(lik, prior, fit, absolute_sigma, False)
    result.extras["robust_start"] = fit.robust
    if result.converged:
        misfit = flag_misfit(result)
        if misfit:
            warnings.warn(misfit, ModelMisfitWarning, stacklevel=4)
    return result, None if result.converged else "not converged"


def point_likelihood(model, pixels, approx_points, prior, **kw):
    """The per-point likelihood of ``model`` (the misaligned one reads the pose prior); the
    keywords are :class:`~bayescal.likelihood.points.LaserLikelihood`'s."""
    if model == "misaligned":
        return MisalignedLikelihood(pixels, approx_points, prior=prior, **kw)
    return LaserLikelihood(pixels, approx_points, **kw)


def calibrate_fixed_points(lik, prior, init, absolute_sigma, raise_on_failure):
    """Points taken as exact: pixel rows of eq. (1) and the cone through the points."""
    from scipy.optimize import least_squares

    from ..sensor.camera import project_theta
    from ..sensor.laser import triangulate_theta

    if lik.infer_px or lik.infer_scene:
        raise InvalidValueError(
            "estimate_points=False needs sigma_px and sigma_scene given (not None)")
    sig = lik.sigma_px
    P = lik.approx
    phi = float(prior.dists["phi"].mean())
    # scene sd along the cone normal, per point
    rho = np.hypot(P[:, 0], P[:, 1])

    def fun(t):
        uv, _ = project_theta(t, P)
        b = t[6]
        nrm = np.stack([np.cos(b) * P[:, 0] / rho, np.cos(b) * P[:, 1] / rho,
                        np.full(len(P), -np.sin(b))], -1)
        with np.errstate(divide="ignore"):
            var_n = np.sum(nrm**2 / lik.w_scene**2, axis=1)       # inf where an axis is blind
        s_n = 1.0 / np.sqrt(var_n)
        dist = rho * np.cos(b) - (P[:, 2] + t[5]) * np.sin(b)
        rp = prior.residuals(from_identifiable(t, phi))
        return np.concatenate([((uv - lik.pixels) / sig).ravel(), dist * s_n, rp])

    t0 = to_identifiable(init.to_array())
    opt = least_squares(fun, t0, x_scale="jac", method="lm", xtol=1e-12, ftol=1e-12)
    J = opt.jac
    data_rows = opt.fun[:-8]                          # the last 8 rows are the priors
    n_res, n_unk = len(data_rows), 7
    red = float(data_rows @ data_rows) / max(n_res - n_unk, 1)
    cov7 = np.linalg.inv(J.T @ J) * (1.0 if absolute_sigma else red)
    cov8 = covariance_8_from_identifiable(opt.x, phi, cov7, float(prior.dists["phi"].var()))
    params = SensorParams.from_array(from_identifiable(opt.x, phi))
    pts, _ = triangulate_theta(opt.x, lik.pixels)
    uv, _ = project_theta(opt.x, P)
    dtheta_da = np.linalg.inv(identifiable_jacobian(opt.x, phi))[:7]
    result = CalibrationResult(
        method="simultaneous", params=params, points=pts, covariance=cov8,
        covariance_identifiable=cov7,
        residual_rms={"pixel_px": float(np.sqrt(np.mean((uv - lik.pixels) ** 2)))},
        sigma_px_estimated=float(sig * np.sqrt(red)), n_residuals=n_res, n_unknowns=n_unk,
        converged=bool(opt.success), message=str(opt.message), nfev=int(opt.nfev),
        identifiability=identifiability_report(J @ dtheta_da, PARAM_NAMES),
        extras={"theta": opt.x, "reduced_chi2": red})
    if not result.converged and raise_on_failure:
        raise ConvergenceError(f"simultaneous calibration did not converge: {opt.message}",
                               result=result)
    return result
