"""The demo's image stage: the truth of extracted pixels."""

import numpy as np
import pytest

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


def test_the_demo_warns_in_the_users_words():
    # its stages read files in a staging folder and calibrate with the demo's own floor
    # plan: a warning names the final folder, and not an option the user never gave
    import warnings

    from bayescal.cli.demo import _said_as_final

    with pytest.warns(UserWarning) as caught:
        with _said_as_final("/tmp/.out.x1.bayescal-tmp", "out"):
            warnings.warn("/tmp/.out.x1.bayescal-tmp/image/laser.csv: with --walls, pixel sds "
                          "up to 2.87 px in 1 of 359 rows", stacklevel=1)
    text = str(caught[0].message)
    assert text.startswith("out/image/laser.csv: with a floor plan (the demo's data/walls.csv)")
    assert "bayescal-tmp" not in text and "--walls" not in text
