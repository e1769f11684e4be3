"""The cross-validation figure of a camera calibration."""

import numpy as np

from bayescal.plotting.camera_cv import plot_halves_chi2


def test_plot_halves_chi2_draws_every_split():
    cv = {"chi2": np.array([1.5, 2.5, 9.0]), "mean_shift": np.array([0.5, 1.0, 3.0]),
          "splits": [([0, 1], [2, 3]), ([0, 2], [1, 3]), ([0, 3], [1, 2])]}
    fig = plot_halves_chi2(cv)
    ax = fig.axes[0]
    np.testing.assert_allclose(ax.lines[0].get_ydata(), cv["chi2"])
    assert [t.get_text() for t in ax.get_xticklabels()] == ["0 1 / 2 3", "0 2 / 1 3",
                                                            "0 3 / 1 2"]
    np.testing.assert_allclose(fig.axes[1].lines[0].get_ydata(), cv["mean_shift"])
