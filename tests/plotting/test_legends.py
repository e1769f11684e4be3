"""Legends and labels never hide data: in the figures calibrate-camera and the calibration
report draw, no legend or text covers a data point, and no legend covers a label."""

import numpy as np
import pytest

import bayescal as bc
from bayescal.plotting import (
    plot_image_residuals,
    plot_reconstruction,
    plot_reconstruction_ellipses,
    plot_view_residuals,
)


def _data(ax):
    """Display coordinates of the points drawn in ``ax`` (line vertices, scatter and quiver
    offsets) that lie inside it."""
    pts = [line.get_transform().transform(np.column_stack(line.get_data()).astype(float))
           for line in ax.get_lines()]
    pts += [c.get_offset_transform().transform(c.get_offsets()) for c in ax.collections
            if len(c.get_offsets())]
    p = np.concatenate(pts) if pts else np.zeros((0, 2))
    p = p[np.all(np.isfinite(p), axis=1)]
    return p[[ax.get_window_extent().contains(*q) for q in p]]


def _clashes(fig):
    """(what, whose) pairs: a legend or text over data, over a label, or over another text."""
    fig.canvas.draw()
    r = fig.canvas.get_renderer()
    out = []
    labels = [a for ax in fig.axes for a in (ax.xaxis.label, ax.yaxis.label, ax.title,
                                              *ax.get_xticklabels(), *ax.get_yticklabels())
              if a.get_text() and a.get_visible()]
    for ax in fig.axes:
        pts = _data(ax)
        boxes = [(t.get_text(), t.get_window_extent(r)) for t in ax.texts]
        if ax.get_legend() is not None:
            boxes.append(("legend", ax.get_legend().get_window_extent(r)))
        for name, bb in boxes:
            if any(bb.contains(*q) for q in pts):
                out.append((name, "data"))
            out += [(name, a.get_text()) for a in labels if bb.overlaps(a.get_window_extent(r))]
        out += [(a, b) for k, (a, x) in enumerate(boxes) for b, y in boxes[k + 1:]
                if x.overlaps(y)]
    return out


@pytest.fixture(scope="module")
def camera():
    views, _ = bc.simulate_views(n_views=5, rng=2)
    return bc.calibrate_camera(views, noise="per-view"), views


def test_the_checker_sees_a_legend_on_data():
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots()
    ax.plot(np.linspace(0, 1, 50), np.ones(50), ".", label="points")
    ax.legend(loc="center")
    ax.annotate("view 1", (0.5, 1.0))
    assert ("legend", "data") in _clashes(fig) and ("view 1", "data") in _clashes(fig)
    plt.close(fig)


def test_camera_figures(camera):
    cam, views = camera
    assert _clashes(plot_view_residuals(cam)) == []
    fig = plot_image_residuals(cam, views)
    assert _clashes(fig) == [] and not fig.axes[0].texts          # the views named aside
    names = [t.get_text() for t in fig.axes[0].get_legend().get_texts()]
    assert names == [v.name for v in views] + ["principal point"]


def test_reconstruction_figures():
    ds = bc.simulate_room(range_mm=2500, n_points=120, sigma_px=0.2, approx_error=0.03,
                          approx_model="gaussian", rng=4)
    res = bc.calibrate_simultaneous(ds.pixels, ds.approx_points, sigma_px=0.2,
                                    sigma_scene=ds.sigma_scene)
    mean, cov = res.reconstruct(ds.pixels)
    assert _clashes(plot_reconstruction_ellipses(mean, cov, truth=ds.points,
                                                 walls=ds.walls)) == []
    assert _clashes(plot_reconstruction(mean, cov, truth=ds.points, walls=ds.walls)) == []
