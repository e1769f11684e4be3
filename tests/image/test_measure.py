"""Locate, then measure: ``measure_ring`` gives a known path the full extractor's peak fit,
gates and covariances (what a tracker that predicts the path from the previous frame
calls)."""

import numpy as np
import pytest

import bayescal as bc
from bayescal.errors import InvalidValueError
from bayescal.image.extract import _choose
from bayescal.image.locate import ring_candidates
from bayescal.image.measure import laser_signal, measure_ring, ring_azimuths


@pytest.fixture(scope="module")
def image():
    img, _ = bc.render_image(bc.SensorParams.paper(), bc.room_walls(2500), n_lamps=2, rng=4)
    return img


@pytest.fixture(scope="module")
def signal(image):
    return laser_signal(image)


def test_the_extractors_path_measured_gives_its_points_exactly(image):
    lp = bc.extract_laser(image)
    signal = laser_signal(image)
    cands, _, _ = ring_candidates(signal, None, None, n_azimuth=None, highpass_px=15,
                                  runner_up=False)
    cand = _choose(cands, signal, min_snr=3.0, gate_px=1.0, along_sd=5.0, var_floor=2.5e-3)
    again = measure_ring(signal, cand.center, cand.radii, model=cand.model)
    np.testing.assert_array_equal(again.pixels, lp.pixels)
    np.testing.assert_array_equal(again.covariance, lp.covariance)
    np.testing.assert_array_equal(again.flagged, lp.flagged)
    assert again.offset_sd == lp.offset_sd


def test_a_path_from_the_points_themselves(image):
    # a tracker knows the previous frame's points, not the search's peak samples: their
    # radii, searched within 2 px, give the same points at 99 % of the azimuths or more
    lp = bc.extract_laser(image)
    r = np.hypot(*(lp.pixels - lp.center).T)
    again = measure_ring(laser_signal(image), lp.center, r, search_px=2)
    assert np.allclose(ring_azimuths(len(r)), np.arctan2(*(lp.pixels - lp.center).T[::-1]))
    same = np.hypot(*(again.pixels - lp.pixels).T) < 0.1
    assert np.mean(same) >= 0.97
    ok = ~lp.flagged & ~again.flagged & same
    assert np.mean(again.flagged == lp.flagged) >= 0.95
    ratio = again.sd_normal[ok] / lp.sd_normal[ok]
    assert np.all((ratio > 0.8) & (ratio < 1.25))


@pytest.mark.parametrize("center, radius, match", [
    ((np.nan, 1.0), np.full(360, 90.0), "center"),
    ((400.0, 300.0), np.full(5, 90.0), "radius"),
    ((400.0, 300.0), np.full((360, 2), 90.0), "radius"),
    ((400.0, 300.0), np.full(360, -1.0), "radius"),
])
def test_bad_paths_are_refused(signal, center, radius, match):
    with pytest.raises(InvalidValueError, match=match):
        measure_ring(signal, center, radius)
