"""The third renderer (tests/image/renderer3.py) and the user's command chain on its images.

Cheap tests (default suite): the renderer's geometry and light are sane, the scorer scores
known errors as it says, and the command line on one of its images (``extract`` on a
textured room, exit 2 on an image without a ring). The chain ``bayescal extract`` ->
``bayescal calibrate --walls`` per scenario with the issue's targets is slow (20-40 s per
image on a shared 2-core machine); where a target is missed the test is a strict xfail
with the measured numbers.
"""
import json
import sys
from pathlib import Path

import numpy as np
import pytest

sys.path.insert(0, str(Path(__file__).parent))
import renderer3 as r3  # noqa: E402

import bayescal as bc  # noqa: E402
from bayescal.cli.main import main  # noqa: E402


@pytest.fixture(scope="module")
def textured():
    return r3.render3("textured", 0)


def test_truth_ring_lies_on_the_cone_and_projects(textured):
    img, off, truth = textured
    p = truth.params
    assert img.shape == (600, 800) and img.dtype == np.uint8 and off is None
    vis = truth.visible
    pts = truth.points[vis]
    rho = np.hypot(pts[:, 0], pts[:, 1])
    # on the cone: z = rho / tan(beta) - h (conventions.md), to rounding
    np.testing.assert_allclose(pts[:, 2], rho / np.tan(p.beta) - p.h, atol=1e-6)
    np.testing.assert_allclose(truth.pixels[vis], bc.project(p, pts), atol=1e-9)
    radius = np.hypot(truth.pixels[vis, 0] - p.u0, truth.pixels[vis, 1] - p.v0)
    # a 2500-mm room: the ring at 80-100 px from the principal point (|gamma| ~55 px)
    assert 75 < radius.min() and radius.max() < 105
    # the doorway leaves a gap of 5-40 degrees; nothing else hides the ring here
    assert 0.88 < vis.mean() < 0.99


def test_the_laser_is_brighter_on_the_true_ring(textured):
    img, _, truth = textured
    from scipy import ndimage

    p = truth.params
    vis = truth.visible & ~truth.hidden
    q = truth.pixels[vis]
    out = (q - [p.u0, p.v0]) / np.hypot(*(q - [p.u0, p.v0]).T)[:, None]
    on = ndimage.map_coordinates(img.astype(float), [q[:, 1], q[:, 0]], order=1)
    off = ndimage.map_coordinates(img.astype(float), [(q + 4 * out)[:, 1], (q + 4 * out)[:, 0]],
                                  order=1)
    # the stripe (90/255 of the full well, gamma 2.2 on top of the wall) stands out by
    # 30-80 grey levels; 20 is far below any rendering and far above texture alone (~0)
    assert np.median(on - off) > 20


def test_score_of_known_errors(textured):
    _, _, truth = textured
    p = truth.params
    vis = truth.visible
    q = truth.pixels[vis][::7]
    c = np.array([p.u0, p.v0])
    radial = (q - c) / np.linalg.norm(q - c, axis=1, keepdims=True)
    cov = np.tile(np.diag([0.04, 0.04]), (len(q), 1, 1))  # sd 0.2 px
    zero = r3.score3(q, cov, np.zeros(len(q), bool), truth)
    assert abs(zero["bias"]) < 1e-6 and zero["gross"] == 0 and zero["robust_sd"] < 1e-6
    shift = r3.score3(q + 0.3 * radial, cov, np.zeros(len(q), bool), truth)
    # a radial shift of 0.3 px is 0.3 cos(angle to the normal) >= 0.29 px along it
    assert 0.29 < shift["bias"] <= 0.3 + 1e-9 and shift["gross"] == 0
    assert 1.45 < shift["z_rms"] <= 1.5 + 1e-9
    assert shift["kept"] > 0.95
    far = r3.score3(q + 1.5 * radial, cov, np.zeros(len(q), bool), truth)
    assert far["gross"] == 1.0
    flagged = r3.score3(q, cov, np.arange(len(q)) % 2 == 0, truth)
    assert flagged["n_flagged"] == (len(q) + 1) // 2


def test_extract_command_on_a_textured_room(textured, tmp_path, capsys):
    # the command line in this process (the shell's subprocess chain is in the slow tests)
    img, off, truth = textured
    path, _, _ = r3.write_inputs(tmp_path, img, off, truth)
    rc = main(["extract", str(path), "--along-sd", "1", "--out", str(tmp_path / "ex")])
    assert rc == 0, capsys.readouterr().err
    pix, cov, flagged, size = r3.read_laser_csv(tmp_path / "ex" / "laser.csv")
    assert size == (800, 600)
    s = r3.score3(pix, cov, flagged, truth)
    # measured on this image (seed 0): kept 0.94, robust sd 0.16, bias -0.011, gross 0.6 %,
    # z rms 1.06; the targets of the issue:
    assert s["kept"] >= 0.90 and s["robust_sd"] <= 0.25 and abs(s["bias"]) <= 0.1
    assert s["gross"] <= 0.02 and 0.7 <= s["z_rms"] <= 1.4


def test_no_ring_exits_2_and_writes_nothing(tmp_path, capsys):
    img, off, truth = r3.render3("noring", 0)
    path, _, _ = r3.write_inputs(tmp_path, img, off, truth)
    rc = main(["extract", str(path), "--out", str(tmp_path / "ex")])
    out, err = capsys.readouterr()
    assert rc == 2, (out, err)
    assert "Traceback" not in err and err.count("bayescal: error:") == 1
    assert not (tmp_path / "ex").exists()


# ----------------------------------------------------------------- the chain, per scenario

#: (scenario, seed) -> why the chain misses a target there (a strict xfail), measured on
#: this branch with the extractor as it is (docs/images.md, "A third renderer")
#: (red-1 and red-2 met every target once a demosaiced colour channel was smoothed (red-2
#: misses again, below),
#: furniture-0 once the floor-plan fit set a block in front of a wall aside; they stay below
#: as regression cases)
KNOWN = {("red", 2): "u0 3.8 sds off (2.9 before the ring was measured on its own "
                    "circle's profiles): the principal point's sds are too small on the Bayer "
                    "images without a laser-off frame, errors correlated along the ring "
                    "(docs/images.md, 'A third renderer'; seeds 0-10: u0, v0 z rms 1.6, 1.7)"}

#: the calibrated identifiable parameters against the truth: |z| < 3.5 for all seven has a
#: false-failure rate of about 0.3 % per image when the sds are honest (7 x 4.7e-4)
PARAM_Z = 3.5


def _targets(res):
    """The issue's targets on one chain result; the list of those missed."""
    miss = []
    if res["extract_rc"] != 0:
        return [f"extract exit {res['extract_rc']}: {res['extract_out'][-200:]}"]
    sd_max = 0.35 if res["scenario"] == "faint" else 0.25
    for name, ok in (("kept", res["kept"] >= 0.90), ("robust_sd", res["robust_sd"] <= sd_max),
                     ("bias", abs(res["bias"]) <= 0.1), ("gross", res["gross"] <= 0.02),
                     ("z_rms", 0.7 <= res["z_rms"] <= 1.4)):
        if not ok:
            miss.append(f"{name} {res[name]:.3f}")
    if res.get("calibrate_rc") != 0:
        miss.append(f"calibrate exit {res.get('calibrate_rc')}: "
                    f"{res.get('calibrate_err', '')[-200:]}")
    elif res["max_abs_z"] > PARAM_Z:
        miss.append(f"parameters {json.dumps(res['param_z'])}")
    return miss


def _case(name, seed):
    marks = [pytest.mark.slow]
    if (name, seed) in KNOWN:
        marks.append(pytest.mark.xfail(strict=True, reason=KNOWN[(name, seed)]))
    return pytest.param(name, seed, marks=marks, id=f"{name}-{seed}")


@pytest.mark.parametrize("name, seed", [_case(n, 0) for n in ("textured", "lamps", "faint",
                                                               "red", "cam1280", "furniture")]
                         # the mirror's bright rim was taken for the ring (exit 2) here
                         + [_case("lamps", 1), _case("bright", 2)]
                         # the Bayer image's robust sd was 0.257-0.260 px here, before its
                         # demosaiced channel was smoothed
                         + [_case("red", 1), _case("red", 2)]
                         + [_case(*k) for k in KNOWN
                            if k[1] != 0 and k not in {("lamps", 1), ("bright", 2), ("red", 1),
                                                       ("red", 2)}])
def test_chain_meets_targets(name, seed, tmp_path):
    # the user's chain from the shell: extract (laser-off frame where the scenario has one,
    # --along-sd 1), then calibrate --walls on its laser.csv as it is
    res = r3.run_chain(name, seed, tmp_path)
    miss = _targets(res)
    assert not miss, miss


@pytest.mark.slow
@pytest.mark.parametrize("seed", [0, 1, 2])
def test_chain_no_ring_exits_2(seed, tmp_path):
    res = r3.run_chain("noring", seed, tmp_path)
    assert res["extract_rc"] == 2, res
    assert not (tmp_path / "ex").exists()
