import numpy as np
import pytest

import bayescal as bc


def test_board_points_in_opencv_order():
    pts = bc.board_points((8, 6), 42.0)
    assert pts.shape == (48, 3)
    np.testing.assert_allclose(pts[1], [42.0, 0, 0])
    np.testing.assert_allclose(pts[8], [0, 42.0, 0])
    with pytest.raises(ValueError, match="square"):
        bc.board_points((8, 6), -1)


def test_board_view_checks_and_subsets():
    pts = bc.board_points((3, 2), 10.0)
    px = pts[:, :2] + 100.0
    v = bc.BoardView(px, pts, name="a.png", image_size=(640, 480))
    assert v.n_corners == 6
    s = v.subset([0, 2, 4, 5])
    assert s.n_corners == 4 and s.name == "a.png"
    with pytest.raises(ValueError, match="a.png.*same M"):
        bc.BoardView(px[:5], pts, name="a.png")
    with pytest.raises(ValueError, match="at least 4"):
        bc.BoardView(px[:3], pts[:3])
    with pytest.raises(ValueError, match="covariance"):
        bc.BoardView(px, pts, covariance=np.eye(2))
