"""params.csv: the parameter table of a run, with the laser pose of a misaligned fit."""

import csv

import numpy as np
import pytest

import bayescal as bc
from bayescal.constants import Z90
from bayescal.io.paramtable import pose_rows, write_params_csv


@pytest.fixture(scope="module")
def fits():
    ds = bc.simulate_room(range_mm=2500, n_points=80, n_walls=6, sigma_px=0.2,
                          approx_error=0.03, tilt=(0.01, -0.005), rng=1)
    return {m: bc.calibrate_simultaneous(ds.pixels, ds.approx_points, sigma_px=0.2,
                                         sigma_scene=ds.sigma_scene, model=m)
            for m in ("aligned", "misaligned")}


def test_pose_rows_of_a_least_squares_fit(fits):
    mis = fits["misaligned"]
    rows = pose_rows(mis)
    assert [r["name"] for r in rows] == list(bc.POSE_NAMES)
    assert [r["unit"] for r in rows] == ["rad", "rad", "mm", "mm"]
    sd = np.sqrt(np.diag(mis.covariance(identifiable=True))[7:])
    np.testing.assert_allclose([r["mean"] for r in rows], mis.laser.to_array(), rtol=1e-15)
    np.testing.assert_allclose([r["sd"] for r in rows], sd, rtol=1e-12)
    np.testing.assert_allclose([r["q95"] - r["q05"] for r in rows], 2 * Z90 * sd, rtol=1e-12)
    assert pose_rows(fits["aligned"]) == []


def test_params_csv_round_trip(fits, tmp_path):
    mis = fits["misaligned"]
    path = write_params_csv(tmp_path / "params.csv", mis.summary_rows(), pose_rows(mis),
                            model="misaligned")
    text = path.read_text()
    assert text.startswith("# bayescal calibrate: parameters, laser model misaligned")
    rows = list(csv.DictReader(t for t in text.splitlines() if not t.startswith("#")))
    assert [r["name"] for r in rows] == list(bc.PARAM_NAMES) + list(bc.POSE_NAMES)
    assert {r["name"]: r["unit"] for r in rows}["alpha_u"] == "px"
    got = np.array([float(r["value"]) for r in rows])
    np.testing.assert_array_equal(got[:8], mis.params.to_array())       # repr: exact
    np.testing.assert_array_equal(got[8:], mis.laser.to_array())
    al = fits["aligned"]
    text = write_params_csv(tmp_path / "a.csv", al.summary_rows(), [], model="aligned").read_text()
    assert "zero by assumption in the aligned model" in text
    assert len([t for t in text.splitlines() if not t.startswith("#")]) == 9
