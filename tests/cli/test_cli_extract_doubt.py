"""``bayescal extract`` on an image with no plausible ring: exit 2, the reason and what to try
on stderr, nothing written (not even an empty output folder)."""

import numpy as np
import pytest

from bayescal.cli.main import main

iio = pytest.importorskip("imageio.v3")


@pytest.mark.parametrize("kind", ["noise", "checkerboard"])
def test_no_ring_exits_2_and_writes_nothing(tmp_path, capsys, kind):
    rng = np.random.default_rng(0)
    yy, xx = np.mgrid[0:300, 0:400]
    img = {"noise": rng.normal(100, 20, xx.shape),
           "checkerboard": ((xx // 30 + yy // 30) % 2) * 150.0 + 40 + rng.normal(0, 3, xx.shape)
           }[kind]
    iio.imwrite(tmp_path / "x.png", np.clip(img, 0, 255).astype(np.uint8))
    before = sorted(p.name for p in tmp_path.iterdir())
    code = main(["extract", str(tmp_path / "x.png"), "--out", str(tmp_path / "out" / "ex")])
    err = capsys.readouterr().err
    assert code == 2
    assert "no laser ring" in err or "no ring stands out" in err
    assert "--background" in err and "--center" in err and "--channel" in err
    assert "background=" not in err                      # the command's options, not Python's
    assert "Traceback" not in err
    assert sorted(p.name for p in tmp_path.iterdir()) == before
