"""The demo's image stage: the truth of extracted pixels."""

import numpy as np

import bayescal as bc
from bayescal.cli.demo import _true_points


def test_true_points_of_pixels_on_the_true_ring():
    """Pixels on the renderer's true centre line get back its true points (to the
    interpolation between its 3600 azimuths), wherever they fall between samples."""
    p = bc.SensorParams.paper()
    _, ring = bc.render_image(p, bc.room_walls(2500), shape=(300, 400), n_truth=3600, rng=0)
    fine = bc.render_image(p, bc.room_walls(2500), shape=(300, 400), n_truth=36000, rng=0)[1]
    k = np.arange(5, len(fine.pixels), 97)                # between the coarse samples
    got = _true_points(p, fine.pixels[k], ring)
    err = np.linalg.norm(got - fine.points[k], axis=1)
    # linear interpolation along a wall is exact; across a corner up to ~a sample (4 mm)
    assert np.median(err) < 0.5 and err.max() < 10, (np.median(err), err.max())
