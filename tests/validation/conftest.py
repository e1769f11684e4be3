"""The shared real views (../shared/data/para relative to the repository, or the folder
in ``BAYESCAL_PARA_DIR``), read with OpenCV's detector; tests using them skip when the
folder or OpenCV is absent."""

import os
import pathlib

import pytest

import bayescal as bc

PARA = pathlib.Path(os.environ.get("BAYESCAL_PARA_DIR") or
                    pathlib.Path(__file__).resolve().parents[2].parent / "shared" / "data" / "para")


@pytest.fixture(scope="session")
def para_views():
    """The five real paracatadioptric views: 8 x 6 corners of 42 mm each."""
    if not PARA.is_dir():
        pytest.skip(f"real views not found at {PARA}")
    cv2 = pytest.importorskip("cv2")
    pts = bc.board_points((8, 6), 42.0)
    views = []
    for path in sorted(PARA.glob("*.pgm")):
        im = cv2.imread(str(path), cv2.IMREAD_GRAYSCALE)
        ok, c = cv2.findChessboardCorners(im, (8, 6))
        assert ok, path.name
        # a 11 x 11 px search window: wider ones pull corners of the smallest boards
        # (8 px apart) onto their neighbours
        c = cv2.cornerSubPix(im, c, (5, 5), (-1, -1),
                             (cv2.TERM_CRITERIA_EPS + cv2.TERM_CRITERIA_MAX_ITER, 100, 1e-4))
        views.append(bc.BoardView(c.reshape(-1, 2).astype(float), pts, name=path.name,
                                  image_size=(im.shape[1], im.shape[0])))
    return views
