"""Reconstructed 3D points with uncertainty: the objects ``result.reconstruct`` returns,
and the prepared :class:`Reconstructor` behind the fast path.

Both result objects unpack as ``mean, covariance``: :class:`Reconstruction`
(Monte-Carlo draws under the posterior) and :class:`LinearReconstruction`
(first-order propagation). A :class:`Reconstructor` is made once per calibration
(``result.reconstructor()``) and then reconstructs a frame of pixels in a few
milliseconds where its first-order path holds: the parameter covariance in the seven
identifiable coordinates
propagated through the analytic Jacobian of the triangulation, plus the pixel
noise through its pixel Jacobian. The identifiable coordinates matter: the
``alpha``-``xi``-``phi`` ridge of the paper's parameters is curved, and a
straight line across it (a Jacobian in the eight paper parameters) gives sds
about 2.4 times too wide. At preparation a posterior's reconstructor checks
itself against the sampled path on the calibration's own pixels and falls
back to sampling where the two disagree (``docs/reconstruction.md``).
"""

from __future__ import annotations

import warnings

import numpy as np
from scipy import stats

from ..errors import BayescalWarning, InvalidValueError, MissingDependencyError
from ..sensor.laser import triangulate_geo

__all__ = ["Reconstruction", "LinearReconstruction", "Reconstructor", "reconstruct_frames",
           "linear_reconstruction", "reconstruct_posterior", "propagate", "SD_TOLERANCE",
           "MEAN_TOLERANCE"]

#: the fast path is used when its sds are within this fraction of the sampled path's
#: (90th percentile over the probe pixels and axes)
SD_TOLERANCE = 0.10
#: ... and its means within this many sds of the sampled path's
MEAN_TOLERANCE = 0.10


def _checked_valid(valid):
    """``valid``, after a warning when no ray of several pixels met the cone: pixels of
    another camera or image size than the calibration's (``bayescal reconstruct`` checks)."""
    if np.size(valid) > 1 and not np.any(valid):
        warnings.warn(f"none of the {np.size(valid)} pixels' rays meets the laser cone: are they "
                      "of the calibrated camera (image size)?", BayescalWarning, stacklevel=3)
    return valid


class _PointCloud:
    """What both reconstruction objects can do with their points: files and Open3D."""

    pixels = None            # (M, 2) px, set when made from pixels
    outlier_prob = None      # (M,), where known

    def save(self, path, *, overwrite=False):
        """Write the points as a point cloud: binary PLY (``.ply``) or ``.npz``, with the
        covariances, the pixels and the outlier probabilities where known
        (:mod:`bayescal.io.pointcloud`); atomic, never replacing a file unless
        ``overwrite``. Returns the path."""
        import pathlib

        from ..io.pointcloud import write_npz, write_ply

        suffix = pathlib.Path(path).suffix.lower()
        if suffix not in (".ply", ".npz"):
            raise InvalidValueError(f"path must end in .ply or .npz, got {str(path)!r}")
        write = write_ply if suffix == ".ply" else write_npz
        mean = np.atleast_2d(self.mean)
        cov = np.reshape(self.covariance, (-1, 3, 3))
        pix = None if self.pixels is None else np.atleast_2d(self.pixels)
        return write(path, mean, cov, pixels=pix, outlier_prob=self.outlier_prob,
                     overwrite=overwrite)

    def to_open3d(self):
        """The valid points as an ``open3d.geometry.PointCloud`` (mm; needs open3d)."""
        try:
            import open3d
        except ImportError:
            raise MissingDependencyError("to_open3d needs open3d (pip install open3d)") from None
        pts = np.atleast_2d(self.mean)
        pts = pts[np.all(np.isfinite(pts), axis=-1)]
        return open3d.geometry.PointCloud(open3d.utility.Vector3dVector(pts))


class Reconstruction(_PointCloud):
    """Reconstructed 3D points with uncertainty; unpacks as ``mean, covariance``.

    Attributes
    ----------
    mean : ndarray, shape (M, 3)
        Posterior mean of each point, mm.
    covariance : ndarray, shape (M, 3, 3)
        Posterior covariance (parameter uncertainty plus pixel noise), mm^2.
    samples : ndarray, shape (S, M, 3)
        The Monte-Carlo draws behind them.
    level : float
        Credible level of :attr:`intervals`.
    intervals : ndarray, shape (M, 3, 2)
        Equal-tailed per-axis credible intervals, mm.
    valid : ndarray of bool, shape (M,)
        False where (almost) every draw missed the cone.
    """

    def __init__(self, samples, level):
        self.samples, self.level = samples, level
        ok = np.all(np.isfinite(samples), axis=-1)                   # (S, M)
        n = ok.sum(axis=0)
        self.valid = _checked_valid(n > 0.99 * len(samples))
        s = np.where(ok[..., None], samples, 0.0)
        with np.errstate(invalid="ignore", divide="ignore"):
            self.mean = s.sum(axis=0) / n[:, None]
            d = np.where(ok[..., None], samples - self.mean, 0.0)
            self.covariance = np.einsum("smi,smj->mij", d, d) / n[:, None, None]
        self._intervals = None

    @property
    def intervals(self):
        """Equal-tailed per-axis credible intervals at :attr:`level`, shape (M, 3, 2), mm."""
        if self._intervals is None:
            s = np.where(np.isfinite(self.samples), self.samples, np.nan)
            lo, hi = (1 - self.level) / 2, (1 + self.level) / 2
            self._intervals = np.moveaxis(np.nanquantile(s, [lo, hi], axis=0), 0, -1)
        return self._intervals

    @intervals.setter
    def intervals(self, value):
        self._intervals = value

    def __iter__(self):
        return iter((self.mean, self.covariance))


class LinearReconstruction(_PointCloud):
    """Points triangulated with first-order uncertainty; unpacks as ``mean, covariance``.

    Attributes
    ----------
    mean : ndarray, shape (M, 3)
        mm (NaN where the ray misses the cone).
    covariance : ndarray, shape (M, 3, 3)
        mm^2.
    """

    def __init__(self, mean, covariance, level=0.9):
        self.mean, self.covariance, self.level = mean, covariance, level
        self.valid = _checked_valid(np.all(np.isfinite(mean), axis=-1))
        self.samples = None

    @property
    def intervals(self):
        """Per-axis Gaussian intervals at :attr:`level`, shape (M, 3, 2), mm."""
        sd = np.sqrt(np.diagonal(self.covariance, axis1=-2, axis2=-1))
        z = stats.norm.ppf(0.5 + self.level / 2)
        return np.stack([self.mean - z * sd, self.mean + z * sd], axis=-1)

    def __iter__(self):
        return iter((self.mean, self.covariance))


def propagate(theta, cov_theta, pixels, pixel_cov):
    """Triangulate ``pixels`` at ``theta`` with first-order uncertainty.

    ``cov = J_theta C_theta J_theta^T + J_px Sigma_px J_px^T`` with the analytic
    Jacobians of :func:`~bayescal.sensor.laser.triangulate_theta` (or, with the
    laser pose, :func:`~bayescal.sensor.pose.triangulate_pose_theta`).

    Parameters
    ----------
    theta : ndarray, shape (7,) or (11,)
        Identifiable parameters (then the laser pose, misaligned model).
    cov_theta : ndarray, shape (7, 7) or (11, 11)
        Their covariance (NaN entries count as 0).
    pixels : ndarray, shape (M, 2)
        px.
    pixel_cov : ndarray, shape (M, 2, 2) or (2, 2)
        Pixel noise covariance, px^2.

    Returns
    -------
    mean : ndarray, shape (M, 3)
        mm (NaN where the ray misses the cone).
    covariance : ndarray, shape (M, 3, 3)
        mm^2.
    """
    pts, _, dpix, dth = triangulate_geo(theta, pixels, jacobian=True)
    C = np.nan_to_num(np.asarray(cov_theta, float))
    cov = dth @ C @ np.swapaxes(dth, -1, -2) + dpix @ pixel_cov @ np.swapaxes(dpix, -1, -2)
    return pts, cov


def linear_reconstruction(params, cov_identifiable, pixels, sigma_px, *, laser=None):
    """Triangulate pixels and propagate parameter and pixel uncertainty to first order.

    ``cov = J_theta C_theta J_theta^T + sigma_px^2 J_px J_px^T`` with the
    analytic Jacobians of :func:`~bayescal.sensor.laser.triangulate_theta`.

    Parameters
    ----------
    params : SensorParams
    cov_identifiable : ndarray, shape (7, 7) or (11, 11)
        Covariance of ``(xi, gamma_u, gamma_v, u0, v0, h, beta)`` (then of the
        laser pose, with ``laser``); NaN entries (not estimated) are treated as 0.
    pixels : ndarray, shape (M, 2)
        px.
    sigma_px : float
        Pixel noise of the new pixels, px (0 for the parameter part only).
    laser : LaserPose, optional
        The laser cone's pose (misaligned model); with an (11, 11) covariance.

    Returns
    -------
    LinearReconstruction
        Unpacks as ``mean (M, 3)`` mm and ``covariance (M, 3, 3)`` mm^2.
    """
    geo = params.to_identifiable()
    if np.shape(cov_identifiable) == (11, 11):
        geo = np.concatenate([geo, np.zeros(4) if laser is None else laser.to_array()])
    pts, cov = propagate(geo, cov_identifiable, np.asarray(pixels, float),
                         sigma_px**2 * np.eye(2))
    return LinearReconstruction(pts, cov)


def _noisy_triangulation(theta, sigma_px, pixels, pixel_cov, rng):
    """Each draw ``theta[s]`` (S, 7) or (S, 11) triangulates the pixels (M, 2) perturbed by
    its pixel noise: ``sigma_px[s]`` (S,), or ``pixel_cov`` (M, 2, 2) or (2, 2) px^2;
    (S, M, 3) mm."""
    z = rng.standard_normal((len(theta),) + pixels.shape)
    if pixel_cov is None:
        noisy = pixels + np.asarray(sigma_px)[:, None, None] * z
    else:
        L = np.linalg.cholesky(np.broadcast_to(np.asarray(pixel_cov, float),
                                               pixels.shape[:-1] + (2, 2)))
        noisy = pixels + np.einsum("mij,smj->smi", L, z)
    with np.errstate(invalid="ignore", divide="ignore"):
        return triangulate_geo(theta[:, None, :], noisy)[0]


class Reconstructor:
    """A calibration prepared for fast reconstruction of new laser pixels.

    Made by ``result.reconstructor()``; calling it reconstructs a frame of pixels
    (first-order propagation in the identifiable coordinates, ~ms for 2000 pixels).
    With posterior draws it checks itself once against the sampled path on probe
    pixels (the calibration's own) and uses the sampled path where the check
    fails or a pixel lies off the probed ring.

    Parameters
    ----------
    theta : ndarray, shape (7,) or (11,)
        Identifiable parameters (posterior mean or least-squares solution), then the
        laser pose with the misaligned model.
    cov_theta : ndarray, shape (7, 7) or (11, 11)
        Their covariance.
    sigma_px : float
        Pixel noise of new pixels, px (default of :meth:`__call__`).
    theta_samples : ndarray, shape (S, 7) or (S, 11), optional
        Posterior draws (enable the check and the sampled fallback).
    sigma_samples : ndarray, shape (S,), optional
        Their pixel noise, px (default ``sigma_px``).
    probe_pixels : ndarray, shape (P, 2), optional
        Pixels of the check (up to 200 are used).
    level : float, optional
        Credible level of the intervals.
    rng : numpy.random.Generator, int or None
        For the sampled path's pixel noise.
    ring_noise : RingNoise, optional
        The noise of new pixels without covariances when the calibration weighed its pixels
        by covariances (``sigma_px`` is then a scale on them, not a noise in px); see
        :mod:`bayescal.results.pixelnoise`.

    Attributes
    ----------
    linear_ok : bool
        The fast path passed its check (or there were no draws to check it with).
    agreement : dict or None
        The check: ``sd_ratio`` (median, p90 of ``|ratio - 1|``), ``mean_offset`` (p90,
        in sds), ``n_probe``.
    radius_range : tuple of float
        Ring radii (px, about the principal point) the check covered, with a 2 px margin.

    Examples
    --------
    >>> import bayescal as bc
    >>> ds = bc.simulate_room(range_mm=1000, n_points=80, sigma_px=0.3, approx_error=0.02,
    ...                       approx_model="gaussian", rng=0)
    >>> res = bc.calibrate_simultaneous(ds.pixels, ds.approx_points, sigma_px=0.3,
    ...                                 sigma_scene=ds.sigma_scene)
    >>> rc = res.reconstructor()                 # prepared once
    >>> rec = rc(ds.pixels)                      # then every frame
    >>> rec.mean.shape, rec.covariance.shape
    ((80, 3), (80, 3, 3))
    """

    def __init__(self, theta, cov_theta, sigma_px, *, theta_samples=None, sigma_samples=None,
                 probe_pixels=None, level=0.9, rng=None, ring_noise=None):
        from .._validation import resolve_rng

        self.ring_noise = ring_noise
        self.theta = np.asarray(theta, float)
        self.cov_theta = np.asarray(cov_theta, float)
        self.sigma_px = float(sigma_px)
        self.level = level
        self._rng = resolve_rng(rng)
        self.theta_samples = None if theta_samples is None else np.asarray(theta_samples)
        self.sigma_samples = (None if self.theta_samples is None else
                              np.broadcast_to(self.sigma_px if sigma_samples is None
                                              else np.asarray(sigma_samples, float),
                                              len(self.theta_samples)))
        self.linear_ok, self.agreement = True, None
        self.radius_range = (0.0, np.inf)
        if self.theta_samples is not None and probe_pixels is not None:
            self._check(np.asarray(probe_pixels, float))

    def _radius(self, pixels):
        return np.hypot(pixels[..., 0] - self.theta[3], pixels[..., 1] - self.theta[4])

    def _check(self, probe):
        idx = np.linspace(0, len(probe) - 1, min(200, len(probe))).round().astype(int)
        probe = probe[idx]
        lin_mean, lin_cov = propagate(self.theta, self.cov_theta, probe, self._noise(probe))
        smp = self.sampled(probe, max_samples=2000)     # Monte-Carlo error ~2 % of an sd
        sd_l = np.sqrt(np.diagonal(lin_cov, axis1=-2, axis2=-1))
        sd_s = np.sqrt(np.diagonal(smp.covariance, axis1=-2, axis2=-1))
        ok = smp.valid & np.all(np.isfinite(lin_mean), axis=-1)
        dev = np.abs(sd_l[ok] / sd_s[ok] - 1.0)
        off = np.abs(lin_mean[ok] - smp.mean[ok]) / sd_s[ok]
        self.agreement = {"sd_ratio_median": float(np.median(sd_l[ok] / sd_s[ok])),
                          "sd_deviation_p90": float(np.quantile(dev, 0.9)),
                          "mean_offset_p90": float(np.quantile(off, 0.9)),
                          "n_probe": int(ok.sum())}
        self.linear_ok = bool(self.agreement["sd_deviation_p90"] <= SD_TOLERANCE
                              and self.agreement["mean_offset_p90"] <= MEAN_TOLERANCE)
        r = self._radius(probe[ok])
        self.radius_range = (float(r.min()) - 2.0, float(r.max()) + 2.0)

    def _noise(self, pixels):
        """The pixel noise of pixels given without covariances: (2, 2) or (M, 2, 2) px^2."""
        if self.ring_noise is not None:
            return self.ring_noise.covariance(pixels)
        return self.sigma_px**2 * np.eye(2)

    def sampled(self, pixels, *, pixel_cov=None, max_samples=400):
        """The sampled path: each posterior draw triangulates the pixels perturbed by
        its pixel noise (or ``pixel_cov``); a :class:`Reconstruction`."""
        if pixel_cov is None and self.ring_noise is not None:
            pixel_cov = self.ring_noise.covariance(pixels)
        if self.theta_samples is None:
            raise InvalidValueError("the sampled path needs posterior draws (a Posterior's "
                                    "reconstructor)")
        n = len(self.theta_samples)
        idx = np.linspace(0, n - 1, min(int(max_samples), n)).round().astype(int)
        samples = _noisy_triangulation(self.theta_samples[idx], self.sigma_samples[idx],
                                       pixels, pixel_cov, self._rng)
        out = Reconstruction(samples, self.level)
        out.pixels = pixels
        return out

    def __call__(self, pixels, *, pixel_cov=None, method="auto"):
        """Reconstruct pixels: mean (M, 3) mm and covariance (M, 3, 3) mm^2.

        Parameters
        ----------
        pixels : array_like, shape (M, 2)
            px.
        pixel_cov : array_like, shape (M, 2, 2) or (2, 2), optional
            Pixel noise covariance of each pixel, px^2 (e.g. from the laser
            extractor); default ``ring_noise``'s, else ``sigma_px^2 I``.
        method : {"auto", "linear", "sampled"}
            ``"auto"``: the fast path where it passed its check and the pixel lies
            on the probed ring, the sampled path elsewhere.

        Returns
        -------
        LinearReconstruction or Reconstruction
            Unpacks as ``mean, covariance``.
        """
        from .._validation import as_pixels

        if method not in ("auto", "linear", "sampled"):
            raise InvalidValueError(f"method must be 'auto', 'linear' or 'sampled', got {method!r}")
        pixels = np.atleast_2d(as_pixels(pixels))
        cov_px = self._noise(pixels) if pixel_cov is None else np.asarray(pixel_cov, float)
        if cov_px.shape not in ((2, 2), (len(pixels), 2, 2)):
            raise InvalidValueError(f"pixel_cov must have shape (2, 2) or (M, 2, 2) = "
                                    f"{(len(pixels), 2, 2)}, got {cov_px.shape}")
        if method == "sampled" or (method == "auto" and not self.linear_ok
                                   and self.theta_samples is not None):
            return self.sampled(pixels, pixel_cov=pixel_cov)
        mean, cov = propagate(self.theta, self.cov_theta, pixels, cov_px)
        out = LinearReconstruction(mean, cov, self.level)
        r = self._radius(pixels)
        off = (r < self.radius_range[0]) | (r > self.radius_range[1])
        if method == "auto" and self.theta_samples is not None and off.any():
            own = pixel_cov is not None or self.ring_noise is not None
            smp = self.sampled(pixels[off], pixel_cov=None if not own else
                               cov_px if cov_px.ndim == 2 else cov_px[off])
            out.mean[off], out.covariance[off] = smp.mean, smp.covariance
        out.method = "linear" if not off.any() or self.theta_samples is None else "mixed"
        out.pixels = pixels
        return out


def reconstruct_posterior(post, pixels, *, approx_points=None, sigma_scene=None, level=0.9,
                          max_samples=1000, rng=None, pixel_cov=None, method="auto"):
    """:meth:`Posterior.reconstruct <bayescal.Posterior.reconstruct>` (see there)."""
    from .._validation import as_pixels, resolve_rng

    if method not in ("auto", "linear", "sampled"):
        raise InvalidValueError(f"method must be 'auto', 'linear' or 'sampled', got {method!r}")
    if not 0 < level < 1:
        raise InvalidValueError(f"level must lie in (0, 1), got {level!r}")
    pixels = as_pixels(pixels)
    single = pixels.ndim == 1
    pixels = np.atleast_2d(pixels)
    if approx_points is None and method != "sampled":
        rec = post.reconstructor(level=level)(pixels, pixel_cov=pixel_cov, method=method)
    else:
        rec = _sampled_posterior(post, pixels, approx_points, sigma_scene, level,
                                 max_samples, resolve_rng(rng), pixel_cov)
        rec.pixels = pixels
    if single:
        rec.mean, rec.covariance = rec.mean[0], rec.covariance[0]
        rec.valid, rec.pixels = rec.valid[0], pixels[0]
        if rec.samples is not None:
            rec.intervals = rec.intervals[0]
    return rec


def _sampled_posterior(post, pixels, approx_points, sigma_scene, level, max_samples, rng,
                       pixel_cov):
    """The Monte-Carlo path (and the only one with approximate points for new pixels)."""
    from .._validation import as_points
    from ..likelihood.misaligned import MisalignedLikelihood
    from ..likelihood.points import LaserLikelihood
    from ..likelihood.points import draw_points as _draw_points
    from ..sensor.laser import cone_points_geo

    idx = np.linspace(0, post.n_samples - 1, min(int(max_samples), post.n_samples))
    idx = idx.round().astype(int)
    theta = post.geometry_samples[idx]             # (S, 7), or (S, 11) with the pose
    sig = post._sigma_px_samples()[idx]
    if approx_points is None:
        return Reconstruction(_noisy_triangulation(theta, sig, pixels, pixel_cov, rng), level)
    approx = np.atleast_2d(as_points(approx_points, "approx_points"))
    if approx.shape != (len(pixels), 3):
        raise InvalidValueError(f"approx_points must have shape (M, 3) = {(len(pixels), 3)}, "
                                f"got {approx.shape}")
    if sigma_scene is None and "kappa" not in post.noise_names:
        raise InvalidValueError("sigma_scene is required with approx_points (the scene noise "
                                "was given, not inferred, at calibration)")
    kw = {"prior": post.prior} if post.model == "misaligned" else {}
    lik = (MisalignedLikelihood if kw else LaserLikelihood)(
        pixels, approx, sigma_px=None if "sigma_px" in post.noise_names else post.sigma_px,
        sigma_scene=sigma_scene, **kw)
    ref = {n: float(np.exp(np.mean(post.noise_samples[:, k])))
           for k, n in enumerate(post.noise_names) if n in ("sigma_px", "kappa")}
    lik.set_reference_noise(**ref)
    psi = np.concatenate([theta, post._noise_for(lik, idx)], axis=1)
    q0 = lik.initial_q(theta.mean(axis=0))
    q, _ = _draw_points(lik, psi, q0, rng, n_mh=2, n_iter=6)
    return Reconstruction(cone_points_geo(theta[:, None, :], q), level)


def reconstruct_frames(result, frames, **kwargs):
    """Reconstruct a sequence of frames with one prepared calibration.

    Parameters
    ----------
    result : CalibrationResult or Posterior
    frames : iterable
        Each frame its pixels, array_like (N, 2) px, or a pair ``(pixels, pixel_cov)``
        with ``pixel_cov`` (N, 2, 2) px^2 (e.g. ``(lp.pixels, lp.covariance)`` of an
        extractor), or an object with ``pixels`` and ``covariance`` attributes.
    **kwargs
        Passed to ``result.reconstructor()`` (e.g. ``sigma_px`` for least squares).

    Yields
    ------
    LinearReconstruction or Reconstruction
        One per frame; unpacks as ``mean (N, 3)`` mm, ``covariance (N, 3, 3)`` mm^2;
        ``.save("frame.ply")`` writes its point cloud.

    Examples
    --------
    >>> import bayescal as bc
    >>> ds = bc.simulate_room(range_mm=1000, n_points=80, sigma_px=0.3, approx_error=0.02,
    ...                       approx_model="gaussian", rng=0)
    >>> res = bc.calibrate_simultaneous(ds.pixels, ds.approx_points, sigma_px=0.3,
    ...                                 sigma_scene=ds.sigma_scene)
    >>> [rec.mean.shape for rec in bc.reconstruct_frames(res, [ds.pixels[:5], ds.pixels[5:9]])]
    [(5, 3), (4, 3)]
    """
    recon = result.reconstructor(**kwargs)
    for frame in frames:
        if hasattr(frame, "pixels") and hasattr(frame, "covariance"):
            yield recon(frame.pixels, pixel_cov=frame.covariance)
        elif isinstance(frame, tuple) and len(frame) == 2:
            yield recon(frame[0], pixel_cov=frame[1])
        else:
            yield recon(frame)
