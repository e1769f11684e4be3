"""``bayescal extract --radius LOW HIGH``: the ring's radius bounded from the shell."""

import numpy as np
import pytest

import bayescal as bc
from bayescal.cli.main import main

iio = pytest.importorskip("imageio.v3")


@pytest.fixture(scope="module")
def image(tmp_path_factory):
    root = tmp_path_factory.mktemp("radius")
    p = bc.SensorParams.paper()
    img, truth = bc.render_image(p, bc.room_walls(2500), rng=4, bits=16)
    iio.imwrite(root / "on.png", img)
    r = np.hypot(truth.pixels[:, 0] - p.u0, truth.pixels[:, 1] - p.v0)
    return root, r


def test_radius_bounds_the_ring(image, capsys):
    root, r_true = image
    assert 80 < r_true.min() and r_true.max() < 100     # the 2500-mm ring of the paper's sensor
    assert main(["extract", str(root / "on.png"), "--radius", "60", "130",
                 "--out", str(root / "ex")]) == 0
    out = capsys.readouterr().out
    assert "nan" not in out and "median sd across the ring" in out
    a = np.loadtxt([ln for ln in open(root / "ex" / "laser.csv") if not ln.startswith("#")][1:],
                   delimiter=",")
    p = bc.SensorParams.paper()
    r = np.hypot(a[a[:, 6] == 0, 0] - p.u0, a[a[:, 6] == 0, 1] - p.v0)
    assert len(r) > 200 and np.all((r > 60) & (r < 130))


@pytest.mark.parametrize("low, high, match", [("130", "60", "expected LOW < HIGH"),
                                              ("-1", "60", "--radius"),
                                              ("200", "260", "--radius")])
def test_bad_or_empty_radius_exit_2_nothing_written(image, capsys, low, high, match):
    # (200, 260) px holds no ring: the extractor's self-doubt, exit 2, and the advice names
    # --radius among what to try
    root, _ = image
    out = root / f"bad_{low}_{high}"
    assert main(["extract", str(root / "on.png"), "--radius", low, high, "--out", str(out)]) == 2
    err = capsys.readouterr().err
    assert match in err and err.count("\n") == 1 and "Traceback" not in err
    assert not out.exists()
