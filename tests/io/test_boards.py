"""Corner files: board views to CSV/NPZ and back, and located errors."""

import numpy as np
import pytest

import bayescal as bc
from bayescal.errors import InputError


def _views(rng, cov=False):
    pts = bc.board_points((4, 3), 30.0)
    out = []
    for k in range(3):
        px = rng.uniform(100, 900, size=(12, 2))
        c = None
        if cov:
            a = rng.uniform(0.01, 0.1, size=(12, 2))
            c = np.zeros((12, 2, 2))
            c[:, 0, 0], c[:, 1, 1], c[:, 0, 1] = a[:, 0], a[:, 1], 0.3 * np.sqrt(a.prod(1))
            c[:, 1, 0] = c[:, 0, 1]
        out.append(bc.BoardView(px, pts, c, name=f"img {k}.pgm", image_size=(1280, 1024)))
    return out[:2] + [out[2].subset(np.arange(7))]       # views need not be complete


@pytest.mark.parametrize("suffix", [".csv", ".npz"])
@pytest.mark.parametrize("cov", [False, True])
def test_round_trip(tmp_path, rng, suffix, cov):
    views = _views(rng, cov)
    path = bc.write_views(tmp_path / f"corners{suffix}", views)
    back = bc.load_views(path)
    assert [v.name for v in back] == [v.name for v in views]
    for a, b in zip(views, back, strict=True):
        np.testing.assert_array_equal(a.pixels, b.pixels)    # repr() keeps every bit
        np.testing.assert_array_equal(a.points, b.points)
        assert b.image_size == (1280, 1024)
        if cov:
            np.testing.assert_array_equal(a.covariance, b.covariance)
        else:
            assert b.covariance is None


def test_minimal_csv_without_comments(tmp_path):
    rows = ["view,u,v,x,y,z"] + [f"7,{i},{i * 2},{i},0,0" for i in range(5)]
    (tmp_path / "c.csv").write_text("\n".join(rows) + "\n")
    (view,) = bc.load_views(tmp_path / "c.csv")
    assert view.n_corners == 5 and view.name == "c.csv view 7" and view.image_size is None


@pytest.mark.parametrize("text, match", [
    ("view,u,v,x,y\n0,1,2,3,4\n", r"c\.csv, line 1: missing column\(s\) 'z'"),
    ("view,u,v,x,y,z\n0,1,2,3,4,5\n0.5,1,2,3,4,5\n", r"c\.csv, line 3, column 'view'.*integer"),
    ("view,u,v,x,y,z\n0,1,abc,3,4,5\n", r"line 2, column 'v'.*'abc'"),
    ("view,u,v,x,y,z\n" + "0,1,2,3,4,5\n" * 3, r"line 2, column 'view'.*at least 4 corners"),
    ("view,u,v,x,y,z,cov_uu,cov_uv,cov_vv\n" + "0,1,2,3,4,5,1,0,1\n" * 4
     + "0,1,2,3,4,5,1,2,1\n", r"line 6, column 'cov_uu'.*positive definite"),
])
def test_bad_csv_names_file_and_line(tmp_path, text, match):
    (tmp_path / "c.csv").write_text(text)
    with pytest.raises(InputError, match=match):
        bc.load_views(tmp_path / "c.csv")


def test_bad_npz_and_writer_arguments(tmp_path, rng):
    np.savez(tmp_path / "c.npz", view=np.zeros(5), pixels=np.ones((5, 2)))
    with pytest.raises(InputError, match=r"c\.npz: missing array\(s\) 'x'"):
        bc.load_views(tmp_path / "c.npz")
    np.savez(tmp_path / "d.npz", view=np.zeros(5), pixels=np.ones((5, 2)),
             points=np.ones((5, 3)), names=np.array(["a", "b"]))
    with pytest.raises(InputError, match="one row per view"):
        bc.load_views(tmp_path / "d.npz")
    with pytest.raises(InputError, match="no such file"):
        bc.load_views(tmp_path / "none.csv")
    with pytest.raises(TypeError, match="BoardView"):
        bc.write_views(tmp_path / "e.csv", [np.zeros((4, 2))])
