"""Figures of a calibration's uncertainty: corner plot, residuals, reconstruction panel.

Every figure is checked by eye in the report of ``bayescal demo``; the rules
they follow: units on every axis; residuals standardized the way that makes a
correct model match its N(0, 1) overlay (see :mod:`bayescal.checks.residuals`); at most a
few dozen ellipses; per-point sds in the radial/tangential frame of the sensor.
"""

from __future__ import annotations

import numpy as np

from ..constants import CHI2_2_95
from ..errors import InvalidValueError
from ..sensor.parameters import IDENTIFIABLE_NAMES, PARAM_NAMES
from ..sensor.pose import POSE_NAMES

__all__ = ["plot_corner", "plot_pixel_residuals", "plot_reconstruction_ellipses",
           "radial_tangential_sd", "UNITS"]

#: unit of each parameter ("" for dimensionless)
UNITS = {"xi": "", "phi": "", "alpha_u": "px", "alpha_v": "px", "u0": "px", "v0": "px",
         "h": "mm", "beta": "rad", "gamma_u": "px", "gamma_v": "px", "tilt_x": "deg",
         "tilt_y": "deg", "offset_x": "mm", "offset_y": "mm"}
#: the laser pose as plotted: tilts from rad to degrees, offsets in mm
POSE_SCALE = np.array([180.0 / np.pi, 180.0 / np.pi, 1.0, 1.0])


def _label(name):
    return f"{name} ({UNITS[name]})" if UNITS.get(name) else name


def _corner_data(posterior, identifiable, truth, laser_truth):
    """Names, samples (S, D) and truths (D,) or None of a corner plot; tilts in degrees."""
    pose = identifiable and getattr(posterior, "model", "aligned") == "misaligned"
    names = list(IDENTIFIABLE_NAMES if identifiable else PARAM_NAMES)
    x = posterior.theta_samples if identifiable else posterior.param_samples
    truths = None
    if truth is not None:
        truths = list(truth.to_identifiable() if identifiable else truth.to_array())
    if pose:
        names += list(POSE_NAMES)
        x = np.concatenate([x, posterior.laser_samples * POSE_SCALE], axis=1)
        if truths is not None or laser_truth is not None:
            truths = truths or [None] * len(IDENTIFIABLE_NAMES)
            truths += ([None] * 4 if laser_truth is None
                       else list(laser_truth.to_array() * POSE_SCALE))
    return names, x, truths


def plot_corner(posterior, *, identifiable=False, truth=None, params=None, prior=True,
                laser_truth=None, **corner_kw):
    """Corner plot of the posterior with units, the prior and labelled quantiles.

    Parameters
    ----------
    posterior : Posterior
    identifiable : bool, optional
        Plot the 7 identifiable coordinates instead of the 8 paper parameters; a
        posterior of the misaligned laser model adds the laser pose's four
        (``tilt_x``, ``tilt_y`` in degrees, ``offset_x``, ``offset_y`` in mm).
    truth : SensorParams, optional
        Drawn in red (e.g. the simulation's true parameters).
    params : sequence of str, optional
        Subset of names to plot (default all).
    prior : bool, optional
        Overlay each parameter's prior density on its histogram (paper
        parameters and the laser pose).
    laser_truth : LaserPose, optional
        The true laser pose, drawn in red with the pose coordinates.
    **corner_kw
        Passed to :func:`corner.corner`.

    Returns
    -------
    matplotlib.figure.Figure
    """
    import warnings

    with warnings.catch_warnings():
        # corner imports ArviZ when it is installed, and ArviZ prints a notice of its
        # coming refactor on the first import of each day: not the user's business
        warnings.filterwarnings("ignore", message=r"\s*ArviZ is undergoing",
                                category=FutureWarning)
        import corner

    names, x, truths = _corner_data(posterior, identifiable, truth, laser_truth)
    idx = list(range(len(names)))
    if params is not None:
        unknown = [p for p in params if p not in names]
        if unknown:
            raise InvalidValueError(f"params {unknown} not among {names}")
        idx = [names.index(p) for p in params]
    names, x = [names[i] for i in idx], x[:, idx]
    truths = None if truths is None else [truths[i] for i in idx]
    kw = {"labels": [_label(n) for n in names], "show_titles": True, "title_fmt": ".4g",
          "quantiles": [0.05, 0.5, 0.95], "truths": truths, "truth_color": "tab:red",
          "hist_kwargs": {"density": True}, "max_n_ticks": 3, "labelpad": 0.1,
          # a pair on a ridge (alpha_u, alpha_v = -alpha_u) fills a handful of the 2-d bins,
          # so two contour levels coincide: corner separates them and would say "Too few
          # points to create valid contours" on the root logger (a stray line on stderr)
          "quiet": True}
    kw.update(corner_kw)
    fig = corner.corner(x, **kw)
    axes = np.asarray(fig.axes).reshape(len(names), len(names))
    for ax in fig.axes:
        for axis in (ax.xaxis, ax.yaxis):
            fmt = axis.get_major_formatter()
            if hasattr(fmt, "set_useOffset"):
                fmt.set_useOffset(False)
    if prior:
        _prior_curves(axes, names, posterior.prior, identifiable)
    note = ("dashed: 5 %, 50 %, 95 % quantiles; dotted grey: prior density"
            + ("; red: truth" if truth is not None or laser_truth is not None else "")
            + "; titles: median and 90 % interval")
    fig.text(0.98, 0.98, note, ha="right", va="top", fontsize="small")
    return fig


def _prior_curves(axes, names, prior, identifiable):
    """Each plotted parameter's prior density (paper parameters; the pose in its units)."""
    pose = getattr(prior, "pose_dists", {}) or {}
    for k, n in enumerate(names):
        if n in POSE_NAMES and n in pose:
            dist, scale = pose[n], POSE_SCALE[POSE_NAMES.index(n)]
        elif not identifiable and n in prior.dists:
            dist, scale = prior.dists[n], 1.0
        else:
            continue
        ax = axes[k, k]
        lo, hi = ax.get_xlim()
        g = np.linspace(lo, hi, 200)
        ax.plot(g, dist.pdf(g / scale) / scale, color="0.5", lw=1, ls=":")


def plot_pixel_residuals(pixels, z, *, raw=None, title=""):
    """Standardized pixel residuals: per point in the image, and their distribution.

    Parameters
    ----------
    pixels : ndarray, shape (N, 2)
        Laser pixels, px (where each point is drawn).
    z : ndarray, shape (N, 2) or (S, N, 2)
        Standardized residuals (dimensionless); with a leading draw axis, the
        residuals under posterior draws (:func:`bayescal.checks.residuals.posterior_residuals`).
    raw : ndarray, shape (N, 2), optional
        Residuals in px, for the RMS in the title (RMS per coordinate).
    title : str, optional

    Returns
    -------
    matplotlib.figure.Figure
    """
    import matplotlib.pyplot as plt

    z = np.asarray(z, float)
    zz = z if z.ndim == 3 else z[None]
    fig, (a1, a2) = plt.subplots(1, 2, figsize=(11, 4.5))
    per_point = np.sqrt(np.nanmean(zz**2, axis=(0, 2)))
    sc = a1.scatter(pixels[:, 0], pixels[:, 1], c=per_point, s=6, cmap="viridis",
                    vmin=0, vmax=max(3.0, float(np.nanmax(per_point))))
    fig.colorbar(sc, ax=a1, label="RMS standardized residual of the point")
    a1.set_aspect("equal")
    a1.invert_yaxis()
    a1.set_xlabel("u (px)")
    a1.set_ylabel("v (px)")
    a1.set_title("per point (about 1 expected)")
    flat = zz[np.isfinite(zz)]
    lim = max(4.0, float(np.nanpercentile(np.abs(flat), 99.9)) if flat.size else 4.0)
    a2.hist(flat, bins=np.linspace(-lim, lim, 61), density=True, color="tab:blue", alpha=0.6,
            label="u and v residuals")
    g = np.linspace(-lim, lim, 300)
    a2.plot(g, np.exp(-g**2 / 2) / np.sqrt(2 * np.pi), "k-", label="N(0, 1)")
    a2.set_xlabel("standardized residual (dimensionless)")
    a2.set_ylabel("density")
    rms_z = float(np.sqrt(np.nanmean(flat**2))) if flat.size else float("nan")
    text = f"RMS standardized {rms_z:.3g}"
    if raw is not None:
        text += f"; RMS per coordinate {float(np.sqrt(np.nanmean(np.square(raw)))):.3g} px"
    a2.set_title(text, fontsize="medium")
    a2.legend(fontsize="small")
    if title:
        fig.suptitle(title)
    fig.tight_layout()
    return fig


def radial_tangential_sd(points, cov):
    """Per-point sd along the horizontal radius, the tangent and z, shape (N, 3), mm.

    Parameters
    ----------
    points : ndarray, shape (N, 3)
        mm, frame C.
    cov : ndarray, shape (N, 3, 3)
        mm^2.
    """
    az = np.arctan2(points[:, 1], points[:, 0])
    c, s = np.cos(az), np.sin(az)
    z0 = np.zeros_like(c)
    R = np.stack([np.stack([c, s, z0], -1), np.stack([-s, c, z0], -1),
                  np.stack([z0, z0, z0 + 1], -1)], axis=1)          # rows: radial, tangential, z
    rc = R @ cov @ np.swapaxes(R, 1, 2)
    return np.sqrt(np.maximum(np.diagonal(rc, axis1=1, axis2=2), 0)), R


def plot_reconstruction_ellipses(points, cov, *, approx_points=None, truth=None, walls=None,
                                 max_ellipses=60):
    """Top view with 95 % ellipses, per-point sd (radial, tangential, z) and error / sd.

    Parameters
    ----------
    points : ndarray, shape (N, 3)
        mm, frame C.
    cov : ndarray, shape (N, 3, 3)
        mm^2.
    approx_points, truth : ndarray, shape (N, 3), optional
    walls : ndarray, shape (W, 2, 2), optional
    max_ellipses : int, optional
        At most this many ellipses are drawn (evenly spaced points).

    Returns
    -------
    matplotlib.figure.Figure
    """
    import matplotlib.pyplot as plt

    from .basic import legend_outside, plot_reconstruction

    ncol = 3 if truth is not None else 2
    fig, axes = plt.subplots(1, ncol, figsize=(5.5 * ncol, 5.8))
    a1, a2 = axes[0], axes[1]
    if approx_points is not None:
        a1.scatter(approx_points[:, 0], approx_points[:, 1], s=2, c="0.75",
                   label="approximate points", zorder=1)
    ok = np.isfinite(points).all(axis=1) & np.isfinite(cov).all(axis=(1, 2))
    plot_reconstruction(points[ok], cov[ok], truth=None if truth is None else truth[ok],
                        walls=walls, n_sigma=np.sqrt(CHI2_2_95), max_ellipses=max_ellipses,
                        ax=a1)
    a1.set_title(f"top view, 95 % ellipses for {min(max_ellipses, int(ok.sum()))} points",
                 fontsize="medium")
    az = np.degrees(np.arctan2(points[:, 1], points[:, 0]))
    sd, R = radial_tangential_sd(points, cov)
    for j, name in enumerate(("radial", "tangential", "z")):
        a2.plot(az[ok], sd[ok, j], ".", ms=3, label=f"sd {name}")
    a2.set_yscale("log")
    a2.set_xlabel("azimuth (deg)")
    a2.set_ylabel("sd (mm)")
    a2.set_title("per-point sd in the sensor's frame", fontsize="medium")
    legend_outside(a2, "below", fontsize="small")
    if truth is not None:
        e = np.einsum("nij,nj->ni", R, truth - points)
        with np.errstate(invalid="ignore", divide="ignore"):
            r = e / sd
        a3 = axes[2]
        for j, name in enumerate(("radial", "tangential", "z")):
            a3.plot(az[ok], r[ok, j], ".", ms=3, label=name)
        for y in (-2, 2):
            a3.axhline(y, color="k", lw=0.8, ls="--")
        inside = float(np.mean(np.abs(r[ok]) < 2)) if ok.any() else float("nan")
        a3.set_xlabel("azimuth (deg)")
        a3.set_ylabel("(truth - estimate) / sd (dimensionless)")
        a3.set_title(f"error / sd: {100 * inside:.0f} % inside +-2 (95 % expected)",
                     fontsize="medium")
        legend_outside(a3, "below", fontsize="small")
    fig.tight_layout()
    return fig
