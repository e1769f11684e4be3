"""Figures of a camera calibration from board views: residuals per view, and over the image.

Both take a :class:`~bayescal.CameraResult` (and, over the image, the views it was
fitted to), an optional matplotlib ``ax``, and return the figure.
"""

from __future__ import annotations

import numpy as np

from ..errors import InvalidValueError
from .basic import _axes, legend_outside

__all__ = ["plot_view_residuals", "plot_image_residuals"]


def plot_view_residuals(result, *, ax=None):
    """Residuals of every view, one box per view (u and v pooled), with its noise level.

    Parameters
    ----------
    result : CameraResult
    ax : matplotlib.axes.Axes, optional

    Returns
    -------
    matplotlib.figure.Figure
    """
    fig, ax = _axes(ax, figsize=(max(6.5, 0.6 * len(result.view_names) + 3.5), 4))
    data = [r.ravel() for r in result.residuals]
    pos = np.arange(1, len(data) + 1)
    ax.boxplot(data, positions=pos)
    ax.plot(pos, 2 * result.sigma, "r_", ms=14, label="2 sigma of the view")
    ax.plot(pos, -2 * result.sigma, "r_", ms=14)
    ax.axhline(0.0, color="k", lw=0.5)
    ax.set_xticks(pos, result.view_names, rotation=45, ha="right", fontsize=8)
    ax.set_ylabel("residual (px)")
    ax.set_title(f"per-view residuals ({result.method}, noise {result.noise!r})",
                 fontsize="medium")
    legend_outside(ax, fontsize=8)
    fig.tight_layout()
    return fig


def plot_image_residuals(result, views, *, scale=100.0, ax=None):
    """Residual vectors at every corner over the image, magnified ``scale`` times, one colour
    per view (named in the legend beside the image).

    Parameters
    ----------
    result : CameraResult
    views : sequence of BoardView
        The views the result was fitted to (same order).
    scale : float
        Magnification of the arrows.
    ax : matplotlib.axes.Axes, optional

    Returns
    -------
    matplotlib.figure.Figure
    """
    views = list(views)
    if len(views) != len(result.residuals):
        raise InvalidValueError(f"views must be the {len(result.residuals)} views of the result, "
                                f"got {len(views)}")
    fig, ax = _axes(ax, figsize=(9, 5.6))
    colours = [f"C{j % 10}" for j in range(len(views))]
    for v, r, c in zip(views, result.residuals, colours, strict=True):
        ax.quiver(v.pixels[:, 0], v.pixels[:, 1], scale * r[:, 0], scale * r[:, 1],
                  angles="xy", scale_units="xy", scale=1.0, width=0.002, color=c)
        ax.plot([], [], color=c, label=v.name)        # the view's colour, named beside
    k = result.intrinsics
    ax.plot(k["u0"], k["v0"], "k+", ms=12, label="principal point")
    if result.image_size is not None:
        ax.set_xlim(0, result.image_size[0])
        ax.set_ylim(result.image_size[1], 0)
    else:
        ax.invert_yaxis()
    ax.set_aspect("equal")
    ax.set_xlabel("u (px)")
    ax.set_ylabel("v (px)")
    ax.set_title(f"residuals over the image (x{scale:g})")
    legend_outside(ax, fontsize=8)
    fig.tight_layout()
    return fig
