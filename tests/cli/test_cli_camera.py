"""``bayescal calibrate-camera``: chessboard images (rendered, known truth) or a corners file
in; camera.json, corners.csv and a report out; a board-less image writes nothing."""

import json

import numpy as np
import pytest
from helpers import REAL_LIKE_CAMERA, REAL_LIKE_POSES, write_rendered_boards

import bayescal as bc
from bayescal.cli.main import main
from tests.cli.test_cli import run

pytest.importorskip("cv2")


@pytest.fixture(scope="module")
def boards(tmp_path_factory):
    root = tmp_path_factory.mktemp("camera")
    paths, truths = write_rendered_boards(root)
    return root, paths, truths


def test_images_to_camera_json_and_report(boards, capsys):
    root, paths, _ = boards
    out = root / "cam"
    code = main(["calibrate-camera", *map(str, paths), "--board", "8x6", "--square", "42",
                 "--noise", "per-view", "--no-cross-validation", "--out", str(out)])
    assert code == 0, capsys.readouterr().err
    cam = bc.load_camera(out / "camera.json")
    assert cam.view_names == [p.name for p in paths] and cam.image_size == (1280, 1024)
    # the rendered corners are exact to ~0.03 px: the fit lands on the truth within 5 of
    # its standard errors in each intrinsic (a 5-sd miss happens once in 3.5e6 per name)
    sd = cam.std()
    for name, value in cam.intrinsics.items():
        assert abs(value - REAL_LIKE_CAMERA[name]) < 5 * sd[name] + 1e-9, name
    views = bc.load_views(out / "corners.csv")
    assert [v.name for v in views] == cam.view_names and views[0].image_size == (1280, 1024)
    report = (out / "camera_report.md").read_text()
    assert "board_4.pgm" in report and "Cross-validation" not in report
    assert (out / "camera_report.html").stat().st_size > 1000
    for png in ("view_residuals.png", "image_residuals.png"):
        assert png in report and (out / png).stat().st_size > 5000


def test_corners_file_with_cross_validation(tmp_path, capsys):
    from bayescal.scene.boards import simulate_views

    views, _ = simulate_views(n_views=4, rng=5)
    bc.write_views(tmp_path / "c.npz", views)
    out = tmp_path / "cam"
    assert main(["calibrate-camera", "--corners", str(tmp_path / "c.npz"), "--noise", "plain",
                 "--out", str(out)]) == 0, capsys.readouterr().err
    assert "chi-square per direction" in capsys.readouterr().out
    report = (out / "camera_report.md").read_text()
    assert "## Cross-validation" in report and "0 1 / 2 3" in report
    assert "crossval.png" in report and (out / "crossval.png").stat().st_size > 5000
    assert json.loads((out / "camera.json").read_text())["format"] == "bayescal-camera"


def test_an_image_without_a_board_writes_nothing(boards, tmp_path):
    import imageio.v3 as iio

    root, paths, _ = boards
    blank = tmp_path / "empty.png"
    iio.imwrite(blank, np.full((512, 640), 90, np.uint8))
    r = run("calibrate-camera", paths[0], blank, paths[1], "--out", tmp_path / "cam",
            cwd=tmp_path)
    assert r.returncode == 2
    assert "empty.png: no 8x6 chessboard found" in r.stderr and "Traceback" not in r.stderr
    assert not (tmp_path / "cam").exists()


@pytest.mark.parametrize("args, match", [
    ((), "either IMAGE files or --corners"),
    (("--corners", "c.csv", "x.png"), "either IMAGE files or --corners"),
    (("x.png", "--board", "8"), "COLUMNSxROWS"),
    (("x.png", "--square", "-1"), "--square"),
    (("--corners", "bad.csv"), r"bad\.csv, line 2, column 'u'"),
    (("--corners", "one.csv"), "1 view"),
])
def test_bad_input_exits_2(tmp_path, capsys, args, match):
    (tmp_path / "x.png").write_bytes(b"")
    (tmp_path / "c.csv").write_text("view,u,v,x,y,z\n")
    (tmp_path / "bad.csv").write_text("view,u,v,x,y,z\n0,a,1,2,3,4\n")
    rows = "".join(f"0,{i},{i * i},{i},{i % 2},0\n" for i in range(6))
    (tmp_path / "one.csv").write_text("view,u,v,x,y,z\n" + rows)
    cwd = tmp_path
    argv = ["calibrate-camera", *[str(cwd / a) if a.endswith((".png", ".csv")) else a
                                  for a in args], "--out", str(tmp_path / "cam")]
    assert main(argv) == 2
    assert __import__("re").search(match, capsys.readouterr().err)
    assert not (tmp_path / "cam").exists()


def test_different_image_sizes_are_refused(boards, tmp_path, capsys):
    import imageio.v3 as iio

    root, paths, _ = boards
    small, _ = bc.render_board({**REAL_LIKE_CAMERA, "u0": 320.0, "v0": 260.0},
                               REAL_LIKE_POSES[0], image_size=(700, 560), rng=1)
    iio.imwrite(tmp_path / "small.png", small)
    assert main(["calibrate-camera", str(paths[0]), str(tmp_path / "small.png"),
                 "--out", str(tmp_path / "cam")]) == 2
    assert "small.png is 700x560 px but" in capsys.readouterr().err


def test_a_view_with_wrong_corners_fails_with_the_files_kept(tmp_path, capsys):
    from bayescal.scene.boards import simulate_views

    views, _ = simulate_views(n_views=4, rng=5)
    rng = np.random.default_rng(0)
    bad = bc.BoardView(views[2].pixels[rng.permutation(48)], views[2].points, name="shuffled")
    bc.write_views(tmp_path / "c.csv", [views[0], views[1], bad, views[3]])
    out = tmp_path / "cam"
    assert main(["calibrate-camera", "--corners", str(tmp_path / "c.csv"), "--noise", "plain",
                 "--no-cross-validation", "--out", str(out)]) == 1
    assert "view(s) shuffled fit over 3x worse" in capsys.readouterr().err
    assert (out / "camera.json").is_file() and "SUSPECT" in (out / "camera_report.md").read_text()


def _rows_of(truth, rows, name):
    """Some rows of a rendered board's true corners, labelled as a board of their own."""
    from bayescal.image.chessboard import order_corners

    g = order_corners(truth.pixels, (8, 6), center=(639.5, 511.5)).reshape(6, 8, 2)[rows]
    return bc.BoardView(g.reshape(-1, 2), bc.board_points((8, len(rows)), 42.0), name=name,
                        image_size=(1280, 1024))


def test_a_board_option_smaller_than_the_board_is_refused(boards, tmp_path, capsys,
                                                          monkeypatch):
    # what OpenCV finds for --board 8x3 on an 8x6 board: every other row, or three rows of
    # it (detection itself is replaced by the true corners, to keep this test fast; the
    # lattice test reads the images)
    root, paths, truths = boards
    by_name = {p.name: t for p, t in zip(paths, truths, strict=True)}
    parts = {"board_0.pgm": [0, 2, 4], "board_1.pgm": [1, 3, 5], "board_2.pgm": [0, 1, 2],
             "board_3.pgm": [3, 4, 5], "board_4.pgm": [0, 2, 4]}

    def find(path, board, **kw):
        return _rows_of(by_name[path.name], parts[path.name], path.name)

    monkeypatch.setattr(bc, "find_chessboard", find)
    assert main(["calibrate-camera", *map(str, paths), "--board", "8x3",
                 "--out", str(tmp_path / "cam")]) == 2
    err = capsys.readouterr().err
    assert "--board 8x3: the chessboard goes on past the corners found in 5 of 5 images" in err
    assert "8x6 inner corners seen; expected --board 8x6" in err
    assert not (tmp_path / "cam").exists()


def test_a_view_or_two_of_a_larger_lattice_only_warn(recwarn):
    from bayescal.cli.camera import _check_extent

    _check_extent(["a.pgm", "b.pgm", "c.pgm"], (8, 6), [(8, 6), (8, 7), (8, 6)])
    assert "b.pgm: the chessboard seems to go on past the 8x6 corners found (8x7 seen)" in \
        str(recwarn.pop().message)
    with pytest.raises(bc.BayescalError, match="in 2 of 3 images .* 10x6 inner corners seen"):
        _check_extent(["a.pgm", "b.pgm", "c.pgm"], (8, 6), [(10, 6), (8, 6), (10, 6)])


def test_a_fit_that_does_not_determine_the_camera_is_no_success(tmp_path, capsys):
    from bayescal.scene.boards import simulate_views

    # every other row of each view taken for the next: the default noise model then
    # leaves xi and gamma_v with an sd above their value (seed 0, four views)
    views, _ = simulate_views(n_views=4, rng=0)
    parts = [bc.BoardView(v.pixels.reshape(6, 8, 2)[[0, 2, 4]].reshape(-1, 2),
                          bc.board_points((8, 3), 42.0), name=v.name) for v in views]
    bc.write_views(tmp_path / "c.csv", parts)
    out = tmp_path / "cam"
    assert main(["calibrate-camera", "--corners", str(tmp_path / "c.csv"),
                 "--no-cross-validation", "--out", str(out)]) == 1
    cap = capsys.readouterr()
    assert "failed: the views do not determine xi, gamma_v (sd >= |value|)" in cap.err
    assert "xi" in cap.out and "NOT IDENTIFIED (sd >= |value|)" in cap.out
    report = (out / "camera_report.md").read_text()
    assert "The views do not determine xi, gamma_v" in report and "**no** (sd >= value)" in report
