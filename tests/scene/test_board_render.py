"""render_board: chessboards through eq. (1), with exact corners."""

import numpy as np
import pytest
from helpers import REAL_LIKE_POSES

import bayescal as bc
from bayescal.sensor.board import project_board

# the real-like camera at a quarter of the size: any image size renders
SMALL = {"xi": 1.134, "gamma_u": 79.5, "gamma_v": -79.5, "u0": 160.6, "v0": 130.7}


def test_truth_is_the_projection_and_the_image_is_reproducible():
    pose = REAL_LIKE_POSES[0]
    img, truth = bc.render_board(SMALL, pose, image_size=(320, 256), rng=3)
    assert img.shape == (256, 320) and img.dtype == np.uint8
    k = [SMALL[n] for n in ("xi", "gamma_u", "gamma_v", "u0", "v0")]
    uv, _ = project_board(k, pose, bc.board_points((8, 6), 42.0))
    np.testing.assert_allclose(truth.pixels, uv, rtol=0, atol=1e-12)
    assert truth.image_size == (320, 256)
    again, _ = bc.render_board(list(SMALL.values()), pose, image_size=(320, 256), rng=3)
    np.testing.assert_array_equal(img, again)


def test_levels_and_anti_aliasing():
    levels = (30.0, 220.0, 100.0)
    img, truth = bc.render_board(SMALL, REAL_LIKE_POSES[3], image_size=(320, 256), noise=0.0,
                                 psf_px=0.0, levels=levels, rng=0)
    assert img[0, 0] == 0                                   # outside the mirror's image
    assert img[int(SMALL["v0"]), int(SMALL["u0"])] == 100   # the scene around the board
    vals = np.unique(img)
    assert {30, 220} <= set(vals.tolist())
    # supersampling leaves grey levels between the squares' along their edges
    assert np.count_nonzero((img > 31) & (img < 219) & (img != 100)) > 100


def test_poses_that_cannot_be_rendered():
    above = [0.0, 0.0, 0.0, -147.0, -105.0, 300.0]    # straight up: beyond the rim
    with pytest.raises(ValueError, match="field of view"):
        bc.render_board(SMALL, above, image_size=(320, 256))
    edge_on = [np.pi / 2, 0.0, 0.0, 300.0, 0.0, 0.0]  # its plane through the focus
    with pytest.raises(ValueError, match="edge-on"):
        bc.render_board(SMALL, edge_on, image_size=(320, 256))
    with pytest.raises(ValueError, match="inside the 100x80 image"):
        bc.render_board(SMALL, REAL_LIKE_POSES[0], image_size=(100, 80))
    with pytest.raises(ValueError, match="intrinsics lack"):
        bc.render_board({"xi": 1.0}, REAL_LIKE_POSES[0])
    with pytest.raises(ValueError, match="pose must be 6"):
        bc.render_board(SMALL, [0.0, 0.0, 0.0])
