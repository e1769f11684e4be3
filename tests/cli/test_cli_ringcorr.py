"""``calibrate --walls --ring-corr DEG``: pixel errors correlated along the ring
(docs/floorplan.md, "Errors correlated along the ring"); in process, small."""

import numpy as np
import pytest

import bayescal as bc
from bayescal.cli.main import main


@pytest.fixture(scope="module")
def sim(tmp_path_factory):
    root = tmp_path_factory.mktemp("ringcorr")
    assert main(["simulate", "--out", str(root / "sim"), "--n-points", "60", "--seed", "4"]) == 0
    return root / "sim"


@pytest.mark.slow          # two calibrate runs with their reports: ~40 s
def test_ring_corr_widens_u0_v0_and_keeps_the_fit(sim, tmp_path):
    runs = {}
    for name, extra in (("plain", []), ("corr", ["--ring-corr", "3"])):
        out = tmp_path / name
        assert main(["calibrate", str(sim / "laser.csv"), "--walls", str(sim / "walls.csv"),
                     "--out", str(out), *extra]) == 0
        runs[name] = bc.load_result(out / "result.json")
    p, c = runs["plain"], runs["corr"]
    np.testing.assert_allclose(c.params.to_array(), p.params.to_array(), rtol=1e-9)
    cp, cc = p.covariance_identifiable, c.covariance_identifiable
    assert cc[3, 3] > cp[3, 3] and cc[4, 4] > cp[4, 4]


@pytest.mark.parametrize("extra, match", [
    (["--ring-corr", "2"], "--ring-corr needs --walls"),
    (["--walls", "WALLS", "--method", "bayes", "--ring-corr", "2"],
     "--ring-corr needs --walls and --method simultaneous"),
    (["--walls", "WALLS", "--ring-corr", "-1"], "--ring-corr"),
])
def test_ring_corr_misuse_exits_2_nothing_written(sim, tmp_path, capsys, extra, match):
    out = tmp_path / "bad"
    args = [str(sim / "walls.csv") if a == "WALLS" else a for a in extra]
    rc = main(["calibrate", str(sim / "laser.csv"), "--out", str(out), *args])
    err = capsys.readouterr().err
    assert rc == 2 and match in err and len(err.strip().splitlines()) == 1, err
    assert not out.exists()
