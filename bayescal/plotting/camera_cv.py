"""The figure of a camera calibration's cross-validation between halves of the views.

:func:`plot_halves_chi2` draws :func:`~bayescal.validation.camera_cv.halves_chi2`'s output:
for each split of the views into two halves, the chi-square per direction of the two
calibrations' disagreement (2 expected when their covariances are honest) and the mean
pixel shift between them.
"""

from __future__ import annotations

import numpy as np

from .basic import _axes

__all__ = ["plot_halves_chi2"]


def plot_halves_chi2(crossval, *, ax=None):
    """Chi-square per direction and mean shift for each split of the views.

    Parameters
    ----------
    crossval : dict
        ``chi2`` (S,), ``mean_shift`` (S,) px and ``splits`` (S pairs of index lists), as
        returned by :func:`~bayescal.validation.camera_cv.halves_chi2`.
    ax : matplotlib Axes, optional

    Returns
    -------
    matplotlib.figure.Figure
    """
    fig, ax = _axes(ax, figsize=(7, 4))
    chi2 = np.asarray(crossval["chi2"], float)
    shift = np.asarray(crossval["mean_shift"], float)
    labels = [" ".join(map(str, a)) + " / " + " ".join(map(str, b))
              for a, b in crossval["splits"]]
    x = np.arange(len(chi2))
    ax.plot(x, chi2, "o", color="tab:blue", label="chi-square per direction")
    ax.axhline(2.0, color="gray", ls="--", label="2: honest covariances")
    ax.axhline(chi2.mean(), color="tab:blue", lw=1, label=f"mean {chi2.mean():.2f}")
    ax.set_yscale("log")
    ax.set_xticks(x, labels, rotation=45, ha="right", fontsize=7)
    ax.set_xlabel("views in half A / half B")
    ax.set_ylabel("chi-square per direction")
    right = ax.twinx()
    right.plot(x, shift, "s", color="tab:orange", ms=4, label="mean shift (px)")
    right.set_ylabel("mean shift between the halves, px", color="tab:orange")
    right.set_ylim(0, None)
    h1, l1 = ax.get_legend_handles_labels()
    h2, l2 = right.get_legend_handles_labels()
    ax.legend(h1 + h2, l1 + l2, fontsize=7, loc="upper left")
    ax.set_title("Cross-validation between halves of the views")
    fig.tight_layout()
    return fig
