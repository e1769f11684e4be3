"""find_chessboard: OpenCV's corners on rendered boards (known truth) and on the real views."""

import os
import pathlib
import sys
import warnings

import numpy as np
import pytest
from helpers import REAL_LIKE_CAMERA, REAL_LIKE_POSES

import bayescal as bc
from bayescal.image.chessboard import board_extent, order_corners

pytest.importorskip("cv2")

# the shared real views: ../shared/data/para beside the repository, or $BAYESCAL_PARA_DIR
REAL = pathlib.Path(os.environ.get("BAYESCAL_PARA_DIR") or
                    pathlib.Path(__file__).resolve().parents[2].parent / "shared" / "data" / "para")
CENTRE = (639.5, 511.5)   # centre of a 1280 x 1024 image

# Corner accuracy required of the detector on a rendered board: 0.25 px at worst and
# 0.08 px rms. The image noise (sd 2 grey levels on a contrast of 190, edges blurred to
# ~0.6 px) moves a corner located from ~11-px edge segments by
# 2 * sqrt(2 sqrt(pi) 0.6) / (190 sqrt(11)) = 0.005 px sd, so noise alone never fails
# these bounds; what they bound is the detector's own bias on curved catadioptric edges
# (measured 0.03 px rms, 0.12 px max), which must stay well below the real views' residual
# noise (0.16-0.35 px) for a calibration to be limited by the images, not the detector.
MAX_ERR, RMS_ERR = 0.25, 0.08


@pytest.fixture(scope="module")
def rendered():
    """Views 0 (OpenCV lists it in the fixed order) and 2 (OpenCV lists it reversed)."""
    return [bc.render_board(REAL_LIKE_CAMERA, REAL_LIKE_POSES[k], rng=k) for k in (0, 2)]


def _check_corners(view, truth):
    expected = order_corners(truth.pixels, (8, 6), center=CENTRE)
    err = view.pixels - expected
    assert np.abs(err).max() < MAX_ERR
    assert np.sqrt(np.mean(err ** 2)) < RMS_ERR
    np.testing.assert_array_equal(view.points, bc.board_points((8, 6), 42.0))


@pytest.mark.parametrize("k", [0, 1])
def test_corners_of_rendered_boards_match_the_truth(rendered, k):
    img, truth = rendered[k]
    view = bc.find_chessboard(img, board=(8, 6), square=42.0)
    assert view is not None and view.n_corners == 48
    assert view.image_size == (1280, 1024) and view.name == "image"
    _check_corners(view, truth)


def test_corner_order_is_fixed_whatever_opencv_returns(rendered):
    # view 0's truth is already in the fixed order (first row outermost), view 2's is not
    t0, t2 = rendered[0][1].pixels, rendered[1][1].pixels
    np.testing.assert_array_equal(order_corners(t0, (8, 6), center=CENTRE), t0)
    np.testing.assert_array_equal(order_corners(t2, (8, 6), center=CENTRE), t2[::-1])
    for t in (t0, t2):
        np.testing.assert_array_equal(order_corners(t[::-1], (8, 6), center=CENTRE),
                                      order_corners(t, (8, 6), center=CENTRE))


def test_pgm_16_bit_and_colour_images(rendered, tmp_path):
    import imageio.v3 as iio

    img, truth = rendered[0]
    path = tmp_path / "board.pgm"
    iio.imwrite(path, img)
    view = bc.find_chessboard(path)
    assert view.name == "board.pgm"
    _check_corners(view, truth)
    colour = np.repeat(img[..., None], 3, axis=2)
    _check_corners(bc.find_chessboard(colour, name="c"), truth)
    deep = tmp_path / "board16.png"                   # 16 bit, the full range used
    iio.imwrite(deep, (img.astype(np.uint16) * 257))
    _check_corners(bc.find_chessboard(deep), truth)


@pytest.mark.slow
def test_sector_based_detector(rendered):
    img, truth = rendered[1]
    _check_corners(bc.find_chessboard(img, method="sb"), truth)


def test_no_board_gives_none(rng):
    img = np.clip(100 + 20 * rng.standard_normal((240, 320)), 0, 255).astype(np.uint8)
    assert bc.find_chessboard(img) is None
    assert bc.find_chessboard(np.full((64, 64), 7.0)) is None


def test_bad_arguments(rendered, tmp_path):
    img = rendered[0][0]
    with pytest.raises(ValueError, match="method"):
        bc.find_chessboard(img, method="fast")
    with pytest.raises(TypeError, match="board"):
        bc.find_chessboard(img, board=8)
    with pytest.raises(FileNotFoundError, match="nope.png"):
        bc.find_chessboard(tmp_path / "nope.png")


def test_without_opencv_the_error_says_what_to_install(monkeypatch):
    monkeypatch.setitem(sys.modules, "cv2", None)
    with pytest.raises(ImportError, match=r"pip install bayescal\[camera\]"):
        bc.find_chessboard(np.zeros((64, 64)))


@pytest.mark.skipif(not REAL.is_dir(), reason="../shared/data/para is absent")
def test_every_real_view_is_found():
    paths = sorted(REAL.glob("img_para_*.pgm"))
    assert len(paths) == 5
    signs = []
    for p in paths:
        with warnings.catch_warnings():         # the whole board: no larger lattice seen
            warnings.simplefilter("error", bc.BayescalWarning)
            view = bc.find_chessboard(p, board=(8, 6), square=42.0)
        assert view is not None, p.name
        assert view.n_corners == 48 and view.image_size == (1280, 1024) and view.name == p.name
        g = view.pixels.reshape(6, 8, 2)
        a, b = g[0, 1] - g[0, 0], g[1, 0] - g[0, 0]
        signs.append(np.sign(a[0] * b[1] - a[1] * b[0]))
        # the fixed order: the first row is the one farther from the image centre
        r = np.linalg.norm(g - CENTRE, axis=-1).mean(axis=1)
        assert r[0] > r[-1]
    assert len(set(signs)) == 1      # one handedness: no view is mirrored


def test_another_image_size():
    # the same poses through an 800 x 600 camera (gamma scaled by 0.6): squares of 8-20 px
    cam = {**REAL_LIKE_CAMERA, "gamma_u": 190.7, "gamma_v": -190.8, "u0": 401.5, "v0": 298.2}
    img, truth = bc.render_board(cam, REAL_LIKE_POSES[3], image_size=(800, 600), rng=7)
    view = bc.find_chessboard(img)
    assert view.image_size == (800, 600)
    err = view.pixels - order_corners(truth.pixels, (8, 6), center=(399.5, 299.5))
    assert np.abs(err).max() < MAX_ERR and np.sqrt(np.mean(err ** 2)) < RMS_ERR


@pytest.mark.slow
def test_a_blurred_board_is_found_by_the_fallback():
    import cv2

    from bayescal.image.chessboard import _to_uint8

    # 2 px of lens blur on the thinnest board: findChessboardCorners gives up, the
    # sector-based detector finds it and cornerSubPix refines it. Blur this strong costs
    # accuracy (0.2 px rms measured); the bound checks the correspondence: a corner matched
    # to the wrong one would be off by the corner spacing, 8.5 px or more here.
    img, truth = bc.render_board(REAL_LIKE_CAMERA, REAL_LIKE_POSES[1], psf_px=2.0, rng=1)
    assert not cv2.findChessboardCorners(_to_uint8(img.astype(float)), (8, 6), flags=3)[0]
    view = bc.find_chessboard(img)
    err = view.pixels - order_corners(truth.pixels, (8, 6), center=CENTRE)
    assert np.abs(err).max() < 2.0


def _part(truth, rows, cols, board=(8, 6)):
    """The view of some rows and columns of a whole board's corners, labelled as a board of
    their own (what OpenCV gives for a board option smaller than the board)."""
    g = order_corners(truth.pixels, board, center=CENTRE).reshape(board[1], board[0], 2)
    sub = g[np.ix_(rows, cols)]
    return bc.BoardView(sub.reshape(-1, 2), bc.board_points((len(cols), len(rows)), 42.0))


@pytest.mark.parametrize("k", [0, 1])
def test_the_extent_of_a_whole_board_is_its_size(rendered, k):
    img, truth = rendered[k]
    assert board_extent(img, _part(truth, range(6), range(8))) == (8, 6)


def test_the_extent_of_other_boards_and_sizes():
    img, truth = bc.render_board(REAL_LIKE_CAMERA, REAL_LIKE_POSES[2], board=(10, 7), rng=2)
    assert board_extent(img, _part(truth, range(7), range(10), (10, 7))) == (10, 7)
    cam = {**REAL_LIKE_CAMERA, "gamma_u": 190.7, "gamma_v": -190.8, "u0": 401.5, "v0": 298.2}
    img, truth = bc.render_board(cam, REAL_LIKE_POSES[3], image_size=(800, 600), rng=7)
    g = order_corners(truth.pixels, (8, 6), center=(399.5, 299.5))
    assert board_extent(img, bc.BoardView(g, bc.board_points((8, 6), 42.0))) == (8, 6)


@pytest.mark.parametrize("rows, cols", [
    ([0, 2, 4], range(8)),             # every other row: OpenCV's answer to a smaller board
    (range(6), [1, 3, 5, 7]),          # every other column
    (range(1, 5), range(1, 7)),        # a smaller board inside
    (range(0, 4), range(2, 8)),        # ... at a corner of it
    ([0, 3], range(8)),                # every third row
])
def test_the_extent_of_part_of_a_board_is_the_whole(rendered, rows, cols):
    img, truth = rendered[0]
    assert board_extent(img, _part(truth, rows, cols)) == (8, 6)


def test_a_smaller_board_option_warns_with_the_size_seen(rendered):
    img, _ = rendered[1]
    with pytest.warns(bc.BayescalWarning, match=r"goes on past the 6x4 .* 6x8 seen; pass "
                                                r"board=\(6, 8\)"):
        view = bc.find_chessboard(img, board=(6, 4), method="sb")
    assert view.n_corners == 24


@pytest.mark.skipif(not REAL.is_dir(), reason="../shared/data/para is absent")
def test_a_smaller_board_option_on_a_real_view():
    # OpenCV finds a 6x4 lattice on the real 8x6 board: every other row of it
    view = bc.find_chessboard(REAL / "img_para_002.pgm", board=(6, 4), method="sb",
                              check_extent=False)
    assert board_extent(REAL / "img_para_002.pgm", view) == (6, 8)


def test_a_none_from_find_chessboard_is_named_in_the_views():
    views, _ = bc.simulate_views(n_views=2, rng=0)
    with pytest.raises(TypeError, match=r"views\[1\] is NoneType, not a BoardView \(find_"
                                        r"chessboard returns None for an image where it finds "
                                        r"no whole board: leave that image out\); 2 of the 4 "
                                        r"views are not: indices 1, 3"):
        bc.calibrate_camera([views[0], None, views[1], None])
