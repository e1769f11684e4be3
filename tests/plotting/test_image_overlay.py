"""The laser overlay figure."""

import numpy as np

import bayescal as bc
from bayescal.plotting.image import plot_laser_overlay


def test_overlay_marks_flagged_points_and_zooms_on_the_ring():
    img, truth = bc.render_image(bc.SensorParams.paper(), bc.room_walls(2500), rng=4, n_lamps=3)
    lp = bc.extract_laser(img)
    fig = plot_laser_overlay(img, lp)
    ax = fig.axes[0]
    assert len(ax.collections) == 1 + int(np.any(lp.flagged))
    assert ax.get_xlim()[0] > 0 and ax.get_xlim()[1] < img.shape[1]
