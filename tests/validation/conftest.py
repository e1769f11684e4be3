"""The shared real views (../shared/data/para relative to the repository, or the folder
in ``BAYESCAL_PARA_DIR``), read with bc.find_chessboard (OpenCV's detector); tests using
them skip when the folder or OpenCV is absent."""

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
    pytest.importorskip("cv2")
    views = [bc.find_chessboard(path, board=(8, 6), square=42.0)
             for path in sorted(PARA.glob("*.pgm"))]
    assert all(v is not None for v in views)
    return views
