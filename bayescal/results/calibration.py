"""The result of the least-squares calibrations, in the vocabulary shared with the posterior.

Both least-squares methods (:func:`~bayescal.calibrate_sequential` and
:func:`~bayescal.calibrate_simultaneous`) return a :class:`CalibrationResult`.
It answers to the same names as :class:`~bayescal.Posterior`:

``params``
    the MAP estimate (:class:`~bayescal.SensorParams`);
``points``
    the reconstructed laser points, (N, 3) mm (None without room data);
``covariance(identifiable=False)``
    (8, 8) in the order of :data:`~bayescal.PARAM_NAMES`, or (7, 7) in the
    identifiable coordinates ((11, 11) with the misaligned model: the laser pose
    ``tilt_x, tilt_y, offset_x, offset_y`` after the seven);
``laser``
    the laser cone's pose (:class:`~bayescal.LaserPose`; zero for the aligned model);
``point_covariance()``
    (N, 3, 3) mm^2;
``reconstruct(pixels)``
    new pixels to 3D points with first-order uncertainty (parameter covariance
    plus pixel noise); unpacks as ``mean (M, 3), covariance (M, 3, 3)``;
``summary()``, ``to_dict()``, ``save(path)``, :func:`load_result`.

The data never determine ``phi`` (``docs/model.md``, "Identifiability": ``phi``,
``alpha_u`` and ``alpha_v`` enter the model only through
``gamma_u = alpha_u (xi + phi)`` and ``gamma_v = alpha_v (xi + phi)``). The 8x8
covariance is built from the 7x7 identifiable one plus a variance for ``phi``
that the method chooses (0 when ``phi`` is held fixed, a prior variance
otherwise), see :func:`~bayescal.stats.identifiability.covariance_8_from_identifiable`.

File format (:meth:`CalibrationResult.save`): one JSON object with
``"format": "bayescal-result"`` and ``"version"``; non-finite numbers are
written as the strings ``"nan"``, ``"inf"``, ``"-inf"``.
"""

from __future__ import annotations

import json
import os
import pathlib

import numpy as np

from ..constants import Z90
from ..errors import BayescalError, InvalidValueError, MissingFileError, OutputExistsError
from ..sensor.parameters import IDENTIFIABLE_NAMES, PARAM_NAMES, SensorParams
from ..sensor.pose import POSE_NAMES, LaserPose, as_pose_array
from ..stats.identifiability import (
    PRIOR_DOMINATED_RATIO,
    IdentifiabilityReport,
    covariance_8_from_identifiable,
    identifiability_report,
    identifiable_to_paper_jacobian,
    prior_dominated,
)
from .reconstruction import LinearReconstruction, linear_reconstruction

__all__ = ["IdentifiabilityReport", "identifiability_report", "CalibrationResult",
           "ConvergenceError", "LinearReconstruction", "covariance_8_from_identifiable",
           "identifiable_to_paper_jacobian", "linear_reconstruction", "load_result",
           "RESULT_FORMAT", "RESULT_VERSION"]

RESULT_FORMAT = "bayescal-result"
RESULT_VERSION = 1
#: extras that are plain arrays or numbers and are saved with the result
_SAVED_EXTRAS = ("point_covariance", "sigma_px", "sigma_scene", "pixels", "approx_points",
                 "log_evidence", "pixel_cov", "pose_prior_sd", "offset_sd", "ring_corr_deg",
                 # floor plan: the walls the report draws
                 "walls", "wall_covariance", "wall_index", "azimuths",
                 # sequential: what its residual plot needs (bayescal.sequential_residuals)
                 "stage1_residuals_px", "stage1_residuals_std", "stage2_residuals_mm",
                 "stage2_residuals_std", "sigma_px_used")


class ConvergenceError(BayescalError, RuntimeError):
    """A calibration did not converge; ``.result`` holds the flagged result.

    Attributes
    ----------
    result : CalibrationResult
        The result at the last iterate, with ``converged=False``.
    """

    def __init__(self, message, result=None):
        super().__init__(message)
        self.result = result


class CalibrationResult:
    """Result of a least-squares calibration (sequential or simultaneous).

    Parameters
    ----------
    method : str
        ``"sequential"`` or ``"simultaneous"``.
    params : SensorParams
        Estimated parameters (``phi`` as fixed or as given by its prior).
    points : ndarray, shape (N, 3) or None
        Reconstructed laser points in frame C, mm.
    covariance : ndarray, shape (8, 8)
        Covariance of the paper parameters, order :data:`~bayescal.PARAM_NAMES`;
        NaN rows/columns mark parameters the method did not estimate. Read it
        back with :meth:`covariance`.
    covariance_identifiable : ndarray, shape (7, 7) or (11, 11)
        Covariance of ``(xi, gamma_u, gamma_v, u0, v0, h, beta)``, then of the
        laser pose with the misaligned model.
    residual_rms : dict
        RMS of each kind of residual, e.g. ``{"pixel_px": ..., "cone_mm": ...}``.
    sigma_px_estimated : float or None
        Pixel noise estimated from the pixel residuals,
        ``RMS / sqrt(1 - n_unknowns / n_residuals)`` over the pixel fit.
    n_residuals, n_unknowns : int
        Number of scalar residuals and of unknowns solved for (all stages).
    converged : bool
    message : str
    nfev : int
        Residual evaluations (all stages).
    identifiability : IdentifiabilityReport
    extras : dict, optional
        Method-specific outputs (pose, planes, ``point_covariance`` (N, 3, 3)).
    outlier_prob : ndarray, shape (N,), optional
        Per-point probability of being an outlier (None: not modelled).
    laser : LaserPose, optional
        The fitted pose of the laser cone (misaligned model); None: the aligned
        model, whose :attr:`laser` is the zero pose.

    Examples
    --------
    >>> import bayescal as bc
    >>> ds = bc.simulate_room(range_mm=1000, n_points=80, sigma_px=0.3, approx_error=0.02,
    ...                       approx_model="gaussian", rng=0)
    >>> res = bc.calibrate_simultaneous(ds.pixels, ds.approx_points, sigma_px=0.3,
    ...                                 sigma_scene=ds.sigma_scene)
    >>> res.covariance().shape, res.covariance(identifiable=True).shape, res.points.shape
    ((8, 8), (7, 7), (80, 3))
    >>> mean, cov = res.reconstruct(ds.pixels[:3])
    >>> cov.shape
    (3, 3, 3)
    """

    def __init__(self, *, method, params, points, covariance, covariance_identifiable,
                 residual_rms, sigma_px_estimated, n_residuals, n_unknowns, converged,
                 message, nfev, identifiability, extras=None, outlier_prob=None,
                 laser=None):
        self.method, self.params = str(method), params
        self.points = None if points is None else np.asarray(points, float)
        self._covariance = np.asarray(covariance, float)
        self.covariance_identifiable = np.asarray(covariance_identifiable, float)
        self.residual_rms = dict(residual_rms)
        self.sigma_px_estimated = sigma_px_estimated
        self.n_residuals, self.n_unknowns = int(n_residuals), int(n_unknowns)
        self.converged, self.message, self.nfev = bool(converged), str(message), int(nfev)
        self.identifiability = identifiability
        self.extras = dict(extras or {})
        if outlier_prob is None:
            outlier_prob = self.extras.get("outlier_prob")
        self.outlier_prob = None if outlier_prob is None else np.asarray(outlier_prob, float)
        self._laser = None if laser is None else LaserPose.from_array(as_pose_array(laser),
                                                                      h=self.params.h)

    @property
    def model(self):
        """``"misaligned"`` when the laser cone's pose was fitted, else ``"aligned"``."""
        return "aligned" if self._laser is None else "misaligned"

    @property
    def laser(self):
        """The laser cone's pose (:class:`~bayescal.LaserPose`, apex depth ``h`` set): the
        fitted one with the misaligned model, the zero pose with the aligned one."""
        return LaserPose(h=self.params.h) if self._laser is None else self._laser

    def geometry(self):
        """The fitted geometry in identifiable coordinates, shape (7,) or (11,): theta,
        then the laser pose with the misaligned model (the order of
        ``covariance(identifiable=True)``)."""
        theta = self.params.to_identifiable()
        return theta if self._laser is None else np.concatenate([theta,
                                                                 self._laser.to_array()])

    def __repr__(self):
        n = "no" if self.points is None else len(self.points)
        return (f"<CalibrationResult {self.method}: {n} points, "
                f"{'converged' if self.converged else 'NOT converged'}>")

    # -- the shared vocabulary ------------------------------------------------------
    def covariance(self, identifiable=False):
        """Parameter covariance: (8, 8) paper parameters, or (7, 7) identifiable ones
        ((11, 11) with the misaligned model: the laser pose after the seven)."""
        return (self.covariance_identifiable if identifiable else self._covariance).copy()

    def point_covariance(self):
        """Covariance of each reconstructed laser point, shape (N, 3, 3), mm^2.

        The simultaneous method's joint covariance when it provides one, else
        the first-order propagation of the parameter covariance (no pixel noise).
        """
        cov = self.extras.get("point_covariance")
        if cov is not None:
            return np.asarray(cov, float)
        if self.points is None:
            raise InvalidValueError(f"this {self.method} result has no laser points")
        from ..sensor.camera import project

        return linear_reconstruction(self.params, self.covariance_identifiable,
                                     project(self.params, self.points), 0.0,
                                     laser=self._laser).covariance

    def model_check(self, **kwargs):
        """The predictive check of this fit: does the model fit its data?

        See :func:`bayescal.checks.model.model_check` (keyword arguments pass through).

        Returns
        -------
        ModelCheck
            ``fits``, ``message``, ``p_values`` and per-point statistics.
        """
        from ..checks.model import model_check

        return model_check(self, **kwargs)

    def reconstruct(self, pixels, *, sigma_px=None):
        """Triangulate new laser pixels with first-order uncertainty.

        Parameters
        ----------
        pixels : array_like, shape (M, 2)
            px.
        sigma_px : float, optional
            Pixel noise of the new pixels, px (0: parameter part only). Default:
            the noise the calibration used, else the one it estimated, else 0; after a fit
            with per-pixel covariances, :meth:`ring_noise` (its ``sigma_px`` is a scale).

        Returns
        -------
        LinearReconstruction
            Unpacks as ``mean (M, 3)`` mm, ``covariance (M, 3, 3)`` mm^2.
        """
        from .._validation import as_pixels

        pixels = np.atleast_2d(as_pixels(pixels))
        if sigma_px is None and self.ring_noise() is not None:
            return self.reconstructor()(pixels)
        if sigma_px is None:
            sigma_px = self.extras.get("sigma_px") or self.sigma_px_estimated or 0.0
        if not (np.isfinite(sigma_px) and sigma_px >= 0):
            raise InvalidValueError(f"sigma_px must be a finite number >= 0 px, got {sigma_px!r}")
        rec = linear_reconstruction(self.params, self.covariance_identifiable, pixels,
                                    float(sigma_px), laser=self._laser)
        rec.pixels = pixels
        return rec

    def reconstructor(self, *, sigma_px=None, level=0.9):
        """This fit prepared for fast reconstruction of frames of new pixels (first order
        in the identifiable parameters, per-pixel covariances accepted): a
        :class:`~bayescal.results.reconstruction.Reconstructor`."""
        from .reconstruction import Reconstructor

        ring = None if sigma_px is not None else self.ring_noise()
        if sigma_px is None:
            sigma_px = self.extras.get("sigma_px") or self.sigma_px_estimated or 0.0
        return Reconstructor(self.geometry(), self.covariance_identifiable,
                             float(sigma_px), level=level, ring_noise=ring)

    def ring_noise(self):
        """The noise of new pixels without covariances after a fit with them (its
        ``sigma_px`` a scale on them): :func:`~bayescal.results.pixelnoise.ring_noise_of`."""
        from .pixelnoise import ring_noise_of

        return ring_noise_of(self)

    @property
    def std(self) -> np.ndarray:
        """Standard deviations of the eight parameters, shape (8,) (NaN if not estimated)."""
        with np.errstate(invalid="ignore"):
            return np.sqrt(np.diag(self._covariance))

    @property
    def correlation(self) -> np.ndarray:
        """Correlation matrix, shape (8, 8); NaN rows/columns where the variance is 0 or NaN."""
        sd = self.std
        with np.errstate(divide="ignore", invalid="ignore"):
            sd = np.where(sd > 0, sd, np.nan)
            return self._covariance / np.outer(sd, sd)

    def summary_rows(self, *, prior=None, ratio_limit=PRIOR_DOMINATED_RATIO):
        """One dict per paper parameter: ``name, mean, sd, q05, q95, prior_dominated``.

        ``q05``/``q95`` is the normal 90 % interval. ``prior_dominated`` by the rule of
        :func:`~bayescal.stats.identifiability.prior_dominated`: ``phi``, ``alpha_u``,
        ``alpha_v``; with ``prior`` (``{name: frozen distribution}``; then ``prior_sd``
        and ``sd_ratio`` are added) any whose sd exceeds ``ratio_limit`` x the prior sd;
        without, any in a near-null direction of the data.
        """
        null = getattr(self.identifiability, "null_directions", []) or []
        rows = []
        for name, v, s in zip(PARAM_NAMES, self.params.to_array(), self.std, strict=True):
            row = {"name": name, "mean": float(v), "sd": float(s), "q05": float(v - Z90 * s),
                   "q95": float(v + Z90 * s)}
            ratio = None
            if prior is not None and name in prior:
                psd = float(prior[name].std())
                row["prior_sd"] = psd
                row["sd_ratio"] = ratio = s / psd if psd > 0 else float("nan")
            scaled = None if ratio is None else ratio * PRIOR_DOMINATED_RATIO / ratio_limit
            row["prior_dominated"] = prior_dominated(name, scaled, null)
            rows.append(row)
        return rows

    def summary(self) -> str:
        """Readable table: name, value, standard deviation; residuals; convergence; report."""
        sd = self.std
        lines = [f"{self.method} calibration: "
                 + ("converged" if self.converged else "NOT CONVERGED")
                 + f" ({self.message}; {self.nfev} evaluations)",
                 f"{'parameter':<10} {'value':>14} {'sd':>12}"]
        for name, val, s in zip(PARAM_NAMES, self.params.to_array(), sd, strict=True):
            s_txt = "not estimated" if np.isnan(s) else ("fixed" if s == 0 else f"{s:.4g}")
            lines.append(f"{name:<10} {val:>14.6g} {s_txt:>12}")
        sd7 = np.sqrt(np.maximum(np.diag(self.covariance_identifiable), 0))
        names = IDENTIFIABLE_NAMES + (POSE_NAMES if self._laser is not None else ())
        lines.append("identifiable: " + ", ".join(
            f"{n} = {v:.6g} +- {s:.3g}"
            for n, v, s in zip(names, self.geometry(), sd7, strict=True)))
        lines.append(f"laser model: {self.model}" + ("" if self._laser is None else
                     " (tilt in rad, offset in mm; docs/conventions.md)"))
        lines += self._pose_lines(sd7[7:])
        lines.append("residual RMS: " + ", ".join(f"{k} = {v:.4g}"
                                                    for k, v in self.residual_rms.items()))
        if self.sigma_px_estimated is not None:
            lines.append(f"{self.noise_label()}: {self.noise_text()} "
                         f"({self.n_residuals} residuals, {self.n_unknowns} unknowns)")
        if self.outlier_prob is not None:
            flagged = np.flatnonzero(self.outlier_prob > 0.5)
            lines.append(f"outliers (probability > 0.5): {flagged.size} of "
                         f"{self.outlier_prob.size}"
                         + (f", rows {', '.join(map(str, flagged[:20]))}"
                            + (" ..." if flagged.size > 20 else "") if flagged.size else ""))
        lines.append(str(self.identifiability))
        return "\n".join(lines)

    def noise_label(self):
        """What :attr:`sigma_px_estimated` is: a pixel noise in px, or, when the fit had
        per-point pixel covariances (``extras["pixel_cov"]``), a scale on them."""
        if self.extras.get("pixel_cov") is not None:
            return "estimated pixel covariance scale"
        return "estimated pixel noise"

    def noise_text(self):
        """:attr:`sigma_px_estimated` with its unit (none for a covariance scale)."""
        unit = "" if self.extras.get("pixel_cov") is not None else " px"
        return f"{self.sigma_px_estimated:.4g}{unit}"

    def _pose_lines(self, sd):
        """What the data determine of the laser pose: its sd against its prior's
        (``extras["pose_prior_sd"]``); above half the prior's, the prior decides it."""
        prior_sd = self.extras.get("pose_prior_sd")
        if self._laser is None or prior_sd is None:
            return []
        out = []
        for name, v, s, p in zip(POSE_NAMES, self._laser.to_array(), sd, prior_sd,
                                 strict=True):
            ratio = s / p
            out.append(f"  {name} = {v:.4g} +- {s:.3g} (prior sd {p:.3g}; "
                       + ("PRIOR-DOMINATED: the data barely see it)" if ratio > 0.5 else
                          f"the data narrow it {1 / ratio:.0f}x)"))
        return out

    # -- persistence -------------------------------------------------------------------
    def to_dict(self):
        """Plain-data form (what :meth:`save` writes; arrays as lists).

        Returns
        -------
        dict
            ``format``, ``version``, ``method``, ``params`` (by name),
            ``points``, ``covariance`` (8x8), ``covariance_identifiable`` (7x7),
            ``residual_rms``, ``sigma_px_estimated``, ``n_residuals``,
            ``n_unknowns``, ``converged``, ``message``, ``nfev``,
            ``identifiability``, ``outlier_prob``, ``laser`` (the pose by name, or
            None for the aligned model), ``extras`` (array extras only).
        """
        from ..io.jsonfile import to_jsonable

        ident = self.identifiability
        d = {"format": RESULT_FORMAT, "version": RESULT_VERSION, "method": self.method,
             "params": self.params.as_dict(), "points": self.points,
             "covariance": self._covariance, "covariance_identifiable":
             self.covariance_identifiable, "residual_rms": self.residual_rms,
             "sigma_px_estimated": self.sigma_px_estimated, "n_residuals": self.n_residuals,
             "n_unknowns": self.n_unknowns, "converged": self.converged,
             "message": self.message, "nfev": self.nfev,
             "identifiability": None if ident is None else {
                 "names": list(ident.names), "singular_values": ident.singular_values,
                 "condition_number": ident.condition_number,
                 "null_directions": ident.null_directions, "rtol": ident.rtol},
             "outlier_prob": self.outlier_prob,
             "laser": None if self._laser is None else dict(zip(POSE_NAMES,
                                                                self._laser.to_array(),
                                                                strict=True)),
             "extras": {k: self.extras[k] for k in _SAVED_EXTRAS
                        if self.extras.get(k) is not None}}
        return to_jsonable(d)

    def save(self, path, *, overwrite=False):
        """Write :meth:`to_dict` as JSON (atomically: a temporary file, then renamed).

        Parameters
        ----------
        path : str or pathlib.Path
        overwrite : bool, optional
            Refuse to replace an existing file unless True.

        Returns
        -------
        pathlib.Path
        """
        path = pathlib.Path(path)
        if path.exists() and not overwrite:
            raise OutputExistsError(f"{path} exists; pass overwrite=True to replace it")
        tmp = path.with_name(path.name + ".tmp")
        tmp.write_text(json.dumps(self.to_dict(), indent=1) + "\n", encoding="utf-8")
        os.replace(tmp, path)
        return path

    @classmethod
    def from_dict(cls, d):
        """Rebuild a result from :meth:`to_dict` output."""
        def arr(x):
            return None if x is None else np.array(x, dtype=float)

        ident = d.get("identifiability")
        if ident is not None:
            ident = IdentifiabilityReport(
                names=tuple(ident["names"]), singular_values=arr(ident["singular_values"]),
                condition_number=float(ident["condition_number"]),
                null_directions=ident["null_directions"], rtol=float(ident["rtol"]))
        extras = {k: (float(v) if k in ("sigma_px", "sigma_px_used", "log_evidence") else arr(v))
                  for k, v in (d.get("extras") or {}).items()}
        spe = d.get("sigma_px_estimated")
        return cls(method=d["method"], params=SensorParams(**{n: float(d["params"][n])
                                                             for n in PARAM_NAMES}),
                   points=arr(d.get("points")), covariance=arr(d["covariance"]),
                   covariance_identifiable=arr(d["covariance_identifiable"]),
                   residual_rms={k: float(v) for k, v in d["residual_rms"].items()},
                   sigma_px_estimated=None if spe is None else float(spe),
                   n_residuals=d["n_residuals"], n_unknowns=d["n_unknowns"],
                   converged=d["converged"], message=d["message"], nfev=d["nfev"],
                   identifiability=ident, extras=extras, outlier_prob=arr(d.get("outlier_prob")),
                   laser=None if d.get("laser") is None else
                   np.array([float(d["laser"][n]) for n in POSE_NAMES]))


def load_result(path):
    """Load a :class:`CalibrationResult` written by :meth:`CalibrationResult.save`.

    Raises
    ------
    FileNotFoundError
        No file at ``path``.
    ValueError
        Not a bayescal result file, a newer format version, or damaged
        (the message names the file and what is wrong).

    Examples
    --------
    >>> import pathlib, tempfile
    >>> import bayescal as bc
    >>> ds = bc.simulate_room(range_mm=1000, n_points=60, sigma_px=0.3, approx_error=0.01,
    ...                       approx_model="gaussian", rng=0)
    >>> res = bc.calibrate_simultaneous(ds.pixels, ds.approx_points, sigma_px=0.3,
    ...                                 sigma_scene=ds.sigma_scene)
    >>> path = res.save(pathlib.Path(tempfile.mkdtemp()) / "result.json")
    >>> bool((bc.load_result(path).params.to_array() == res.params.to_array()).all())
    True
    """
    path = pathlib.Path(path)
    if not path.is_file():
        raise MissingFileError(f"no result file at {path}")
    try:
        d = json.loads(path.read_text(encoding="utf-8"))
    except (UnicodeDecodeError, json.JSONDecodeError) as exc:
        raise InvalidValueError(f"{path} is not a bayescal result file (not valid JSON: {exc})") \
            from None
    if not isinstance(d, dict) or d.get("format") != RESULT_FORMAT:
        raise InvalidValueError(f"{path} is not a bayescal result file (no \"format\": "
                                f"\"{RESULT_FORMAT}\")")
    if not isinstance(d.get("version"), int) or d["version"] > RESULT_VERSION:
        raise InvalidValueError(
            f"{path} has format version {d.get('version')!r}; this bayescal reads "
            f"up to {RESULT_VERSION}")
    try:
        return CalibrationResult.from_dict(d)
    except (KeyError, TypeError, ValueError) as exc:
        raise InvalidValueError(f"{path} is a damaged bayescal result file ({type(exc).__name__}: "
                                f"{exc})") from None
