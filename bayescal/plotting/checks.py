"""Plot of the posterior predictive check (:mod:`bayescal.checks.predictive`)."""

from __future__ import annotations

import numpy as np

__all__ = ["plot_predictive_check"]


def plot_predictive_check(check, *, azimuth=None, outlier_prob=None, ax=None):
    """Per-point discrepancy under the posterior, against azimuth (or row).

    Parameters
    ----------
    check : dict
        Output of :func:`bayescal.checks.predictive.posterior_predictive_check`.
    azimuth : array_like, shape (N,), optional
        Azimuth of each point, rad (x axis; default the row index).
    outlier_prob : array_like, shape (N,), optional
        Outlier probabilities; points above 0.5 are drawn in red.
    ax : matplotlib.axes.Axes, optional

    Returns
    -------
    matplotlib.figure.Figure
    """
    import matplotlib.pyplot as plt
    from scipy.stats import chi2

    if ax is None:
        fig, ax = plt.subplots(figsize=(7, 3.5))
    else:
        fig = ax.figure
    t, k = np.asarray(check["point_chi2"]), np.asarray(check["point_rows"])
    x = np.degrees(azimuth) if azimuth is not None else np.arange(len(t))
    flagged = (np.zeros(len(t), bool) if outlier_prob is None
               else np.asarray(outlier_prob) > 0.5)
    ax.scatter(x[~flagged], t[~flagged], s=6, label="points")
    if flagged.any():
        ax.scatter(x[flagged], t[flagged], s=14, color="red", label="outlier_prob > 0.5")
    order = np.argsort(x)
    ax.plot(x[order], chi2.ppf(0.999, k[order]), "k--", lw=0.8, label="model 99.9 %")
    ax.set_yscale("log")
    ax.set_xlabel("azimuth (deg)" if azimuth is not None else "row")
    ax.set_ylabel("sum of squared std. residuals")
    ax.set_title(check["message"], fontsize=8)
    ax.legend(fontsize=7)
    return fig
