"""Locate, then measure: ``measure_ring`` gives a known path the full extractor's peak fit,
gates and covariances (what a tracker that predicts the path from the previous frame
calls)."""

import numpy as np
import pytest

import bayescal as bc
from bayescal.errors import InvalidValueError
from bayescal.image.extract import _choose
from bayescal.image.locate import ring_candidates
from bayescal.image.measure import laser_signal, measure_ring, measure_settled, ring_azimuths
from bayescal.image.ring import RAY_GRID, RAY_STEP, ring_circle, ring_rays


@pytest.fixture(scope="module")
def image():
    img, _ = bc.render_image(bc.SensorParams.paper(), bc.room_walls(2500), n_lamps=2, rng=4)
    return img


@pytest.fixture(scope="module")
def signal(image):
    return laser_signal(image)


def test_the_extractors_path_measured_gives_its_points_exactly(image):
    # the chosen ring measured, then on its own circle's profiles (measure_settled)
    lp = bc.extract_laser(image)
    signal = laser_signal(image)
    cands, _, _ = ring_candidates(signal, None, None, n_azimuth=None, highpass_px=15,
                                  runner_up=False)
    kw = dict(min_snr=3.0, gate_px=1.0, along_sd=5.0, var_floor=2.5e-3)
    cand = _choose(cands, signal, **kw)
    again = measure_settled(signal, measure_ring(signal, cand.center, cand.radii,
                                                 model=cand.model), **kw)
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


def test_parts_alike_compares_a_rings_width_where_it_parts_with_where_it_agrees():
    from bayescal.image.locate import parts_alike

    w = np.r_[np.full(60, 1.2), np.full(40, 0.8)]        # a narrower ridge over 40 %
    apart = np.r_[np.zeros(60, bool), np.ones(40, bool)]
    kept = np.ones(100, bool)
    assert parts_alike(w, kept, apart) == pytest.approx(np.log(1.5))
    assert parts_alike(np.full(100, 1.2), kept, apart) == pytest.approx(0.0)
    assert np.isnan(parts_alike(w, kept & ~apart, apart))     # nothing kept where apart


def test_a_ring_measured_on_other_profiles_settles_on_the_extractors(image, signal):
    # measured about a centre 7 px off with 400 profiles (a tracker's guess), the ring
    # settles on the profiles of its own circle, the full extractor's: the same points
    # wherever each found the same peak sample (measured: all but 1-3 of 360)
    lp = bc.extract_laser(image)
    c = lp.center + np.array([5.0, -5.0])
    d = lp.pixels - c
    a = np.arctan2(d[:, 1], d[:, 0])
    order = np.argsort(a)
    radius = np.interp(ring_azimuths(400), a[order], np.hypot(*d.T)[order], period=2 * np.pi)
    first = measure_ring(signal, c, radius, search_px=2)
    again = measure_settled(signal, first)
    np.testing.assert_array_equal(again.center, lp.center)
    assert len(again) == len(lp)
    same = np.hypot(*(again.pixels - lp.pixels).T) < 0.01
    assert np.mean(same) >= 0.98
    assert np.mean(again.flagged == lp.flagged) >= 0.98
    assert measure_settled(signal, again) is again           # settled: measured once


def test_ring_circle_does_not_depend_on_the_profiles():
    # an ellipse (semi-axes 250 and 238 px, lumpy) sampled at 766 equal azimuths about
    # centres up to 11 px apart: each point weighted by its arc, the circle's centre moves
    # by 0.001 px (unweighted, 0.2 px: enough to cross the grid of ring_rays)
    t = np.linspace(0, 2 * np.pi, 20000, endpoint=False)
    ring = np.stack([250 * np.cos(t) + 9 * np.cos(3 * t), 238 * np.sin(t) + 6 * np.sin(2 * t)], -1)
    centres = []
    for c in ([0.0, 0.0], [10.0, 5.0], [-8.0, 3.0]):
        d = ring - c
        a = np.arctan2(d[:, 1], d[:, 0])
        order = np.argsort(a)
        phi = ring_azimuths(766)
        r = np.interp(phi, a[order], np.hypot(*d.T)[order], period=2 * np.pi)
        pts = np.asarray(c) + r[:, None] * np.stack([np.cos(phi), np.sin(phi)], -1)
        centres.append(ring_circle(pts, np.zeros(766, bool))[0])
    assert np.ptp(np.array(centres), axis=0).max() < 0.005


def test_ring_rays_grid():
    # the centre on the grid, one profile per 2 px of the circumference (pi R = 471.2)
    # rounded down to a multiple of RAY_STEP; the user's centre and number as given
    c, n = ring_rays([401.9, 298.1], 150.0)
    np.testing.assert_array_equal(c, [RAY_GRID * round(401.9 / RAY_GRID),
                                      RAY_GRID * round(298.1 / RAY_GRID)])
    assert n == RAY_STEP * int(np.pi * 150.0 / RAY_STEP)
    assert ring_rays([401.9, 298.1], 100.0)[1] == 360
    c, n = ring_rays([401.9, 298.1], 250.0, center=(400.0, 300.0), n_azimuth=720)
    np.testing.assert_array_equal(c, [400.0, 300.0])
    assert n == 720
    assert ring_rays([0.0, 0.0], 5000.0)[1] == 3600
