"""The result of a camera calibration from board views (least squares or posterior).

:func:`~bayescal.calibrate_camera` and :func:`~bayescal.sample_camera_posterior` both
return a :class:`CameraResult`; it answers:

``intrinsics``
    ``{xi, gamma_u, gamma_v, u0, v0}`` (the estimate: least squares, or the posterior mean);
``covariance()``
    (5, 5) in that order, the poses integrated out; ``covariance(noise=True)`` appends
    the noise levels (``sigma_<view>`` per view, then ``tau``, px);
``poses``
    (K, 6): one pose per view, rotation vector (rad) and translation (mm), board -> C;
``residuals``
    list of (M_k, 2) px, one per view (observed minus predicted);
``project(points)``, ``reconstruct(pixels)``
    eq. (1) both ways, with first-order covariances from ``covariance()``;
``model_check()``, ``unidentified()``, ``summary()``, ``save(path)`` / :func:`load_camera`.

A posterior adds ``samples`` (n, 5 + noise), ``diagnostics`` and ``converged``.
File format: one JSON object with ``"format": "bayescal-camera"``.
"""

from __future__ import annotations

import json
import os
import pathlib

import numpy as np
from scipy import stats

from ..errors import InvalidValueError, OutputExistsError
from ..sensor.board import CAMERA_NAMES
from ..sensor.camera import backproject_theta, project_theta
from ..stats.chains import ChainDiagnostics

__all__ = ["CameraResult", "load_camera", "CAMERA_FORMAT"]

CAMERA_FORMAT = "bayescal-camera"
_ARRAYS = ("poses", "cov", "pose_cov", "sigma", "noise_cov", "samples")


class CameraResult:
    """Calibrated camera intrinsics with their uncertainty and the per-view fit.

    Parameters
    ----------
    intrinsics : array_like, shape (5,)
        ``xi, gamma_u, gamma_v, u0, v0``.
    cov : array_like, shape (5, 5)
    poses : array_like, shape (K, 6)
    residuals : list of ndarray (M_k, 2)
    view_names : list of str
    noise : str
        The noise model (``"plain"``, ``"per-view"``, ``"view-systematic"``).
    sigma : array_like, shape (K,)
        Per-view corner noise, px.
    tau : float
        Amplitude of the per-view systematic field, px (0 without it).
    image_size : tuple of int
    method : str
        ``"least-squares"`` or ``"posterior"``.
    pose_cov : array_like, shape (K, 6, 6), optional
    noise_cov : array_like, shape (n_noise, n_noise), optional
    samples : array_like, shape (n, 5 + n_noise), optional
    diagnostics : ChainDiagnostics, optional
    info : dict, optional
        Anything else (iterations, degree of the systematic field, ...).
    """

    def __init__(self, intrinsics, cov, poses, residuals, view_names, *, noise, sigma, tau,
                 image_size, method="least-squares", pose_cov=None, noise_cov=None,
                 samples=None, diagnostics=None, info=None):
        self.k = np.asarray(intrinsics, float)
        self.cov = np.asarray(cov, float)
        self.poses = np.asarray(poses, float)
        self.residuals = [np.asarray(r, float) for r in residuals]
        self.view_names = list(view_names)
        self.noise, self.sigma, self.tau = str(noise), np.asarray(sigma, float), float(tau)
        self.image_size = None if image_size is None else tuple(int(s) for s in image_size)
        self.method = method
        self.pose_cov = None if pose_cov is None else np.asarray(pose_cov, float)
        self.noise_cov = None if noise_cov is None else np.asarray(noise_cov, float)
        self.samples = None if samples is None else np.asarray(samples, float)
        self.diagnostics = diagnostics
        self.info = dict(info or {})

    # ------------------------------------------------------------ vocabulary
    @property
    def intrinsics(self):
        """``{xi, gamma_u, gamma_v, u0, v0}`` as floats."""
        return {n: float(v) for n, v in zip(CAMERA_NAMES, self.k, strict=True)}

    @property
    def noise_names(self):
        """Names of the noise levels appended by ``covariance(noise=True)``."""
        names = [f"sigma_{n}" for n in self.view_names]
        if self.noise == "plain":
            names = ["sigma"]
        return names + (["tau"] if self.noise == "view-systematic" else [])

    @property
    def converged(self):
        """True for least squares; the sampler's verdict for a posterior."""
        return True if self.diagnostics is None else bool(self.diagnostics.converged)

    def covariance(self, *, noise=False):
        """Covariance of the intrinsics (5, 5), poses integrated out; with ``noise=True``
        the noise levels after them (block-diagonal for least squares)."""
        if not noise:
            return self.cov.copy()
        if self.samples is not None:
            return np.cov(self.samples, rowvar=False)
        n = len(self.noise_names)
        out = np.zeros((5 + n, 5 + n))
        out[:5, :5] = self.cov
        out[5:, 5:] = np.nan if self.noise_cov is None else self.noise_cov
        return out

    def std(self):
        """Standard deviations of the intrinsics as a dict (NaN where the variance is not
        positive)."""
        with np.errstate(invalid="ignore"):
            sd = np.sqrt(np.diag(self.cov))
        return {n: float(s) for n, s in zip(CAMERA_NAMES, sd, strict=True)}

    def unidentified(self):
        """Names of the intrinsics the views do not determine: sd at least the value (or
        not finite).

        None of the five is near zero for a real camera (``xi`` about 1, ``gamma`` hundreds
        of px, the principal point inside the image), so an interval that reaches zero says
        the views leave it open; the real views of ``docs/camera.md`` give sd / value at most
        0.009, a board option smaller than the board (every other row taken for the next,
        ``docs/camera_images.md``) 1.3-86 for all but ``v0``.
        """
        sd = self.std()
        return [n for n, v in self.intrinsics.items() if not sd[n] < abs(v)]

    @property
    def theta(self):
        """``(xi, gamma_u, gamma_v, u0, v0, 0, 0)``: the camera part of the sensor's theta."""
        return np.concatenate([self.k, [0.0, 0.0]])

    def project(self, points, *, return_cov=False):
        """Pixels of points (or directions) in frame C by eq. (1).

        Parameters
        ----------
        points : array_like, shape (..., 3)
            mm (a direction's scale does not matter).
        return_cov : bool
            Also return the (..., 2, 2) px^2 covariance from the intrinsics.
        """
        uv, _, _, dth = project_theta(self.theta, np.asarray(points, float), jacobian=True)
        if not return_cov:
            return uv
        J = dth[..., :5]
        return uv, np.einsum("...ia,ab,...jb->...ij", J, self.cov, J)

    def reconstruct(self, pixels, *, pixel_cov=None):
        """Unit rays in frame C of pixels, with their (..., 3, 3) covariance.

        Parameters
        ----------
        pixels : array_like, shape (..., 2)
        pixel_cov : array_like, shape (..., 2, 2), optional
            Pixel noise to add (px^2); default none (intrinsics only).

        Returns
        -------
        rays : ndarray, shape (..., 3)
        cov : ndarray, shape (..., 3, 3)
        """
        rays, _, dpix, dth = backproject_theta(self.theta, np.asarray(pixels, float),
                                               jacobian=True)
        J = dth[..., :5]
        cov = np.einsum("...ia,ab,...jb->...ij", J, self.cov, J)
        if pixel_cov is not None:
            cov = cov + np.einsum("...ia,...ab,...jb->...ij", dpix, pixel_cov, dpix)
        return rays, cov

    # ------------------------------------------------------------- checks
    def model_check(self):
        """Per-view residual statistics against the noise model.

        Returns
        -------
        dict
            ``views``: one dict per view (``name``, ``n``, ``rms`` px per coordinate,
            ``sigma`` px, ``lag1`` correlation of neighbouring residuals along the
            board's rows); ``bartlett_p`` (equal per-view variances); ``rms`` overall;
            ``suspect``: names of views whose rms exceeds 3x the median (worth a look).
        """
        rows = []
        for name, r, s in zip(self.view_names, self.residuals, self.sigma, strict=True):
            lag = np.corrcoef(r[:-1].ravel(), r[1:].ravel())[0, 1] if len(r) > 2 else np.nan
            rows.append({"name": name, "n": len(r), "rms": float(np.sqrt(np.mean(r * r))),
                         "sigma": float(s), "lag1": float(lag)})
        rms = np.array([v["rms"] for v in rows])
        p = stats.bartlett(*[r.ravel() for r in self.residuals])[1] if len(rows) > 1 else np.nan
        allr = np.concatenate([r.ravel() for r in self.residuals])
        return {"views": rows, "bartlett_p": float(p), "rms": float(np.sqrt(np.mean(allr ** 2))),
                "suspect": [v["name"] for v in rows if v["rms"] > 3 * np.median(rms)]}

    def summary(self):
        """Text: estimates with standard errors, the noise, every view's rms."""
        sd, bad = self.std(), self.unidentified()
        lines = [f"camera calibration ({self.method}, noise model {self.noise!r}, "
                 f"{len(self.view_names)} views, all used)"]
        lines += [f"  {n:8s} {v:12.5f} +- {sd[n]:.5f}"
                  + ("  NOT IDENTIFIED (sd >= |value|)" if n in bad else "")
                  for n, v in self.intrinsics.items()]
        if bad:
            lines.append(f"  NOT IDENTIFIED: the views do not determine {', '.join(bad)}; check "
                         "the board size and square, and use views spread over the image")
        if self.noise == "view-systematic":
            lines.append(f"  tau (per-view systematic field, rms) {self.tau:.3f} px")
        mc = self.model_check()
        lines.append(f"  rms {mc['rms']:.3f} px per coordinate; equal view variances p = "
                     f"{mc['bartlett_p']:.2g}")
        for v in mc["views"]:
            flag = "  SUSPECT" if v["name"] in mc["suspect"] else ""
            lines.append(f"    {v['name']}: {v['n']} corners, rms {v['rms']:.3f} px, "
                         f"sigma {v['sigma']:.3f} px{flag}")
        if self.diagnostics is not None:
            lines.append("  " + self.diagnostics.summary())
        return "\n".join(lines)

    # ------------------------------------------------------------- files
    def to_dict(self):
        """JSON-able dict (the inverse of :meth:`from_dict`)."""
        d = {"format": CAMERA_FORMAT, "version": 1, "intrinsics": self.intrinsics,
             "view_names": self.view_names, "noise": self.noise, "tau": self.tau,
             "image_size": self.image_size, "method": self.method,
             "residuals": [r.tolist() for r in self.residuals], "info": self.info,
             "diagnostics": None if self.diagnostics is None else self.diagnostics.to_dict()}
        for name in _ARRAYS:
            v = getattr(self, name)
            d[name] = None if v is None else np.asarray(v).tolist()
        return d

    @classmethod
    def from_dict(cls, d):
        """A result from :meth:`to_dict`'s output."""
        if d.get("format") != CAMERA_FORMAT:
            raise InvalidValueError(f"not a camera result (format {d.get('format')!r}, expected "
                                    f"{CAMERA_FORMAT!r})")
        diag = d.get("diagnostics")
        return cls([d["intrinsics"][n] for n in CAMERA_NAMES], d["cov"], d["poses"],
                   d["residuals"], d["view_names"], noise=d["noise"], sigma=d["sigma"],
                   tau=d["tau"], image_size=d["image_size"], method=d["method"],
                   pose_cov=d.get("pose_cov"), noise_cov=d.get("noise_cov"),
                   samples=d.get("samples"), info=d.get("info"),
                   diagnostics=None if diag is None else ChainDiagnostics.from_dict(diag))

    def save(self, path, *, overwrite=False):
        """Write the result as JSON to ``path`` (atomically: a temporary file, then renamed);
        refuses to overwrite unless asked."""
        path = pathlib.Path(path)
        if path.exists() and not overwrite:
            raise OutputExistsError(f"{path} exists; pass overwrite=True to replace it")
        tmp = path.with_name(path.name + ".tmp")
        tmp.write_text(json.dumps(self.to_dict()), encoding="utf-8")
        os.replace(tmp, path)
        return path

    def __repr__(self):
        k = ", ".join(f"{n}={v:.4g}" for n, v in self.intrinsics.items())
        return f"CameraResult({self.method}, {k}, {len(self.view_names)} views)"


def load_camera(path):
    """Read a :class:`CameraResult` written by :meth:`CameraResult.save`.

    Raises
    ------
    ValueError
        If the file is not text, not JSON or not a camera result (named).
    """
    path = pathlib.Path(path)
    try:
        d = json.loads(path.read_text(encoding="utf-8"))
    except UnicodeDecodeError:
        raise InvalidValueError(f"{path}: not a text file; expected a camera result (JSON "
                                "written by CameraResult.save or bayescal calibrate-camera)"
                                ) from None
    except (OSError, json.JSONDecodeError) as exc:
        raise InvalidValueError(f"{path}: cannot read a camera result ({exc})") from None
    try:
        return CameraResult.from_dict(d)
    except (KeyError, TypeError, ValueError) as exc:
        raise InvalidValueError(f"{path}: not a valid camera result ({exc})") from None
