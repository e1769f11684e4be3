"""Files written by an older bayescal (before the package was split into subpackages) still
load, with the same numbers: ``tests/data/legacy/README.md`` says where they come from."""

import pathlib

import numpy as np
import pytest

import bayescal as bc

DATA = pathlib.Path(__file__).resolve().parents[1] / "data" / "legacy"


@pytest.fixture(scope="module")
def expected():
    with np.load(DATA / "expected.npz") as f:
        return dict(f)


@pytest.mark.parametrize("name", ["points", "plan"])
def test_old_result_files_load(name, expected):
    r = bc.load_result(DATA / f"result_{name}.json")
    np.testing.assert_array_equal(r.params.to_array(), expected[f"result_{name}_params"])
    if name == "points":
        np.testing.assert_array_equal(r.covariance(), expected["result_points_cov"])
    mean, cov = r.reconstruct(np.array([[480.0, 300.0], [400.0, 385.0]]))   # on the ring
    assert np.all(np.isfinite(mean)) and np.all(np.isfinite(cov))


@pytest.mark.parametrize("name", ["points", "plan"])
def test_old_posterior_files_load(name, expected):
    post = bc.load_posterior(DATA / f"posterior_{name}.npz")
    np.testing.assert_array_equal(post.param_samples.mean(0), expected[f"posterior_{name}_mean"])
    if name == "points":
        np.testing.assert_array_equal(post.covariance(), expected["posterior_points_cov"])
    else:
        assert post.wall_samples is not None and post.plan is not None
    mean, cov = post.reconstruct(post.pixels[:3])
    assert mean.shape == (3, 3) and cov.shape == (3, 3, 3)
