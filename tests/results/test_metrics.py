"""The paper's reconstruction error: known distances, broadcasting, NaN handling."""

import numpy as np
import pytest

import bayescal as bc


def test_known_distances():
    true = np.zeros((4, 3))
    rec = np.array([[3.0, 4.0, 0.0], [0.0, 0.0, -2.0], [1.0, 2.0, 2.0], [0.0, 0.0, 0.0]])
    np.testing.assert_allclose(bc.reconstruction_errors(rec, true), [5.0, 2.0, 3.0, 0.0],
                               rtol=1e-15)
    assert bc.reconstruction_error(rec, true) == pytest.approx(2.5, rel=1e-15)


def test_broadcasts_samples_against_truth(rng):
    true = rng.normal(size=(10, 3))
    shift = np.array([0.0, 0.0, 7.0])
    rec = np.stack([true + shift, true - 2 * shift])        # (2, 10, 3)
    d = bc.reconstruction_errors(rec, true)
    assert d.shape == (2, 10)
    np.testing.assert_allclose(d, [[7.0] * 10, [14.0] * 10], rtol=1e-12)
    assert bc.reconstruction_error(rec, true) == pytest.approx(10.5, rel=1e-12)


def test_round_trip_of_noise_free_pixels_is_exact():
    ds = bc.simulate_room(range_mm=5000, n_points=50, sigma_px=0.0, rng=2)
    rec = bc.triangulate(ds.params, ds.pixels)
    assert bc.reconstruction_error(rec, ds.points) < 1e-8


def test_nan_reconstructions_raise_or_are_skipped():
    true = np.zeros((3, 3))
    rec = np.array([[1.0, 0.0, 0.0], [np.nan, np.nan, np.nan], [0.0, 3.0, 0.0]])
    d = bc.reconstruction_errors(rec, true)
    assert np.isnan(d[1]) and d[0] == 1.0 and d[2] == 3.0
    with pytest.raises(ValueError,
                       match=r"1 invalid \(NaN\) points of 3 \(first at index \(1,\)\)"):
        bc.reconstruction_error(rec, true)
    assert bc.reconstruction_error(rec, true, invalid="ignore") == pytest.approx(2.0)
    assert np.isnan(bc.reconstruction_error(np.full((2, 3), np.nan), np.zeros((2, 3)),
                                            invalid="ignore"))


def test_bad_input():
    with pytest.raises(ValueError, match=r"true must contain only finite values"):
        bc.reconstruction_error(np.zeros((2, 3)), [[0.0, 0.0, np.nan], [0.0, 0.0, 0.0]])
    with pytest.raises(ValueError, match=r"reconstructed must have shape \(\.\.\., 3\)"):
        bc.reconstruction_error(np.zeros((2, 2)), np.zeros((2, 3)))
    with pytest.raises(ValueError, match=r"broadcastable shapes, got \(4, 3\) and \(2, 3\)"):
        bc.reconstruction_error(np.zeros((4, 3)), np.zeros((2, 3)))
    with pytest.raises(ValueError, match=r"invalid must be one of"):
        bc.reconstruction_error(np.zeros((2, 3)), np.zeros((2, 3)), invalid="drop")
    with pytest.raises(ValueError, match=r"hold no points"):
        bc.reconstruction_error(np.zeros((0, 3)), np.zeros((0, 3)))
