"""From rendered images to a calibration with a rough floor plan, over replications (slow)."""

import warnings

import numpy as np
import pytest

import bayescal as bc

N_REPS = 20
Z90 = 1.645


@pytest.fixture(scope="module")
def z_scores():
    """Errors of the 7 identifiable parameters in posterior sds, one row per replication:
    a fresh image (2500 mm, two lamps, a ghost, a laser-off image) and a fresh rough plan."""
    p = bc.SensorParams.paper()
    rows = []
    for seed in range(N_REPS):
        ds = bc.simulate_room(p, range_mm=2500, n_points=50, rng=100 + seed)
        img, truth = bc.render_image(p, ds.walls, rng=seed, with_background=True, n_lamps=2,
                                     ghost=0.3)
        lp = bc.extract_laser(img, background=truth.background)
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            r = bc.calibrate_simultaneous(lp.pixels[~lp.flagged], ds.floor_plan, sigma_px=None,
                                          offset_sd=lp.offset_sd)
        sd = np.sqrt(np.diag(r.covariance_identifiable))
        rows.append((r.extras["theta"] - p.to_identifiable()) / sd)
    return np.array(rows)


@pytest.mark.slow
def test_intervals_cover_the_truth_except_the_principal_point(z_scores):
    # 90 % intervals of xi, gamma_u, gamma_v, h, beta: coverage over 20 replications.
    # A true 0.9 gives < 0.75 with probability 0.04 per parameter (binomial); measured 1.0
    # on 20 replications, z rms 0.04-0.24 (conservative: the intervals are wide)
    cover = np.mean(np.abs(z_scores) < Z90, axis=0)
    keep = [0, 1, 2, 5, 6]
    assert np.all(cover[keep] >= 0.75), cover


@pytest.mark.slow
def test_principal_point_intervals_cover_the_truth(z_scores):
    # u0, v0 are informed by every point, so an error shared along the ring (texture under
    # the stripe) matters most for them: the extractor's offset_sd, passed to the fit,
    # carries it. Measured: coverage 0.95 and 0.95, z rms 0.75 and 0.73 on 20 replications
    # (without the offset 0.70 and 0.75, z rms 1.53 and 1.46). Same false-failure rate as
    # above (0.04 per parameter).
    cover = np.mean(np.abs(z_scores[:, 3:5]) < Z90, axis=0)
    assert np.all(cover >= 0.75), cover
