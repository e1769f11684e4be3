"""Every plotting function runs on the agg backend and returns a Figure."""

import matplotlib.pyplot as plt
import numpy as np
import pytest
from matplotlib.figure import Figure

import bayescal as bc
import bayescal.plotting
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


# -- uncertainty figures -------------------------------------------------------------------

@pytest.fixture(scope="module")
def fit(room):
    res = bc.calibrate_simultaneous(room.pixels, room.approx_points, sigma_px=0.1,
                                    sigma_scene=np.maximum(room.sigma_scene, 1.0))
    return res


def test_reconstruction_ellipses_are_capped_and_frame_is_radial(room, fit):
    from bayescal.plotting import plot_reconstruction_ellipses, radial_tangential_sd

    fig = plot_reconstruction_ellipses(fit.points, fit.point_covariance(),
                                       approx_points=room.approx_points, truth=room.points,
                                       max_ellipses=25)
    from matplotlib.patches import Ellipse

    n = sum(isinstance(p, Ellipse) for p in fig.axes[0].patches)
    assert 0 < n <= 25 and len(fig.axes) == 3
    assert "(mm)" in fig.axes[1].get_ylabel()
    plt.close(fig)
    # an isotropic covariance has the same sd in every frame; a radial one only radially
    pts = np.array([[1000.0, 0, 0], [0, 1000.0, 0]])
    cov = np.zeros((2, 3, 3))
    cov[0, 0, 0] = cov[1, 1, 1] = 4.0                     # 2 mm along each point's radius
    sd, _ = radial_tangential_sd(pts, cov)
    np.testing.assert_allclose(sd, [[2, 0, 0], [2, 0, 0]], atol=1e-12)


def test_least_squares_residuals_are_standard_normal(room, fit):
    """With the right noise, leverage-standardized residuals have RMS about 1.

    240 values: the RMS of N(0, 1) has sd about 1/sqrt(2 * 240) = 0.046; the neglected
    leverage of the 7 global parameters lowers it by about 7 / 240 / 2 = 1.5 %. The band
    0.8-1.15 is > 4 sd wide on each side (false failure < 1e-4).
    """
    from bayescal.checks.residuals import least_squares_residuals
    from bayescal.plotting import plot_pixel_residuals

    raw, z = least_squares_residuals(fit, room.pixels, 0.1, np.maximum(room.sigma_scene, 1.0))
    rms = float(np.sqrt(np.mean(z**2)))
    assert 0.8 < rms < 1.15, rms
    fig = plot_pixel_residuals(room.pixels, z, raw=raw, title="t")
    assert "RMS per coordinate" in fig.axes[1].get_title()
    plt.close(fig)


def test_validation_figures(tmp_path):
    from bayescal.plotting.validation import plot_sbc

    counts = np.full((8, 10), 10)
    plot_sbc(counts, np.zeros(8), 100, tmp_path / "sbc.png")
    assert (tmp_path / "sbc.png").stat().st_size > 1000


def test_plot_floor_plan_draws_every_layer(rng):
    from bayescal.plotting import plot_floor_plan, wall_draws

    ds = bc.simulate_room(range_mm=1000, n_points=40, sigma_px=0.5, approx_error=0.05, rng=rng)
    plan = ds.floor_plan
    walls = np.column_stack([plan.distances, plan.angles])
    cov = np.diag(np.column_stack([plan.distance_sd, plan.angle_sd]).ravel() ** 2)
    draws = wall_draws(walls, covariance=cov, n_draws=4000, rng=1)
    # draws from the Laplace approximation have its covariance (4000 draws: relative sd
    # error of the variance ~2.2 %, 5 sd margin)
    np.testing.assert_allclose(draws.reshape(4000, -1).var(axis=0), np.diag(cov), rtol=0.12)
    post = wall_draws(walls, samples=draws, n_draws=10)
    assert post.shape == (10,) + walls.shape
    cov3 = np.broadcast_to(np.eye(3) * 100.0, (40, 3, 3))
    fig = plot_floor_plan(plan, walls=walls, wall_covariance=cov, points=ds.points,
                          point_covariance=cov3, truth_walls=ds.walls, truth_points=ds.points,
                          max_ellipses=10)
    ax = fig.axes[0]
    labels = {t.get_text() for t in ax.get_legend().get_texts()}
    assert {"plan as given", "wall draws", "estimated walls", "true walls", "points",
            "true points"} <= labels
    assert len(ax.patches) == 10                         # one ellipse in every 4 points
    plt.close(fig)


def test_plot_sequential_residuals_draws_both_stages():
    from bayescal.fit.sequential import SequentialResiduals

    rng = np.random.default_rng(0)
    res = SequentialResiduals(grid_px=rng.normal(size=(50, 2)), grid_z=rng.normal(size=(50, 2)),
                              laser_mm=rng.normal(size=40), laser_z=rng.normal(size=40))
    fig = bc.plotting.plot_sequential_residuals(res)
    titles = [ax.get_title() for ax in fig.axes]
    assert any("Stage 1" in t for t in titles) and any("Stage 2" in t for t in titles)
