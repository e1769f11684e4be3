"""Where a least squares on approximate points starts, and the design values its prior is
centred on when none is given: both read off the data by fits a few bad rows cannot drag.

* :func:`camera_from_points` - the camera's ``gamma_u, gamma_v, u0, v0`` from the pixels
  and the approximate points: eq. (1) is linear in them at a given ``xi``
  (``u = gamma_u x / (xi r - z) + u0``), so two straight lines, each fitted by a
  high-breakdown line fit (:func:`robust_line`: Siegel's repeated median, then least
  trimmed squares). A point typed in metres or centimetres projects where the true one
  does (the model is scale-free), a swapped or mistyped row is one of the trimmed.
* :func:`point_start` - the start of every fit on approximate points: the design's ``xi``
  with that camera and the cone through the approximate points (:func:`cone_from_points`,
  combined with the prior of ``h`` and ``beta``), so that the first residuals measure the
  rows and not how far the design is from this sensor (``docs/robustness.md``, 4c).
* :func:`design_values` - the design values (the prior's centre): the paper's sensor when
  the data agree with it, else the principal point and focal scale the data imply
  (:func:`design_prior`, the library's default prior); the command line's ``--nominal`` and
  image size pass through here too (``bayescal/cli/design.py``).
* :func:`trimmed_weights` and :func:`tail_score` - the concentration steps' trim, shared by
  the per-point start (:func:`bayescal.fit.em._robust_start`) and the floor plan's
  (:mod:`bayescal.fit.plan_robust`).
"""

from __future__ import annotations

import numpy as np

from ..errors import InvalidValueError
from ..sensor.parameters import SensorParams

__all__ = ["ROBUST_STEPS", "ROBUST_KEEP", "TRIMMED_NOISE_LIMIT", "DESIGN_MISMATCH_SDS",
           "PAPER_IMAGE_SIZE", "robust_line", "camera_from_points", "cone_from_points",
           "point_start", "trimmed_weights", "tail_score", "design_values", "design_prior",
           "data_prior", "centre_sd"]

#: concentration steps of the high-breakdown start, and the fraction of points each keeps
ROBUST_STEPS, ROBUST_KEEP = 4, 0.8
#: an inferred level more than this many times its estimate from the best-fitting
#: ``1 - NOISE_TRIM`` of the points is set by a few rows (clean rooms: 1.10-1.43); the
#: floor plan's retry (:mod:`bayescal.fit.plan_robust`) reads it
TRIMMED_NOISE_LIMIT = 1.75
#: the paper's image, width x height in px: its design values are the paper's sensor
PAPER_IMAGE_SIZE = (800, 600)
#: the data disagree with the paper's design when the principal point or the focal scale
#: they imply lies further than this many of the default prior's sds from it. The focal
#: scale is read at the design's xi, so an error of xi shows in it (11 % per 0.05, one
#: alpha sd per xi sd): over 200 sensors drawn from the default prior (150 points,
#: 1000-5000 mm, 1-5 % approximate points, fig9 or gaussian) the largest reading was 6.7
#: sds, the 99 % quantile 4.8, the median 1.8 (``tests/fit/test_start.py`` repeats 20 of
#: them); the 1280x1024 camera of issue 39 (280 px) reads 37
DESIGN_MISMATCH_SDS = 8.0
#: the repeated median's quadratic cost is spent on at most this many points (its breakdown
#: point is that of the sample; the trimmed steps then use every point)
_MEDIAN_POINTS = 200


def robust_line(x, y, *, keep=ROBUST_KEEP, steps=6, with_cov=False):
    """A straight line ``y = a x + b`` a fraction ``1 - keep`` of bad points cannot drag.

    Siegel's repeated median (breakdown point 50 %) on at most 200 evenly spaced points,
    then concentration steps of least trimmed squares (each refits the ``keep`` fraction
    of all points closest to the line).

    Parameters
    ----------
    x, y : ndarray, shape (N,)
        N >= 2 finite values.

    with_cov : bool, optional
        Also return the covariance of ``(a, b)`` (2, 2) of the last least squares, its
        residual variance made consistent for the trim.

    Returns
    -------
    a, b : float
        Slope and intercept.
    """
    x, y = np.asarray(x, float), np.asarray(y, float)
    idx = np.unique(np.linspace(0, len(x) - 1, min(len(x), _MEDIAN_POINTS)).astype(int))
    xs, ys = x[idx], y[idx]
    with np.errstate(divide="ignore", invalid="ignore"):
        s = (ys[None, :] - ys[:, None]) / (xs[None, :] - xs[:, None])
    s[~np.isfinite(s)] = np.nan
    with np.errstate(all="ignore"):
        inner = np.nanmedian(np.where(np.all(np.isnan(s), axis=1)[:, None], 0.0, s), axis=1)
    a = float(np.median(inner))
    b = float(np.median(y - a * x))
    n_keep = max(2, int(keep * len(x)))
    for _ in range(steps):
        k = np.argsort(np.abs(y - a * x - b))[:n_keep]
        A = np.stack([x[k], np.ones(len(k))], axis=1)
        (a, b), *_ = np.linalg.lstsq(A, y[k], rcond=None)
    if not with_cov:
        return float(a), float(b)
    res = y[k] - A @ np.array([a, b])
    s2 = float(res @ res) / max(len(k) - 2, 1) / _trimmed_variance(keep)
    return float(a), float(b), s2 * np.linalg.pinv(A.T @ A)


def _trimmed_variance(keep):
    """Variance of a standard normal kept to its central ``keep`` fraction (the factor
    that makes a trimmed residual variance consistent: 0.438 at 80 %)."""
    from scipy import stats

    c = stats.norm.ppf(0.5 + keep / 2.0)
    return 1.0 - 2.0 * c * stats.norm.pdf(c) / keep


def camera_from_points(pixels, points, xi):
    """``(gamma_u, gamma_v, u0, v0)`` from pixels and approximate points at a given ``xi``.

    Parameters
    ----------
    pixels : ndarray, shape (N, 2)
        px.
    points : ndarray, shape (N, 3)
        Approximate points in frame C, mm (NaN rows are left out).
    xi : float

    Returns
    -------
    ndarray, shape (4,) or None
        None when fewer than 4 points lie where eq. (1) is defined (``xi r - z > 0``) or
        the lines come out degenerate (a zero focal scale).
    """
    p = np.asarray(points, float)
    with np.errstate(invalid="ignore"):
        D = xi * np.linalg.norm(p, axis=1) - p[:, 2]
        ok = np.isfinite(D) & (D > 0) & np.all(np.isfinite(pixels), axis=1)
    if ok.sum() < 4:
        return None
    gu, u0 = robust_line(p[ok, 0] / D[ok], pixels[ok, 0])
    gv, v0 = robust_line(p[ok, 1] / D[ok], pixels[ok, 1])
    out = np.array([gu, gv, u0, v0])
    return out if np.all(np.isfinite(out)) and gu != 0 and gv != 0 else None


def _start_points(lik, theta):
    """The approximate points the camera line fit reads: z from the cone at ``theta``
    (the design's) where the given scene sd of z is infinite (z carries no information)."""
    p = lik.approx.copy()
    mask = getattr(lik, "_scene_mask", None)
    if mask is not None:
        p[~np.all(mask[:, :2], axis=1)] = np.nan          # x or y not measured: left out
        blind = ~mask[:, 2]
        rho = np.hypot(p[blind, 0], p[blind, 1])
        p[blind, 2] = rho / np.tan(theta[6]) - theta[5]
    return p


def point_start(lik, theta0, prior):
    """The start of a fit on approximate points: ``theta0`` (the design's, shape
    (n_geo,)) with the camera's ``gamma_u, gamma_v, u0, v0`` read off the data
    (:func:`camera_from_points` at the design's ``xi``) and the cone's ``h, beta``
    from the approximate points (:func:`cone_from_points`) combined with their prior (a
    wide room's points carry little of ``h``); the design's wherever the data give no
    usable line."""
    theta = np.array(theta0, dtype=float)
    pts = _start_points(lik, theta)
    cam = camera_from_points(lik.pixels, pts, theta[0])
    if cam is not None and np.all(np.sign(cam[:2]) == np.sign(theta[1:3])):
        theta[1:5] = cam
    cone = cone_from_points(pts)
    if cone is not None:
        theta[5:7] = _with_prior(cone, theta[5:7], prior)
    return theta


def cone_from_points(points):
    """The cone through approximate points, ``z = rho cot(beta) - h``: a straight line in
    ``rho`` (:func:`robust_line`). Returns ``((-h, cot beta) estimate (2,), its covariance
    (2, 2))`` or None with fewer than 4 finite points."""
    p = np.asarray(points, float)
    ok = np.all(np.isfinite(p), axis=1)
    if ok.sum() < 4:
        return None
    cot, icpt, cov = robust_line(np.hypot(p[ok, 0], p[ok, 1]), p[ok, 2], with_cov=True)
    return np.array([icpt, cot]), cov[::-1, ::-1]


def _with_prior(cone, design, prior):
    """``(h, beta)``: the cone's line combined with the prior of ``h`` and ``beta`` (normal
    in ``(-h, cot beta)`` to first order), kept inside the domain."""
    (m, C), (h0, b0) = cone, design
    sd_h, sd_b = float(prior.dists["h"].std()), float(prior.dists["beta"].std())
    P0 = np.diag([1.0 / sd_h**2, (np.sin(b0) ** 4) / sd_b**2])
    try:
        Pd = np.linalg.inv(C)
        x = np.linalg.solve(Pd + P0, Pd @ m + P0 @ np.array([-h0, 1.0 / np.tan(b0)]))
    except np.linalg.LinAlgError:
        return np.array([h0, b0])
    h, beta = -x[0], float(np.arctan2(1.0, x[1]))
    return np.array([h, beta]) if h > 0 and 0 < beta < np.pi / 2 else np.array([h0, b0])


def tail_score(m, dof):
    """How unlikely each point's residual is, as a normal score (Wilson-Hilferty's cube
    root of ``m / dof``), shape (N,): monotone in the chi-square tail at any ``m`` (the
    tail probability itself underflows to 0 beyond ``m`` ~ 1500, which made every far
    point tie); NaN and inf rank worst."""
    m = np.asarray(m, dtype=float)
    dof = np.broadcast_to(np.asarray(dof, dtype=float), m.shape)
    v = 2.0 / (9.0 * dof)
    with np.errstate(invalid="ignore", divide="ignore", over="ignore"):
        z = (np.cbrt(np.maximum(m, 0.0) / dof) - (1.0 - v)) / np.sqrt(v)
    return np.where(np.isfinite(z), z, np.inf)


def trimmed_weights(badness, outlier_scale):
    """A concentration step's weights: 1 for the ``ROBUST_KEEP`` fraction of points with
    the smallest ``badness`` (shape (N,)), the outlier component's ``1/c^2`` for the rest
    (the same trim for the per-point EM and the floor plan's, :mod:`.plan_robust`)."""
    n = len(badness)
    u = np.ones(n)
    u[np.argsort(-np.asarray(badness, float), kind="stable")[:n - int(ROBUST_KEEP * n)]] = \
        1.0 / outlier_scale**2
    return u


def centre_sd(image_size):
    """Prior sd of the principal point (px) when it is the image centre, not a design value."""
    return max(10.0, min(image_size) / 40.0)


def _unit_radius(points, xi):
    """``rho / (xi r - z)``: the pixel radius of eq. (1) at unit focal scale."""
    p = np.asarray(points, float)
    r = np.linalg.norm(p, axis=-1)
    with np.errstate(divide="ignore", invalid="ignore"):
        return np.hypot(p[..., 0], p[..., 1]) / (xi * r - p[..., 2])


def _plan_points(plan, base):
    """Points of the nominal cone on the plan's walls at 720 azimuths, (M, 3) mm."""
    from ..scene.floorplan import wall_range
    from ..sensor.laser import cone_point

    t = np.linspace(-np.pi, np.pi, 720, endpoint=False)
    rho = wall_range(t[:, None], plan.distances[None, :], plan.angles[None, :])[0]
    rho = np.nanmin(np.where(rho > 0, rho, np.nan), axis=1)
    ok = np.isfinite(rho)
    xy = rho[ok, None] * np.stack([np.cos(t[ok]), np.sin(t[ok])], axis=-1)
    return cone_point(base, xy)


def _focal_scale(pixels, approx_points, plan, base, image_size):
    """The focal scale (px) the data imply at the nominal ``xi, h, beta`` and centre
    (the median ratio of the pixels' distance from the centre to the unit radius); and
    how it was found."""
    d = None if pixels is None else np.hypot(pixels[:, 0] - base.u0, pixels[:, 1] - base.v0)
    if d is not None and approx_points is not None:
        m = _unit_radius(approx_points, base.xi)
        ok = np.isfinite(m) & (m > 0) & (d > 0)
        if ok.sum() >= 3:
            return float(np.median(d[ok] / m[ok])), "approximate points"
    if d is not None and plan is not None:
        m = _unit_radius(_plan_points(plan, base), base.xi)
        m = m[np.isfinite(m) & (m > 0)]
        if m.size:
            return float(np.median(d) / np.median(m)), "floor plan"
    size = PAPER_IMAGE_SIZE if image_size is None else image_size
    return 55.0 * min(size) / min(PAPER_IMAGE_SIZE), "image size"


def _sized_design(base, given, image_size, pixels, approx_points, plan):
    """The command line's rule for a known image size other than the paper's: the image
    centre, and the focal scale the data imply there."""
    derived = {}
    w, h = image_size
    for name, value in (("u0", w / 2.0), ("v0", h / 2.0)):
        if name not in given:
            base[name], derived[name] = value, "image centre"
    if "alpha_u" not in given or "alpha_v" not in given:
        probe = SensorParams(**{**base, **given})
        scale, how = _focal_scale(pixels, approx_points, plan, probe, image_size)
        scale /= probe.xi + probe.phi          # gamma = alpha (xi + phi)
        for name, sign in (("alpha_u", 1.0), ("alpha_v", -1.0)):
            if name not in given:
                base[name], derived[name] = sign * scale, f"focal scale from the {how}"
    return derived


def _mismatch(paper, u0, v0, alpha_u, alpha_v):
    """How far (in the default prior's sds) the data's camera lies from the paper's."""
    from ..likelihood.priors import DEFAULT_TOLERANCES as tol

    return max(abs(u0 - paper.u0) / tol["u0"], abs(v0 - paper.v0) / tol["v0"],
               abs(alpha_u / paper.alpha_u - 1.0) / tol["alpha_u"],
               abs(alpha_v / paper.alpha_v - 1.0) / tol["alpha_v"])


def _data_design(base, given, pixels, approx_points, plan):
    """The library's rule without an image size: the paper's sensor if the data agree with
    it (:data:`DESIGN_MISMATCH_SDS`), else the principal point and focal scale the
    approximate points imply (:func:`camera_from_points`)."""
    paper = SensorParams(**base)
    probe = SensorParams(**{**base, **given})
    cam = None if approx_points is None or pixels is None else \
        camera_from_points(pixels, approx_points, probe.xi)
    if cam is not None:
        s = probe.xi + probe.phi
        found = dict(zip(("alpha_u", "alpha_v", "u0", "v0"), [cam[0] / s, cam[1] / s,
                                                              cam[2], cam[3]], strict=True))
        if _mismatch(paper, found["u0"], found["v0"], found["alpha_u"], found["alpha_v"]) \
                <= DESIGN_MISMATCH_SDS:
            return {}
        derived = {}
        for name, value in found.items():
            if name not in given:
                base[name], derived[name] = value, "the pixels against the approximate points"
        return derived
    if pixels is None:
        return {}
    scale, how = _focal_scale(pixels, None, plan, probe, None)
    scale /= probe.xi + probe.phi
    centre = np.median(pixels, axis=0)
    far = max(abs(scale / paper.alpha_u - 1.0) / 0.1,
              np.max(np.abs(centre - [paper.u0, paper.v0])) / (10.0 + scale))
    if far > DESIGN_MISMATCH_SDS:
        raise InvalidValueError(
            f"the pixels do not look like the paper's sensor (800x600 image, focal scale 55 px, "
            f"principal point 400, 300): their median lies at ({centre[0]:.0f}, "
            f"{centre[1]:.0f}) px and the {how} imply a focal scale of {scale:.0f} px; give "
            "the design values as prior=bc.default_prior(bc.SensorParams(...)) (the image "
            "centre as u0, v0; the lens' focal scale as alpha_u, -alpha_v), or camera=")
    return {}


def design_values(pixels=None, approx_points=None, *, plan=None, image_size=None, given=None):
    """The design values of a calibration (the prior's centre): ``given`` ones, the rest
    the paper's sensor or derived from the data.

    * ``image_size`` given and the paper's 800x600 (or none of pixels, points, plan):
      the paper's sensor;
    * another ``image_size`` (the command line's rule): ``u0, v0`` the image centre,
      ``alpha_u, alpha_v`` the focal scale that puts the approximate points (or the plan's
      walls) where the pixels are, at the nominal ``xi, h, beta`` (the median ratio of the
      pixels' distance from the centre to eq. (1)'s unit-scale radius); without points or
      plan, the paper's 55 px scaled by ``min(W, H) / 600``;
    * no ``image_size`` (the library's default): the paper's sensor when the principal
      point and focal scale the data imply (:func:`camera_from_points`) lie within
      :data:`DESIGN_MISMATCH_SDS` of the default prior's sds of it; else those.

    ``xi, phi, h, beta`` are the paper's unless given.

    Parameters
    ----------
    pixels : ndarray, shape (N, 2), optional
        px.
    approx_points : ndarray, shape (N, 3), optional
        mm.
    plan : FloorPlan, optional
    image_size : (int, int), optional
        Width, height, px.
    given : dict, optional
        ``{name: value}`` of design values given (the command line's ``--nominal``).

    Returns
    -------
    nominal : SensorParams
    derived : dict
        ``{name: how}`` of the values derived from the data or the image size.

    Raises
    ------
    InvalidValueError
        Values no sensor has; or, with a floor plan, no approximate points and no image
        size, pixels the paper's sensor cannot have made (the message names the prior
        to give).
    """
    given = dict(given or {})
    base = SensorParams.paper().as_dict()
    if image_size is not None and tuple(image_size) != PAPER_IMAGE_SIZE:
        derived = _sized_design(base, given, tuple(image_size), pixels, approx_points, plan)
    elif image_size is None:
        derived = _data_design(base, given, pixels, approx_points, plan)
    else:
        derived = {}
    base.update(given)
    try:
        return SensorParams(**base), derived
    except (TypeError, ValueError) as exc:
        raise InvalidValueError(f"design values: {exc}") from None


def design_prior(pixels, approx_points=None, *, plan=None, image_size=None, given=None):
    """The default prior centred on :func:`design_values`: ``({name: distribution} or
    None, derived)``. ``None`` when the design is the paper's sensor (the default prior as
    it is). A principal point derived from the data, not designed, gets a wider sd: the
    image centre's :func:`centre_sd`, or without an image size the paper's 10 px scaled
    with the focal scale found (51 px at 280 px)."""
    from scipy import stats

    from ..likelihood.priors import default_prior

    nominal, derived = design_values(pixels, approx_points, plan=plan,
                                     image_size=image_size, given=given)
    if not derived and not given:
        return None, derived
    prior = default_prior(nominal)
    scale = abs(nominal.alpha_u) / 55.0
    for name in ("u0", "v0"):
        if name in derived:
            sd = centre_sd(image_size) if image_size is not None else max(10.0, 10.0 * scale)
            prior[name] = stats.norm(getattr(nominal, name), sd)
    return prior, derived



def data_prior(prior, camera, pixels, approx_points):
    """The prior of a fit and the design values it derived (``{name: how}``).

    ``prior`` and ``camera`` as given (:func:`~bayescal.likelihood.priors.as_prior`); with
    neither, the default prior centred on the design values of the data
    (:func:`design_prior`: the paper's sensor unless the data disagree with it). Input the
    later checks refuse (a wrong shape, non-numbers) leaves the default prior to them.
    """
    from ..likelihood.priors import as_prior
    from ..scene.floorplan import FloorPlan

    if prior is not None or camera is not None:
        return as_prior(prior, camera), {}
    plan = approx_points if isinstance(approx_points, FloorPlan) else None
    try:
        pix = np.asarray(pixels, dtype=float)
        apx = None if plan is not None else np.asarray(approx_points, dtype=float)
    except (TypeError, ValueError):
        return as_prior(None), {}
    if pix.ndim != 2 or pix.shape[1] != 2 or (apx is not None and apx.shape != (len(pix), 3)):
        return as_prior(None), {}
    found, derived = design_prior(pix, apx, plan=plan)
    return as_prior(found), derived
