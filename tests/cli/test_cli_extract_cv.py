"""``bayescal extract`` says whether its covariances match the ring's scatter: the line of
``bc.ring_cross_validation``, printed and written into ``laser.csv``'s header, which
``calibrate`` reads past."""

import numpy as np
import pytest

import bayescal as bc
from bayescal.cli.main import main
from bayescal.io.data import load_pixels

iio = pytest.importorskip("imageio.v3")


def test_extract_prints_and_writes_the_cross_validation(tmp_path, capsys):
    p = bc.SensorParams.paper()
    img, _ = bc.render_image(p, bc.room_walls(2500), rng=4, bits=16)
    iio.imwrite(tmp_path / "on.png", img)
    assert main(["extract", str(tmp_path / "on.png"), "--out", str(tmp_path / "ex")]) == 0
    out = capsys.readouterr().out.splitlines()
    line = [ln for ln in out if ln.startswith("cross-validation: z rms")]
    assert len(line) == 1 and "held-out points" in line[0]
    z = float(line[0].split("z rms ")[1].split()[0])
    assert 0.5 < z < 2.0 and np.isfinite(z)
    header = [ln for ln in open(tmp_path / "ex" / "laser.csv") if ln.startswith("#")]
    assert any(line[0] in h for h in header)
    px, _ = load_pixels(tmp_path / "ex" / "laser.csv")         # the header stays readable
    assert px.shape[1] == 2 and len(px) > 300
