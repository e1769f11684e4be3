"""Per-point variances checked against the ring's own scatter (``ring_scatter_scale``): wall
texture under the stripe moves neighbouring peaks together, so the scatter about a smoother
through a point's neighbours hides part of its error; the check leaves the nearest out."""

import numpy as np
import pytest
from test_extract_robust import assert_targets, ours_errors, targets

import bayescal as bc
from bayescal.image.noise import ring_scatter_scale


def _ring(seed, *, understate):
    """A closed ring of 360 radii (1.75 px apart) whose errors (sd 0.1 px) share neighbours
    (lag-1 correlation 0.5), with variances ``understate`` x too small."""
    rng = np.random.default_rng(seed)
    phi = np.arange(360) * 2 * np.pi / 360
    u = rng.standard_normal(361)
    r = 100 + 5 * np.cos(2 * phi) + 2 * np.sin(3 * phi) + 0.1 * (u[1:] + u[:-1]) / np.sqrt(2)
    return r, np.full(360, 0.01 / understate)


def test_ring_scatter_scale_finds_variances_too_small_by_a_factor():
    # mean of the scale over 20 rings. Measured over 1000 rings: with the right variances
    # mean 1.151, sd 0.165 (floored at 1: the prediction's correlated neighbours and the
    # median's noise push it up a little); with variances 2.5x too small mean 2.81, sd 0.49.
    # The mean of 20 then has sd ~0.037 and ~0.11: the bounds are 5 or more sds from the
    # measured means (false-failure rate < 1e-6).
    ok = np.ones(360, bool)
    right = [ring_scatter_scale(*_ring(s, understate=1.0), ok) for s in range(20)]
    small = [ring_scatter_scale(*_ring(s, understate=2.5), ok) for s in range(20)]
    assert np.mean(right) <= 1.35
    assert 2.2 <= np.mean(small) <= 3.5


def test_ring_scatter_scale_ignores_flagged_points_and_is_at_least_one():
    r, var = _ring(0, understate=1.0)
    ok = np.ones(360, bool)
    ok[100:110] = False
    r_bad = r.copy()
    r_bad[100:110] += 5.0                          # a stray sector, flagged
    f = ring_scatter_scale(r_bad, var, ok)
    assert f >= 1.0
    assert f == ring_scatter_scale(r, var, ok)
    assert ring_scatter_scale(r, var, np.zeros(360, bool)) == 1.0     # nothing to check


def test_textured_walls_with_laser_off_image_single_image_z_rms():
    # the single image of seeds 100-103 whose z rms was furthest out: 1.76 before the ring's
    # scatter scaled its variances (the wall's reflectance multiplies the stripe and moves
    # neighbouring peaks together), with the sd the extractor states along the ring's
    # normal (``sd_normal``, as studies/extraction_rooms.py scores it). Measured now: kept
    # 0.99, robust sd 0.14 px, gross 0, z rms 1.01
    img, truth = bc.render_image(bc.SensorParams.paper(), bc.room_walls(2500), n_lamps=0,
                                 with_background=True, rng=np.random.default_rng(102))
    lp = bc.extract_laser(img, background=truth.background)
    e, _, kept = ours_errors(lp, truth)
    assert_targets(targets(e, lp.sd_normal[~lp.flagged], kept, max_rsd=0.25))


@pytest.mark.slow
def test_1280x1024_camera_with_laser_off_image_single_image_z_rms():
    # the image of seeds 100-103 with the largest z rms before the scale: 2.37 (robust sd
    # 0.15 px). Measured now: kept 1.00, robust sd 0.15 px, gross 0, z rms 1.05
    p = bc.SensorParams(**{**bc.SensorParams.paper().as_dict(), "alpha_u": 90.0,
                           "alpha_v": -90.0, "u0": 640.0, "v0": 512.0})
    img, truth = bc.render_image(p, bc.room_walls(2500), shape=(1024, 1280), n_lamps=0,
                                 with_background=True, rng=np.random.default_rng(102))
    lp = bc.extract_laser(img, background=truth.background)
    e, _, kept = ours_errors(lp, truth)
    assert_targets(targets(e, lp.sd_normal[~lp.flagged], kept, max_rsd=0.25))
