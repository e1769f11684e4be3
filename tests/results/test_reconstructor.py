"""The fast reconstruction path: first order in the identifiable parameters, checked once
against the sampled path, and the same numbers as sampling within 10 % (sds) and 0.1 sd
(means) across ranges."""

import warnings

import numpy as np
import pytest

import bayescal as bc
from bayescal.results.reconstruction import LinearReconstruction, Reconstruction


def _posterior(range_mm, n_points=150):
    ds = bc.simulate_room(range_mm=range_mm, n_points=n_points, n_walls=6, sigma_px=0.2,
                          approx_error=0.03, approx_model="gaussian", rng=0)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", bc.NotConvergedWarning)
        post = bc.sample_posterior(ds.pixels, ds.approx_points, sigma_px=0.2,
                                   sigma_scene=ds.sigma_scene, rng=1, min_ess=500,
                                   progress=False)
    new = bc.simulate_room(range_mm=range_mm, n_points=400, n_walls=6, sigma_px=0.2,
                           approx_error=0.03, rng=5)
    return post, new


@pytest.fixture(scope="module", params=[1000.0, 2500.0, 5000.0])
def room(request):
    return _posterior(request.param)


def test_fast_path_agrees_with_sampling(room):
    """Reference: 2000 posterior draws (Monte-Carlo error of an sd ~1.6 %, of a mean
    ~0.022 sd); the fast path's sds within 10 % and means within 0.1 sd for 90 % of the
    pixel axes, the median sd ratio within 5 %."""
    post, new = room
    fast = post.reconstruct(new.pixels)
    ref = post.reconstruct(new.pixels, method="sampled", max_samples=2000, rng=3)
    assert isinstance(fast, LinearReconstruction) and isinstance(ref, Reconstruction)
    assert post.reconstructor().linear_ok
    ok = fast.valid & ref.valid
    sd_f = np.sqrt(np.diagonal(fast.covariance[ok], axis1=1, axis2=2))
    sd_r = np.sqrt(np.diagonal(ref.covariance[ok], axis1=1, axis2=2))
    ratio = sd_f / sd_r
    assert abs(np.median(ratio) - 1) < 0.05
    assert np.quantile(np.abs(ratio - 1), 0.9) < 0.10
    assert np.quantile(np.abs(fast.mean[ok] - ref.mean[ok]) / sd_r, 0.9) < 0.10


def test_fast_path_keeps_the_interface():
    post, new = _posterior(1000.0, n_points=80)
    mean, cov = post.reconstruct(new.pixels[:5])
    assert mean.shape == (5, 3) and cov.shape == (5, 3, 3)
    one = post.reconstruct(new.pixels[0])
    assert one.mean.shape == (3,) and one.intervals.shape == (3, 2)
    rec = post.reconstruct(new.pixels[:5])
    assert rec.intervals.shape == (5, 3, 2) and np.all(rec.valid)
    assert post.reconstructor() is post.reconstructor()          # prepared once
    with pytest.raises(ValueError, match="method must be"):
        post.reconstruct(new.pixels, method="fast")
    with pytest.raises(ValueError, match="pixel_cov must have shape"):
        post.reconstruct(new.pixels[:5], pixel_cov=np.eye(3))


def test_pixels_off_the_calibrated_ring_are_sampled():
    post, new = _posterior(1000.0, n_points=80)
    rc = post.reconstructor()
    lo, hi = rc.radius_range
    c = rc.theta[3:5]
    far = c + np.array([[0.0, (lo + hi) / 2], [0.0, hi + 6.0]])
    rec = post.reconstruct(far)
    assert rec.method == "mixed"
    assert post.reconstruct(far[:1]).method == "linear"


def test_per_pixel_covariance_widens_the_points():
    post, new = _posterior(1000.0, n_points=80)
    pix = new.pixels[:10]
    small = post.reconstruct(pix, pixel_cov=np.broadcast_to(0.01 * np.eye(2), (10, 2, 2)))
    large = post.reconstruct(pix, pixel_cov=np.broadcast_to(4.0 * np.eye(2), (10, 2, 2)))
    assert np.all(np.trace(large.covariance, axis1=1, axis2=2)
                  > np.trace(small.covariance, axis1=1, axis2=2))


def test_least_squares_reconstructor_is_its_reconstruct():
    ds = bc.simulate_room(range_mm=1000, n_points=120, sigma_px=0.3, approx_error=0.02,
                          approx_model="gaussian", rng=2)
    res = bc.calibrate_simultaneous(ds.pixels, ds.approx_points, sigma_px=0.3,
                                    sigma_scene=ds.sigma_scene)
    a = res.reconstruct(ds.pixels[:20], sigma_px=0.3)
    b = res.reconstructor(sigma_px=0.3)(ds.pixels[:20])
    np.testing.assert_allclose(b.mean, a.mean, rtol=1e-12)
    np.testing.assert_allclose(b.covariance, a.covariance, rtol=1e-9, atol=1e-12)


@pytest.mark.slow
def test_fast_path_covers_held_out_truth_over_replications():
    """M = 40 replications (new noise, new posterior, 100 held-out pixels each, 2500 mm):
    the fraction of held-out points inside their 90 % ellipsoid. Points of one replication
    share its calibration error, so the fractions scatter more than binomially; the test
    is a one-sample t-test of their mean against 0.9 at the 1 % level (false failure 1 %)."""
    from scipy import stats

    inside = []
    for seed in range(40):
        ds = bc.simulate_room(range_mm=2500, n_points=150, n_walls=6, sigma_px=0.2,
                              approx_error=0.03, approx_model="gaussian", rng=1000 + seed)
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", bc.NotConvergedWarning)
            post = bc.sample_posterior(ds.pixels, ds.approx_points, sigma_px=0.2,
                                       sigma_scene=ds.sigma_scene, rng=seed, min_ess=300,
                                       progress=False)
        new = bc.simulate_room(range_mm=2500, n_points=100, n_walls=6, sigma_px=0.2,
                               rng=5000 + seed)
        mean, cov = post.reconstruct(new.pixels)
        d = new.points - mean
        nse = np.einsum("mi,mij,mj->m", d, np.linalg.inv(cov), d)
        inside.append(np.mean(nse < stats.chi2.ppf(0.9, 3)))
    frac, sd = float(np.mean(inside)), float(np.std(inside, ddof=1))
    half = stats.t.ppf(0.995, len(inside) - 1) * sd / np.sqrt(len(inside))
    print(f"held-out 90 % ellipsoid coverage over 40 replications: {frac:.3f} "
          f"(per replication sd {sd:.3f}; 99 % band 0.9 +- {half:.3f})")
    assert abs(frac - 0.9) <= half


def test_pixels_whose_rays_all_miss_the_cone_are_said():
    # pixels of a 1280x1024 camera given to an 800x600 calibration: no ray meets the cone
    ds = bc.simulate_room(range_mm=1000, n_points=60, sigma_px=0.3, approx_error=0.02,
                          approx_model="gaussian", rng=2)
    res = bc.calibrate_simultaneous(ds.pixels, ds.approx_points, sigma_px=0.3,
                                    sigma_scene=ds.sigma_scene)
    far = np.array([[1100.0, 950.0], [1150.0, 900.0], [1000.0, 1000.0]])
    with pytest.warns(bc.BayescalWarning, match="none of the 3 pixels' rays meets the laser"):
        rec = res.reconstruct(far)
    assert not rec.valid.any()
    with warnings.catch_warnings():                  # some rays meeting it: no warning
        warnings.simplefilter("error", bc.BayescalWarning)
        res.reconstruct(np.vstack([far, ds.pixels[:2]]))
