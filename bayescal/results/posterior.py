"""The :class:`Posterior`: samples, summaries, reconstruction with uncertainty, I/O.

File format (:meth:`Posterior.save`): one NumPy ``.npz`` archive, written
without pickles, holding every array under its attribute name plus a
``meta_json`` string (format version, settings, the prior as
``{name: [scipy distribution name, args, kwds]}``). Loading rebuilds the same
object; arrays round-trip bit for bit.
"""

from __future__ import annotations

import numpy as np

from ..likelihood.priors import Prior
from ..sensor.parameters import PARAM_NAMES, SensorParams, to_identifiable
from ..sensor.pose import POSE_NAMES, LaserPose
from ..stats.identifiability import PRIOR_DOMINATED_RATIO, RIDGE_NAMES, prior_dominated
from .posterior_file import read_posterior, save_posterior
from .reconstruction import Reconstruction

__all__ = ["Posterior", "Reconstruction", "load_posterior", "PRIOR_DOMINATED_RATIO",
           "LAPLACE_SD_TOLERANCE"]

#: MCMC and Laplace disagree when their sd differ by more than this fraction, or their
#: centres by more than this many MCMC sd
LAPLACE_SD_TOLERANCE = 0.2
LAPLACE_MEAN_TOLERANCE = 0.5
#: parameters the data cannot see one by one (docs/model.md, fact 1)
NON_IDENTIFIABLE = RIDGE_NAMES


class Posterior:
    """Posterior over the 8 sensor parameters and the N laser points.

    Built by :func:`bayescal.sample_posterior`; see ``docs/bayes.md``.

    Attributes
    ----------
    param_samples : ndarray, shape (S, 8)
        Order :data:`~bayescal.PARAM_NAMES`.
    point_samples : ndarray, shape (S, N, 3)
        Laser points in frame C, mm.
    noise_samples : ndarray, shape (S, K)
        The extra globals named by ``noise_names``: the laser pose (misaligned
        model, see :attr:`laser_samples`), inferred ``log sigma_px`` / ``log kappa``,
        ``logit`` of the outlier fraction (K = 0 when none).
    tau, ess : ndarray, shape (7 + K,)
        Integrated autocorrelation time (steps) and honest ensemble effective
        sample size of ``(xi, gamma_u, gamma_v, u0, v0, h, beta)``, then of each
        extra global (see :attr:`diagnostics`).
    converged : bool
        The chain met its convergence rule (``diagnostics.rule``).
    offset_sd : float
        Pixels; the sd of a translation shared by every pixel (an extractor's
        ``LaserPixels.offset_sd``) that ``sample_posterior(..., offset_sd=)`` added to the
        u0 and v0 samples and the Laplace covariances; 0 when none was.

    Examples
    --------
    >>> import bayescal as bc
    >>> ds = bc.simulate_room(range_mm=1000, n_points=60, sigma_px=0.3, approx_error=0.02,
    ...                       approx_model="gaussian", rng=0)
    >>> post = bc.sample_posterior(ds.pixels, ds.approx_points, sigma_px=0.3,
    ...                            sigma_scene=ds.sigma_scene, rng=1, min_ess=200,
    ...                            n_samples=200, progress=False)
    >>> post.param_samples.shape, post.point_samples.shape, post.reconstruct(ds.pixels).mean.shape
    ((200, 8), (200, 60, 3), (60, 3))
    """

    def __init__(self, *, param_samples, point_samples, noise_samples, noise_names, pixels,
                 approx_points, sigma_px, sigma_scene, prior, tau, ess, n_steps, burn,
                 n_walkers, converged, acceptance, imh_acceptance, map_result=None,
                 laplace_cov8=None, laplace_cov7=None, map_params=None, map_points=None,
                 map_point_covariance=None, diagnostics=None, wall_samples=None, plan=None,
                 outlier_prob=None, offset_sd=0.0):
        self.offset_sd = float(offset_sd)
        self.diagnostics = diagnostics      # ChainDiagnostics (tau, ESS, rule) or None
        # (N,) posterior probability that each input row is an outlier (None: no mixture)
        self.outlier_prob = None if outlier_prob is None else np.asarray(outlier_prob, float)
        # floor-plan posteriors only: (S, W, 2) draws of (d_k mm, a_k rad) and the FloorPlan
        self.wall_samples = None if wall_samples is None else np.asarray(wall_samples, float)
        self.plan = plan
        self.param_samples = np.asarray(param_samples, float)
        self.point_samples = np.asarray(point_samples, float)
        self.noise_samples = np.asarray(noise_samples, float).reshape(len(self.param_samples), -1)
        self.noise_names = tuple(noise_names)
        self.pixels = np.asarray(pixels, float)
        self.approx_points = np.asarray(approx_points, float)
        self.sigma_px = sigma_px
        self.sigma_scene = sigma_scene
        self.prior = prior if isinstance(prior, Prior) else Prior(prior)
        self.tau = np.asarray(tau, float)
        self.ess = np.asarray(ess, float)
        self.n_steps, self.burn, self.n_walkers = int(n_steps), int(burn), int(n_walkers)
        self.converged = bool(converged)
        self.acceptance, self.imh_acceptance = float(acceptance), float(imh_acceptance)
        self.map_result = map_result
        if map_result is not None:
            laplace_cov8 = map_result.covariance()
            laplace_cov7 = map_result.covariance_identifiable
            map_params = map_result.params.to_array()
            map_points = map_result.points
            map_point_covariance = map_result.extras["point_covariance"]
        self.laplace_cov8 = np.asarray(laplace_cov8, float)
        self.laplace_cov7 = np.asarray(laplace_cov7, float)
        self.map_params = np.asarray(map_params, float)
        self.map_points = np.asarray(map_points, float)
        self.map_point_covariance = np.asarray(map_point_covariance, float)

    # -- basic views -----------------------------------------------------------
    @property
    def n_samples(self):
        """Number of joint samples S."""
        return len(self.param_samples)

    @property
    def theta_samples(self):
        """Identifiable coordinates of the samples, shape (S, 7)."""
        return to_identifiable(self.param_samples)

    @property
    def model(self):
        """``"misaligned"`` when the laser cone's pose was sampled, else ``"aligned"``."""
        return "misaligned" if POSE_NAMES[0] in self.noise_names else "aligned"

    @property
    def laser_samples(self):
        """Draws of the laser pose ``(tilt_x, tilt_y, offset_x, offset_y)``, shape (S, 4),
        rad and mm (zeros for the aligned model)."""
        if self.model == "aligned":
            return np.zeros((self.n_samples, 4))
        k = self.noise_names.index(POSE_NAMES[0])
        return self.noise_samples[:, k:k + 4]

    @property
    def laser(self):
        """Posterior mean of the laser pose (:class:`~bayescal.LaserPose`, ``h`` set)."""
        return LaserPose.from_array(self.laser_samples.mean(axis=0), h=self.params_mean.h)

    @property
    def geometry_samples(self):
        """The samples in identifiable coordinates, shape (S, 7), then the pose (S, 11)
        with the misaligned model: the order of ``covariance(identifiable=True)``."""
        th = self.theta_samples
        return th if self.model == "aligned" else np.concatenate([th, self.laser_samples], 1)

    @property
    def params_mean(self):
        """Posterior mean of the 8 parameters as a :class:`SensorParams`."""
        return SensorParams.from_array(self.param_samples.mean(axis=0))

    @property
    def point_mean(self):
        """Posterior mean of each laser point, shape (N, 3), mm."""
        return self.point_samples.mean(axis=0)

    @property
    def params(self):
        """The posterior mean of the 8 parameters (:class:`SensorParams`); shared vocabulary."""
        return self.params_mean

    @property
    def points(self):
        """The posterior mean of each laser point, shape (N, 3), mm; shared vocabulary."""
        return self.point_mean

    def point_covariance(self):
        """Posterior covariance of each laser point, shape (N, 3, 3), mm^2."""
        d = self.point_samples - self.point_mean
        return np.einsum("sni,snj->nij", d, d) / (self.n_samples - 1)

    def point_intervals(self, level=0.9):
        """Equal-tailed per-axis credible intervals of the points, shape (N, 3, 2)."""
        lo, hi = (1 - level) / 2, (1 + level) / 2
        return np.moveaxis(np.quantile(self.point_samples, [lo, hi], axis=0), 0, -1)

    def covariance(self, identifiable=False):
        """Posterior covariance: (8, 8) paper parameters, or (7, 7) identifiable ones
        ((11, 11) with the misaligned model: the laser pose after the seven)."""
        x = self.geometry_samples if identifiable else self.param_samples
        return np.cov(x, rowvar=False)

    def laplace_covariance(self, identifiable=False):
        """Laplace covariance at the MAP: (8, 8) paper parameters or (7, 7) identifiable.

        The least-squares approximation beside :meth:`covariance`; see
        :meth:`laplace_comparison` for where the two disagree.
        """
        return (self.laplace_cov7 if identifiable else self.laplace_cov8).copy()

    def intervals(self, level=0.9, identifiable=False):
        """Equal-tailed credible intervals, shape (8, 2) (or (7, 2), (11, 2) misaligned)."""
        x = self.geometry_samples if identifiable else self.param_samples
        lo, hi = (1 - level) / 2, (1 + level) / 2
        return np.quantile(x, [lo, hi], axis=0).T

    # -- summaries ---------------------------------------------------------------
    def _param_tau(self):
        """tau/ESS per paper parameter: that of the identifiable coordinate it follows
        (xi, u0, v0, h, beta directly; alpha through gamma; phi is drawn exactly)."""
        t7, e7 = self.tau[:7], self.ess[:7]
        idx = {"xi": 0, "alpha_u": 1, "alpha_v": 2, "u0": 3, "v0": 4, "h": 5, "beta": 6}
        tau = {n: (float(t7[idx[n]]) if n in idx else float("nan")) for n in PARAM_NAMES}
        ess = {n: (float(e7[idx[n]]) if n in idx else float(self.n_samples)) for n in PARAM_NAMES}
        return tau, ess

    def summary(self):
        """The summary table and diagnostics as text (see :meth:`summary_rows`)."""
        return self.summary_text()

    def summary_rows(self):
        """One row per paper parameter.

        Returns
        -------
        list of dict
            Keys ``name, mean, sd, q05, q50, q95, tau, ess, prior_sd, sd_ratio,
            prior_dominated, identifiable``. ``sd_ratio`` is posterior sd / prior
            sd; ``prior_dominated`` by the rule of
            :func:`~bayescal.stats.identifiability.prior_dominated`: it exceeds
            :data:`PRIOR_DOMINATED_RATIO` (the data did not even halve the prior's
            spread), and always for ``phi``, ``alpha_u``, ``alpha_v``: the data do not see
            them one by one, so whatever their posterior is, the priors decided it.
        """
        x = self.param_samples
        q = np.quantile(x, [0.05, 0.5, 0.95], axis=0)
        psd = self.prior.std()
        tau, ess = self._param_tau()
        rows = []
        for k, name in enumerate(PARAM_NAMES):
            sd = float(x[:, k].std(ddof=1))
            ratio = sd / psd[k] if psd[k] > 0 else float("nan")
            rows.append({"name": name, "mean": float(x[:, k].mean()), "sd": sd,
                         "q05": float(q[0, k]), "q50": float(q[1, k]), "q95": float(q[2, k]),
                         "tau": tau[name], "ess": ess[name], "prior_sd": float(psd[k]),
                         "sd_ratio": float(ratio),
                         "prior_dominated": prior_dominated(name, ratio),
                         "identifiable": name not in NON_IDENTIFIABLE})
        return rows

    def laplace_comparison(self):
        """MCMC against the Laplace approximation at the MAP, per paper parameter.

        Returns
        -------
        list of dict
            ``name, map, laplace_sd, mcmc_mean, mcmc_sd, sd_ratio, disagree``;
            ``disagree`` when the sd differ by more than 20 % or the MAP is more
            than 0.5 MCMC sd from the MCMC mean.
        """
        lsd = np.sqrt(np.diag(self.laplace_cov8))
        x = self.param_samples
        rows = []
        for k, name in enumerate(PARAM_NAMES):
            msd = float(x[:, k].std(ddof=1))
            ratio = msd / lsd[k] if lsd[k] > 0 else float("nan")
            shift = abs(float(x[:, k].mean()) - self.map_params[k]) / msd if msd > 0 else 0.0
            rows.append({"name": name, "map": float(self.map_params[k]),
                         "laplace_sd": float(lsd[k]), "mcmc_mean": float(x[:, k].mean()),
                         "mcmc_sd": msd, "sd_ratio": float(ratio),
                         "disagree": bool(abs(ratio - 1) > LAPLACE_SD_TOLERANCE
                                          or shift > LAPLACE_MEAN_TOLERANCE)})
        return rows

    def summary_text(self):
        """The summary table and diagnostics as plain text."""
        lines = [f"{'param':8s} {'mean':>11s} {'sd':>10s} {'5%':>11s} {'50%':>11s} {'95%':>11s} "
                 f"{'tau':>6s} {'ESS':>7s} {'sd/prior':>8s}  flags"]
        lap = {r["name"]: r for r in self.laplace_comparison()}
        for r in self.summary_rows():
            flags = []
            if r["prior_dominated"]:
                flags.append("PRIOR-DOMINATED")
            if not r["identifiable"]:
                flags.append("not identifiable alone (phi/alpha ridge)")
            if lap[r["name"]]["disagree"]:
                flags.append(f"Laplace differs (sd ratio {lap[r['name']]['sd_ratio']:.2f})")
            lines.append(f"{r['name']:8s} {r['mean']:11.5g} {r['sd']:10.3g} {r['q05']:11.5g} "
                         f"{r['q50']:11.5g} {r['q95']:11.5g} {r['tau']:6.1f} {r['ess']:7.0f} "
                         f"{r['sd_ratio']:8.3f}  {', '.join(flags)}")
        for name, v in self.noise_values().items():
            lines.append(f"{name:8s} {v.mean():11.5g} {v.std(ddof=1):10.3g}   (inferred)")
        if self.model == "misaligned":
            q = np.quantile(self.laser_samples, [0.05, 0.5, 0.95], axis=0)
            for k, name in enumerate(POSE_NAMES):
                v = self.laser_samples[:, k]
                lines.append(f"{name:8s} {v.mean():11.5g} {v.std(ddof=1):10.3g} {q[0, k]:11.5g} "
                             f"{q[1, k]:11.5g} {q[2, k]:11.5g}  laser pose "
                             f"({'rad' if k < 2 else 'mm'})")
        status = "converged" if self.converged else "NOT CONVERGED"
        lines.append(f"chain: {self.n_walkers} walkers x {self.n_steps} steps, burn-in "
                     f"{self.burn}, max tau {np.max(self.tau):.1f}, min ESS {np.min(self.ess):.0f},"
                     f" acceptance {self.acceptance:.2f}: {status} (rule: {self._rule()})")
        lines.append(f"points: {self.point_samples.shape[1]} laser points, {self.n_samples} "
                     f"joint samples (IMH correction acceptance {self.imh_acceptance:.2f})")
        return "\n".join(lines)

    def _rule(self):
        """The convergence rule the chain was judged by (older files: the default rule)."""
        d = self.diagnostics
        return d.rule if d is not None else "kept steps > 50 tau"

    def to_dict(self):
        """Plain-data summary: ``method``, ``params`` (means), ``covariance`` (8x8),
        ``covariance_identifiable`` (7x7), ``rows``, ``converged``, ``n_samples``,
        ``tau``, ``ess``, ``noise`` (mean of each inferred noise level)."""
        from ..io.jsonfile import to_jsonable

        return to_jsonable({
            "method": "bayes", "params": self.params_mean.as_dict(),
            "covariance": self.covariance(),
            "covariance_identifiable": self.covariance(identifiable=True),
            "rows": self.summary_rows(), "converged": self.converged,
            "n_samples": self.n_samples, "tau": self.tau, "ess": self.ess,
            "noise": {n: float(v.mean()) for n, v in self.noise_values().items()},
            "outlier_prob": self.outlier_prob})

    def to_inference_data(self):
        """The samples for ArviZ (needs the ``arviz`` extra): see
        :func:`bayescal.results.export.to_inference_data`."""
        from .export import to_inference_data

        return to_inference_data(self)

    def __repr__(self):
        return (f"<Posterior: {self.n_samples} samples, {self.point_samples.shape[1]} points, "
                f"{'converged' if self.converged else 'NOT converged'}>")

    # -- reconstruction ----------------------------------------------------------
    def reconstruct(self, pixels, *, approx_points=None, sigma_scene=None, level=0.9,
                    max_samples=1000, rng=None, pixel_cov=None, method="auto"):
        """Reconstruct new laser pixels as 3D points with uncertainty.

        Parameters
        ----------
        pixels : array_like, shape (M, 2)
            New laser pixels, px.
        approx_points : array_like, shape (M, 3), optional
            Approximate positions of the new points; with them each point's
            posterior combines the pixel and the scene prior (the same
            per-point model as the calibration; always sampled).
        sigma_scene : float or array_like broadcastable to (M, 3), optional
            Their standard deviation, mm (required with ``approx_points``
            unless the scene noise was inferred).
        level : float, optional
            Credible level of the intervals.
        max_samples, rng : int; numpy.random.Generator, int or None, optional
            Posterior samples used by the sampled path (evenly thinned), and its randomness.
        pixel_cov : array_like, shape (M, 2, 2) or (2, 2), optional
            Pixel noise covariance of the new pixels, px^2 (default: the posterior's
            pixel noise).
        method : {"auto", "linear", "sampled"}, optional
            ``"auto"`` (default): the fast path of :meth:`reconstructor` (first order in the
            identifiable parameters, checked against sampling once), sampling where its
            check failed or off the calibrated ring; ``"sampled"``: every posterior draw
            triangulates the pixel perturbed by its pixel noise (Monte Carlo).

        Returns
        -------
        Reconstruction or LinearReconstruction
            Unpacks as ``mean (M, 3)`` mm, ``covariance (M, 3, 3)`` mm^2; also
            ``intervals (M, 3, 2)`` and ``valid (M,)``; the sampled path keeps its
            draws in ``samples``. Parameter uncertainty and pixel noise are both
            included.
        """
        from .reconstruction import reconstruct_posterior

        return reconstruct_posterior(self, pixels, approx_points=approx_points,
                                     sigma_scene=sigma_scene, level=level,
                                     max_samples=max_samples, rng=rng, pixel_cov=pixel_cov,
                                     method=method)

    def reconstructor(self, *, level=0.9, rng=0):
        """The posterior prepared for fast reconstruction (cached): see
        :class:`~bayescal.results.reconstruction.Reconstructor`."""
        from .reconstruction import Reconstructor

        key = (level, rng if isinstance(rng, (int, type(None))) else id(rng),
               id(getattr(self, "pixel_cov", None)))
        if getattr(self, "_reconstructor", (None, None))[0] != key:
            th = self.geometry_samples
            self._reconstructor = (key, Reconstructor(
                th.mean(axis=0), np.cov(th, rowvar=False),
                float(np.mean(self._sigma_px_samples())), theta_samples=th,
                sigma_samples=self._sigma_px_samples(), probe_pixels=self.pixels,
                level=level, rng=rng, ring_noise=self.ring_noise()))
        return self._reconstructor[1]

    def ring_noise(self):
        """The noise of new pixels without covariances after a fit with them (``pixel_cov``,
        set by :func:`~bayescal.sample_posterior`, not kept in its file):
        :func:`~bayescal.results.pixelnoise.ring_noise_of`."""
        from .pixelnoise import ring_noise_of

        return ring_noise_of(self)

    def noise_values(self):
        """Samples of each inferred global on its natural scale, ``{name: (S,)}``.

        ``sigma_px`` (px) and ``kappa`` are sampled as logarithms, the outlier
        fraction ``outlier_frac`` as a logit; this undoes both.
        """
        out = {}
        for k, n in enumerate(self.noise_names):
            if n in POSE_NAMES:                 # the laser pose: laser_samples
                continue
            x = self.noise_samples[:, k]
            out[n] = 1.0 / (1.0 + np.exp(-x)) if n == "outlier_frac" else np.exp(x)
        return out

    def _sigma_px_samples(self):
        if "sigma_px" in self.noise_names:
            return np.exp(self.noise_samples[:, self.noise_names.index("sigma_px")])
        return np.full(self.n_samples, float(self.sigma_px))

    def _noise_for(self, lik, idx):
        cols = []
        if lik.infer_px:
            cols.append(self.noise_samples[idx, self.noise_names.index("sigma_px")])
        if lik.infer_scene:
            cols.append(self.noise_samples[idx, self.noise_names.index("kappa")])
        return np.stack(cols, axis=1) if cols else np.zeros((len(idx), 0))

    def model_check(self, **kwargs):
        """The posterior predictive check (:func:`bayescal.checks.model.model_check`):
        a ``ModelCheck`` with ``fits``, ``message``, ``p_values``, per-point statistics."""
        from ..checks.model import model_check

        return model_check(self, **kwargs)

    # -- plots -------------------------------------------------------------------
    def corner(self, *, identifiable=False, truth=None, **kwargs):
        """Corner plot of the parameters (see :func:`bayescal.plotting.plot_corner`)."""
        from ..plotting import plot_corner

        return plot_corner(self, identifiable=identifiable, truth=truth, **kwargs)

    # -- I/O ---------------------------------------------------------------------
    def save(self, path, *, overwrite=False):
        """Save to a ``.npz`` file (no pickles; see the module docstring).

        Parameters
        ----------
        path : str or pathlib.Path
        overwrite : bool, optional
            Refuse to replace an existing file unless True.
        """
        return save_posterior(self, path, overwrite=overwrite)


def load_posterior(path):
    """Load a :class:`Posterior` written by :meth:`Posterior.save`.

    Parameters
    ----------
    path : str or pathlib.Path

    Returns
    -------
    Posterior

    Examples
    --------
    >>> import pathlib, tempfile
    >>> import bayescal as bc
    >>> ds = bc.simulate_room(range_mm=1000, n_points=40, sigma_px=0.3, rng=0)
    >>> post = bc.sample_posterior(ds.pixels, ds.approx_points, sigma_px=0.3, sigma_scene=9.0,
    ...                            rng=1, min_ess=200, n_samples=100, progress=False)
    >>> path = post.save(pathlib.Path(tempfile.mkdtemp()) / "posterior.npz")
    >>> bc.load_posterior(path).param_samples.shape
    (100, 8)
    """
    return Posterior(**read_posterior(path))
