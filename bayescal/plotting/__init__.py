"""Figures: the image plane and the room (the paper's Fig. 6), and a calibration's uncertainty.

Every function returns a matplotlib figure (most take an optional ``ax``), so
it can be composed or saved by the caller (:func:`savefig`). matplotlib and
corner are imported when a figure is drawn, never at import time.
"""

from .basic import plot_image, plot_reconstruction, plot_residuals, plot_room, savefig
from .camera import plot_image_residuals, plot_view_residuals
from .diagnostics import (
    UNITS,
    plot_corner,
    plot_pixel_residuals,
    plot_reconstruction_ellipses,
    radial_tangential_sd,
)
from .plan import plot_floor_plan, wall_draws
from .sequential import plot_sequential_residuals

__all__ = ["plot_image", "plot_room", "plot_corner", "plot_residuals", "plot_reconstruction",
           "plot_pixel_residuals", "plot_reconstruction_ellipses", "radial_tangential_sd",
           "savefig", "UNITS", "plot_floor_plan", "wall_draws", "plot_sequential_residuals",
           "plot_view_residuals", "plot_image_residuals"]
