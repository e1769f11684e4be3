"""``bayescal extract`` over frames: several images, a folder; a laser file per frame and
frames.csv; refused frames flagged; bad input and Ctrl-C leave nothing behind."""

import numpy as np
import pytest

import bayescal as bc
from bayescal.cli.main import main

iio = pytest.importorskip("imageio.v3")

#: a 400x300 camera (the paper's sensor scaled: ring radius ~100 px)
P = bc.SensorParams(**{**bc.SensorParams.paper().as_dict(), "alpha_u": 60.0,
                       "alpha_v": -60.0, "u0": 200.0, "v0": 150.0})


@pytest.fixture(scope="module")
def seq(tmp_path_factory):
    """A folder of three frames of a moving sensor and a frame without a ring."""
    root = tmp_path_factory.mktemp("frames")
    (root / "seq").mkdir()
    frames = [im for im, _ in bc.render_sequence(P, bc.room_walls(2500), 3, shape=(300, 400),
                                                 rng=0)]
    noise = np.random.default_rng(1).integers(0, 40, (300, 400)).astype(np.uint8)
    for name, f in zip(("a0", "a1", "a2", "a3"), (frames[0], frames[1], noise, frames[2]),
                       strict=True):
        iio.imwrite(root / "seq" / f"{name}.png", f)
    return root


def _rows(path):
    lines = [ln for ln in path.read_text().splitlines() if not ln.startswith("#")]
    return lines[0].split(","), np.array([ln.split(",") for ln in lines[1:]], dtype=float)


def test_a_folder_gives_a_laser_file_per_frame(seq, monkeypatch, capsys):
    monkeypatch.chdir(seq)
    assert main(["extract", "seq", "--out", "ex", "--no-progress"]) == 0
    err = capsys.readouterr().err
    assert "frame a2 refused" in err
    assert sorted(p.name for p in (seq / "ex" / "laser").iterdir()) == \
        ["a0.csv", "a1.csv", "a3.csv"]
    head, rows = _rows(seq / "ex" / "frames.csv")
    assert head[:4] == ["frame", "tracked", "refused", "points"]
    assert rows[:, 1].tolist() == [0, 1, 0, 0] and rows[:, 2].tolist() == [0, 0, 1, 0]
    notes = (seq / "ex" / "frames.csv").read_text()
    assert "frame 2: a2 -> refused: " in notes and "(first frame)" in notes
    # each file holds what bc.track_laser returns for that frame, as laser.csv holds it
    want = bc.track_laser(seq / "seq")
    head, a1 = _rows(seq / "ex" / "laser" / "a1.csv")
    assert head == ["u", "v", "cov_uu", "cov_uv", "cov_vv", "snr", "flagged"]
    np.testing.assert_allclose(a1[:, :2], want[1].pixels, rtol=0, atol=1e-9)
    text = (seq / "ex" / "laser" / "a1.csv").read_text()
    assert "# image_size: 400x300" in text and "followed from the last frame" in text


def test_several_images_and_a_progress_bar(seq, monkeypatch, capsys):
    monkeypatch.chdir(seq)
    assert main(["extract", "seq/a0.png", "seq/a1.png", "--out", "two"]) == 0
    err = capsys.readouterr().err
    assert "2/2" in err and "followed=1" in err           # tqdm's bar on stderr
    assert (seq / "two" / "laser" / "a1.csv").exists()


@pytest.mark.parametrize("args, match", [
    (["seq/a0.png", "seq/missing.png"], "no such file or folder"),
    (["seq/a2.png", "seq/a2.png"], "share a name"),
    (["seq/a2.png", "seq/a2.png", "seq"], "must all be image files"),
    (["seq/a0.png", "small/s.png"], "size"),
    (["empty"], "holds no image"),
    (["seq/a2.png", "seq/a0.png", "--channel", "2", "--radius", "5", "4"], "LOW < HIGH"),
])
def test_bad_input_exit_2_nothing_written(seq, monkeypatch, capsys, args, match):
    monkeypatch.chdir(seq)
    (seq / "small").mkdir(exist_ok=True)
    (seq / "empty").mkdir(exist_ok=True)
    iio.imwrite(seq / "small" / "s.png", np.zeros((100, 120), np.uint8))
    assert main(["extract", *args, "--out", "bad", "--no-progress"]) == 2
    assert match in capsys.readouterr().err
    assert not (seq / "bad").exists()


def test_every_frame_refused_is_bad_input(seq, monkeypatch, capsys, tmp_path):
    monkeypatch.chdir(tmp_path)
    noise = iio.imread(seq / "seq" / "a2.png")
    for k in range(2):
        iio.imwrite(tmp_path / f"n{k}.png", noise)
    assert main(["extract", "n0.png", "n1.png", "--out", "bad", "--no-progress"]) == 2
    assert "no frame has a plausible laser ring" in capsys.readouterr().err
    assert not (tmp_path / "bad").exists()


def test_interrupted_leaves_nothing(seq, monkeypatch, capsys):
    from bayescal.image.track import LaserTracker

    calls = []
    real = LaserTracker.__call__

    def stop_at_the_second(self, *a, **k):
        calls.append(1)
        if len(calls) == 2:
            raise KeyboardInterrupt
        return real(self, *a, **k)

    monkeypatch.setattr(LaserTracker, "__call__", stop_at_the_second)
    monkeypatch.chdir(seq)
    assert main(["extract", "seq", "--out", "stopped", "--no-progress"]) == 130
    assert "nothing was written" in capsys.readouterr().err
    assert not (seq / "stopped").exists()
    assert not list(seq.glob(".stopped*"))


@pytest.mark.slow
def test_frames_then_reconstruct(tmp_path, monkeypatch):
    """The laser files of the frames, reconstructed with a calibration run (7-10 s: the
    calibration)."""
    import json

    monkeypatch.chdir(tmp_path)
    assert main(["simulate", "--n-points", "60", "--range-mm", "2500", "--out", "sim"]) == 0
    assert main(["calibrate", "sim/laser.csv", "--out", "cal", "--no-progress"]) == 0
    p = bc.SensorParams(**json.loads((tmp_path / "sim" / "truth.json").read_text())["params"])
    (tmp_path / "seq").mkdir()
    for i, (im, _) in enumerate(bc.render_sequence(p, bc.room_walls(2500), 3, rng=0)):
        iio.imwrite(tmp_path / "seq" / f"f{i}.png", im)
    assert main(["extract", "seq", "--out", "ex", "--no-progress"]) == 0
    files = sorted(str(f) for f in (tmp_path / "ex" / "laser").iterdir())
    assert len(files) == 3
    assert main(["reconstruct", *files, "--run", "cal", "--out", "rec"]) == 0
    _, rows = _rows(tmp_path / "rec" / "frames.csv")
    assert len(rows) == 3 and np.all(rows[:, 1] > 300)
