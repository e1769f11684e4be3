"""Every plotting function runs on the agg backend and returns a Figure."""

import matplotlib.pyplot as plt
import numpy as np
import pytest
from matplotlib.figure import Figure

import bayescal as bc
from bayescal.plotting import plot_image, plot_room, savefig


@pytest.fixture(scope="module")
def room():
    return bc.simulate_room(range_mm=5000, n_points=120, sigma_px=0.1, approx_error=0.05, rng=0)


def test_plot_image(room):
    fig = plot_image(room.pixels, params=room.params)
    assert isinstance(fig, Figure)
    ax = fig.axes[0]
    assert ax.get_ylim() == (600.0, 0.0)                 # v grows downwards
    np.testing.assert_allclose(ax.collections[0].get_offsets(), room.pixels)
    plt.close(fig)
    fig, ax = plt.subplots()
    assert plot_image(room.pixels, ax=ax, c="k") is fig  # draws into the caller's axes
    plt.close(fig)


@pytest.mark.parametrize("view", ["top", "3d"])
def test_plot_room(room, view):
    fig = plot_room(room.points, walls=room.walls, approx_points=room.approx_points, view=view)
    assert isinstance(fig, Figure)
    assert len(fig.axes) == 1
    plt.close(fig)
    fig = plot_room(room.points, view=view)
    assert isinstance(fig, Figure)
    plt.close(fig)


def test_plot_room_bad_view(room):
    with pytest.raises(ValueError, match=r"view must be 'top' or '3d', got 'side'"):
        plot_room(room.points, view="side")
    with pytest.raises(ValueError, match=r"points must have shape \(\.\.\., 3\)"):
        plot_room(room.pixels)


def test_savefig_writes_png(room, tmp_path):
    path = savefig(plot_image(room.pixels), tmp_path / "sub" / "image.png")
    assert path.exists() and path.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
