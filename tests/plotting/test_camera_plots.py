"""Per-view residuals and residuals over the image draw without error."""

import pytest

import bayescal as bc
from bayescal.plotting import plot_image_residuals, plot_view_residuals


def test_camera_plots(tmp_path):
    views, _ = bc.simulate_views(n_views=3, rng=2)
    cam = bc.calibrate_camera(views, noise="per-view")
    fig = plot_view_residuals(cam)
    assert len(fig.axes) == 1
    fig.savefig(tmp_path / "views.png")
    fig = plot_image_residuals(cam, views)
    fig.savefig(tmp_path / "image.png")
    with pytest.raises(ValueError, match="views"):
        plot_image_residuals(cam, views[:2])
