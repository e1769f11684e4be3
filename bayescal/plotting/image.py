"""The laser overlay: an image with its extracted laser pixels coloured by their sd."""

from __future__ import annotations

import numpy as np

__all__ = ["plot_laser_overlay"]


def plot_laser_overlay(image, laser, *, ax=None, zoom=True):
    """Show an image with the extracted laser pixels, coloured by their normal sd.

    Parameters
    ----------
    image : ndarray, shape (H, W) or (H, W, C)
        The image the pixels came from.
    laser : LaserPixels
        Output of :func:`bayescal.extract_laser`.
    ax : matplotlib Axes, optional
    zoom : bool, optional
        Limit the view to the ring (with a 15 % margin).

    Returns
    -------
    matplotlib.figure.Figure
    """
    import matplotlib.pyplot as plt

    if ax is None:
        fig, ax = plt.subplots(figsize=(7, 6))
    else:
        fig = ax.figure
    img = np.asarray(image, dtype=float)
    ax.imshow(img if img.ndim == 2 else img / max(img.max(), 1), cmap="gray")
    ok = ~laser.flagged
    sc = ax.scatter(*laser.pixels[ok].T, c=laser.sd_normal[ok], s=4, cmap="viridis",
                    label="laser pixels")
    fig.colorbar(sc, ax=ax, label="sd along the ring's normal (px)", shrink=0.8)
    if np.any(laser.flagged):
        ax.scatter(*laser.pixels[laser.flagged].T, marker="x", s=14, c="red", lw=0.8,
                   label=f"flagged ({int(laser.flagged.sum())})")
    if zoom and len(laser):
        lo, hi = laser.pixels.min(0), laser.pixels.max(0)
        m = 0.15 * (hi - lo).max()
        ax.set_xlim(lo[0] - m, hi[0] + m)
        ax.set_ylim(hi[1] + m, lo[1] - m)
    ax.set_xlabel("u (px)")
    ax.set_ylabel("v (px)")
    ax.legend(loc="upper right", fontsize=8)
    return fig
