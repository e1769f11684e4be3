"""Figures: the image plane (paper's Fig. 6b) and the room (Fig. 6a).

Every function takes an optional matplotlib ``ax`` and returns the figure, so
it can be composed or saved by the caller. matplotlib is imported lazily.
"""

from __future__ import annotations

import numpy as np

from .._validation import as_pixels, as_points
from ..errors import InvalidValueError

__all__ = ["plot_image", "plot_room", "plot_residuals", "plot_reconstruction", "savefig",
           "legend_outside"]


def _axes(ax, projection=None, figsize=(6, 5)):
    import matplotlib.pyplot as plt

    if ax is not None:
        return ax.figure, ax
    fig = plt.figure(figsize=figsize)
    return fig, fig.add_subplot(111, projection=projection)


def legend_outside(ax, where="right", **kw):
    """A legend outside the axes, where it cannot hide data: at the right of the axes
    (``where="right"``) or below them, under the x label (``"below"``, in columns)."""
    handles, labels = ax.get_legend_handles_labels()
    if where == "below":
        return ax.legend(handles, labels, loc="upper center", bbox_to_anchor=(0.5, -0.13),
                         ncol=min(len(labels), 3), borderaxespad=0.0, **kw)
    return ax.legend(handles, labels, loc="upper left", bbox_to_anchor=(1.02, 1.0),
                     borderaxespad=0.0, **kw)


def plot_image(pixels, *, params=None, image_size=(800, 600), ax=None, label="laser pixels",
               **scatter_kw):
    """Plot laser pixels in the image plane (paper's Fig. 6b).

    Parameters
    ----------
    pixels : array_like, shape (N, 2)
        ``(u, v)`` in px.
    params : SensorParams, optional
        If given, the principal point is marked.
    image_size : (int, int), optional
        Width and height of the image frame drawn, px.
    ax : matplotlib.axes.Axes, optional

    Returns
    -------
    matplotlib.figure.Figure
    """
    pixels = as_pixels(pixels, allow_nan=True)
    fig, ax = _axes(ax)
    kw = {"s": 4, "c": "tab:red"}
    kw.update(scatter_kw)
    ax.scatter(pixels[:, 0], pixels[:, 1], label=label, **kw)
    if params is not None:
        ax.plot(params.u0, params.v0, "k+", ms=10, label="principal point")
    w, h = image_size
    ax.set_xlim(0, w)
    ax.set_ylim(h, 0)
    ax.set_aspect("equal")
    ax.set_xlabel("u (px)")
    ax.set_ylabel("v (px)")
    n_ok = int(np.isfinite(pixels).all(axis=1).sum())
    title = f"{n_ok} laser pixels in the {w} x {h} px image"
    if params is not None and n_ok:
        r = np.hypot(pixels[:, 0] - params.u0, pixels[:, 1] - params.v0)
        title += (f"\nring radius {np.nanmin(r):.1f} to {np.nanmax(r):.1f} px about the "
                  f"principal point ({params.u0:.1f}, {params.v0:.1f}) px")
    ax.set_title(title, fontsize="medium")
    ax.legend(loc="upper right", fontsize="small")
    return fig


def plot_room(points, *, walls=None, approx_points=None, view="top", ax=None):
    """Plot the room and its laser points (paper's Fig. 6a).

    Parameters
    ----------
    points : array_like, shape (N, 3)
        Laser points in frame C, mm.
    walls : ndarray, shape (W, 2, 2), optional
        Wall segments (horizontal end points), mm.
    approx_points : array_like, shape (N, 3), optional
        Approximate points, drawn in grey.
    view : {"top", "3d"}
        Top view (x, y) or a 3D view.
    ax : matplotlib.axes.Axes, optional

    Returns
    -------
    matplotlib.figure.Figure
    """
    points = as_points(points, allow_nan=True)
    if view not in ("top", "3d"):
        raise InvalidValueError(f"view must be 'top' or '3d', got {view!r}")
    fig, ax = _axes(ax, projection="3d" if view == "3d" else None)
    if view == "top":
        if walls is not None:
            for seg in np.asarray(walls):
                ax.plot(seg[:, 0], seg[:, 1], "k-", lw=1.5)
        if approx_points is not None:
            ap = as_points(approx_points, "approx_points", allow_nan=True)
            ax.scatter(ap[:, 0], ap[:, 1], s=3, c="0.6", label="approximate points")
        ax.scatter(points[:, 0], points[:, 1], s=4, c="tab:red", label="laser points")
        ax.plot(0, 0, "b^", label="sensor")
        ax.set_aspect("equal")
        ax.set_xlabel("x (mm)")
        ax.set_ylabel("y (mm)")
        ax.set_title("Room, top view")
        ax.legend(loc="upper right", fontsize="small")
    else:
        if walls is not None:
            zlo, zhi = np.nanmin(points[:, 2]), np.nanmax(points[:, 2])
            for seg in np.asarray(walls):
                for z in (zlo, zhi):
                    ax.plot(seg[:, 0], seg[:, 1], [z, z], "k-", lw=0.8)
                for j in (0, 1):
                    ax.plot([seg[j, 0]] * 2, [seg[j, 1]] * 2, [zlo, zhi], "k-", lw=0.8)
        ax.scatter(points[:, 0], points[:, 1], points[:, 2], s=3, c="tab:red")
        ax.scatter([0], [0], [0], c="b", marker="^")
        ax.set_xlabel("x (mm)")
        ax.set_ylabel("y (mm)")
        ax.set_zlabel("z (mm)")
        ax.set_title("Room, 3D view")
    return fig


def savefig(fig, path, *, dpi=120):
    """Save ``fig`` to ``path`` (parent folders created) and close it."""
    import pathlib

    import matplotlib.pyplot as plt

    path = pathlib.Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=dpi, bbox_inches="tight")
    plt.close(fig)
    return path


def plot_residuals(pixels, predicted, *, scale=200.0, ax=None):
    """Pixel residuals in the image as arrows (magnified by ``scale``).

    Parameters
    ----------
    pixels : array_like, shape (N, 2)
        Observed pixels.
    predicted : array_like, shape (N, 2)
        Model pixels (e.g. ``project(params, points)``).
    scale : float, optional
        Magnification of the residual arrows.

    Returns
    -------
    matplotlib.figure.Figure
    """
    pixels = as_pixels(pixels)
    predicted = as_pixels(predicted, "predicted", allow_nan=True)
    if pixels.shape != predicted.shape:
        raise InvalidValueError(
            f"pixels and predicted must have the same shape, got {pixels.shape} "
            f"and {predicted.shape}")
    fig, ax = _axes(ax)
    d = pixels - predicted
    ax.quiver(predicted[:, 0], predicted[:, 1], d[:, 0] * scale, d[:, 1] * scale,
              angles="xy", scale_units="xy", scale=1, width=0.002, color="tab:blue")
    ax.scatter(predicted[:, 0], predicted[:, 1], s=2, c="k")
    rms = float(np.sqrt(np.nanmean(d**2)))
    ax.set_aspect("equal")
    ax.invert_yaxis()
    ax.set_xlabel("u (px)")
    ax.set_ylabel("v (px)")
    ax.set_title(f"Pixel residuals x{scale:.3g} (RMS per coordinate {rms:.3g} px)")
    return fig


def plot_reconstruction(mean, covariance, *, truth=None, walls=None, n_sigma=2.0, every=None,
                        max_ellipses=60, ax=None):
    """Top view of reconstructed points with their uncertainty ellipses.

    Parameters
    ----------
    mean : array_like, shape (N, 3)
        Reconstructed points, mm.
    covariance : array_like, shape (N, 3, 3)
        Their covariances, mm^2; the (x, y) block is drawn as an ellipse.
    truth : array_like, shape (N, 3), optional
        True points.
    walls : ndarray, shape (W, 2, 2), optional
    n_sigma : float, optional
        Ellipse size in standard deviations (2 holds ~86 % in 2-D).
    every : int, optional
        Draw one ellipse in ``every`` points (default: enough to draw at most
        ``max_ellipses``, so that the ellipses never merge into a fur).
    max_ellipses : int, optional

    Returns
    -------
    matplotlib.figure.Figure
    """
    from matplotlib.patches import Ellipse

    mean = as_points(mean, "mean", allow_nan=True)
    covariance = np.asarray(covariance, dtype=float)
    if covariance.shape != mean.shape + (3,):
        raise InvalidValueError(f"covariance must have shape {mean.shape + (3,)}, got "
                                f"{covariance.shape}")
    fig, ax = _axes(ax)
    if walls is not None:
        for seg in np.asarray(walls):
            ax.plot(seg[:, 0], seg[:, 1], "k-", lw=1)
    if every is None:
        every = int(np.ceil(len(mean) / max(int(max_ellipses), 1)))
    for i in range(0, len(mean), max(int(every), 1)):
        c = covariance[i, :2, :2]
        if not np.all(np.isfinite(c)):
            continue
        e, v = np.linalg.eigh(c)
        angle = np.degrees(np.arctan2(v[1, 1], v[0, 1]))
        w, h = 2 * n_sigma * np.sqrt(np.clip(e[::-1], 0, None))
        ax.add_patch(Ellipse(mean[i, :2], w, h, angle=angle, fill=False, lw=0.6,
                             color="tab:blue"))
    if truth is not None:
        truth = as_points(truth, "truth")
        ax.scatter(truth[:, 0], truth[:, 1], s=4, c="tab:red", label="true points", zorder=4)
    ax.scatter(mean[:, 0], mean[:, 1], s=2, c="tab:blue", label="reconstructed", zorder=3)
    ax.plot(0, 0, "k^")
    ax.set_aspect("equal")
    ax.set_xlabel("x (mm)")
    ax.set_ylabel("y (mm)")
    ax.set_title(f"Reconstruction, {n_sigma:.3g}-sigma ellipses (one in {every})")
    legend_outside(ax, "below", fontsize="small")
    return fig
