"""``bayescal calibrate laser.csv --camera DIR``: the laser stage on a camera calibrated
beforehand, a 1280x1024 camera's pixels accepted, a bad camera file refused."""

import json

import numpy as np
import pytest

import bayescal as bc
from bayescal.cli.main import main
from bayescal.io.data import write_laser_csv
from bayescal.results.camera import CameraResult

#: a 1280x1024 paracatadioptric camera (the shared real one's values)
K = np.array([1.134, 317.8, -318.0, 642.5, 522.9])
COV = np.diag([0.003, 2.0, 2.0, 1.0, 1.0]) ** 2


@pytest.fixture(scope="module")
def files(tmp_path_factory):
    tmp = tmp_path_factory.mktemp("camlaser")
    cam = CameraResult(K, COV, np.zeros((1, 6)), [np.zeros((4, 2))], ["sim_00"],
                       noise="plain", sigma=[0.3], tau=0.0, image_size=(1280, 1024))
    (tmp / "cam").mkdir()
    cam.save(tmp / "cam" / "camera.json")
    sensor = bc.SensorParams.from_identifiable(np.r_[K, 200.0, np.pi / 3], 0.0)
    ds = bc.simulate_room(sensor, range_mm=2500, n_points=80, sigma_px=0.3,
                          approx_error=0.03, rng=2)
    write_laser_csv(tmp / "laser.csv", ds.pixels, ds.approx_points,
                    sigma_scene=ds.sigma_scene, sigma_px=0.3)
    return tmp, ds


def test_calibrate_on_a_camera_folder_takes_its_size_and_prior(files, capsys):
    tmp, ds = files
    assert ds.pixels[:, 0].max() > 1000          # beyond the paper's 800 x 600 sensor
    code = main(["calibrate", str(tmp / "laser.csv"), "--camera", str(tmp / "cam"),
                 "--out", str(tmp / "out"), "--no-progress"])
    assert code == 0, capsys.readouterr().err
    res = bc.load_result(tmp / "out" / "result.json")
    th = res.params.to_identifiable()
    c7 = res.covariance(identifiable=True)
    # the camera's prior (sds 2 px) and the room: the centre near the truth, h and beta too
    z = (th - np.r_[K, 200.0, np.pi / 3]) / np.sqrt(np.diag(c7))
    assert np.all(np.abs(z) < 4), z
    assert np.all(np.diag(c7)[:5] < np.diag(COV))            # the laser data refine it
    run = json.loads((tmp / "out" / "run.json").read_text())
    assert "camera" in json.dumps(run)


def test_the_camera_file_or_its_folder_give_the_nominal_prior_and_image_size(files):
    from bayescal.cli.lasermodel import camera_setting

    tmp, _ = files
    nominal = bc.SensorParams.paper().replace(h=150.0)
    for path in (tmp / "cam", tmp / "cam" / "camera.json"):
        cam, nom, prior, size = camera_setting(path, nominal, [("h", bc.default_prior()["h"])])
        np.testing.assert_allclose(nom.to_identifiable(), np.r_[K, 150.0, np.pi / 3])
        assert size == (1280, 1024) and nom.phi == nominal.phi
        assert set(prior) == {"phi", "h", "beta"}
    np.testing.assert_allclose(bc.Prior(prior, camera=cam).camera[1], COV)


@pytest.mark.parametrize("what, words", [("missing", "no camera file"),
                                         ("garbage", "cannot read a camera result"),
                                         ("prior", "--prior u0=")])
def test_a_bad_camera_exits_2_naming_it_and_writes_nothing(files, capsys, what, words):
    tmp, _ = files
    args = ["calibrate", str(tmp / "laser.csv"), "--out", str(tmp / f"bad_{what}")]
    if what == "missing":
        args += ["--camera", str(tmp / "nowhere")]
    elif what == "garbage":
        bad = tmp / "garbage.json"
        bad.write_text("{not json")
        args += ["--camera", str(bad)]
    else:
        args += ["--camera", str(tmp / "cam"), "--prior", "u0=norm(640, 5)"]
    assert main(args) == 2
    err = capsys.readouterr().err
    assert words in err and err.count("\n") == 1 and "Traceback" not in err
    assert not (tmp / f"bad_{what}").exists()
