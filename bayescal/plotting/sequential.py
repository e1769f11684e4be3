"""The sequential method's residual figure: both stages, standardized, against N(0, 1)."""

from __future__ import annotations

import numpy as np

__all__ = ["plot_sequential_residuals"]


def _panel(ax, z, raw, unit, title):
    from scipy import stats

    z = np.asarray(z, float).ravel()
    z = z[np.isfinite(z)]
    rms = float(np.sqrt(np.mean(z**2))) if z.size else float("nan")
    lim = max(4.0, float(np.quantile(np.abs(z), 0.99))) if z.size else 4.0
    ax.hist(np.clip(z, -lim, lim), bins=60, range=(-lim, lim), density=True, color="C0",
            alpha=0.7, label=f"{z.size} residuals, RMS {rms:.2f}")
    x = np.linspace(-lim, lim, 200)
    ax.plot(x, stats.norm.pdf(x), "k-", label="N(0, 1): a correct model")
    raw = np.asarray(raw, float).ravel()
    raw_rms = float(np.sqrt(np.nanmean(raw**2))) if raw.size else float("nan")
    ax.set_title(f"{title}\nraw RMS {raw_rms:.3g} {unit}", fontsize=10)
    ax.set_xlabel("standardized residual (residual / its sd)")
    ax.set_ylabel("density")
    ax.legend(fontsize=8)


def plot_sequential_residuals(residuals):
    """Histograms of both stages' standardized residuals with their N(0, 1) reference.

    Parameters
    ----------
    residuals : bayescal.fit.sequential.SequentialResiduals
        From :func:`bayescal.sequential_residuals`: stage 1 pattern-point pixel
        residuals (px and standardized), stage 2 laser-point distances from the
        fitted cone or plane (mm and standardized).

    Returns
    -------
    matplotlib.figure.Figure
        An RMS far above 1 says the model does not explain the residuals (e.g.
        calibration patterns whose 3D positions carry errors the method ignores).
    """
    import matplotlib.pyplot as plt

    fig, (a1, a2) = plt.subplots(1, 2, figsize=(11, 4.2))
    _panel(a1, residuals.grid_z, residuals.grid_px, "px",
           "Stage 1: calibration-pattern pixel residuals")
    _panel(a2, residuals.laser_z, residuals.laser_mm, "mm",
           "Stage 2: laser points' distance from the fitted cone")
    fig.tight_layout()
    return fig
