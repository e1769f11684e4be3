"""RingNoise: the noise a covariance-weighted calibration gives new pixels without their own."""

import numpy as np
import pytest

import bayescal as bc
from bayescal.results.pixelnoise import RingNoise


def _ring_cov(pixels, center, across, along):
    d = pixels - center
    n = d / np.linalg.norm(d, axis=1, keepdims=True)
    t = np.column_stack([-n[:, 1], n[:, 0]])
    return (across ** 2 * np.einsum("mi,mj->mij", n, n)
            + along ** 2 * np.einsum("mi,mj->mij", t, t))


def test_medians_across_and_along_turned_to_each_pixel(rng):
    az = rng.uniform(0, 2 * np.pi, 50)
    px = np.column_stack([400 + 150 * np.cos(az), 300 + 150 * np.sin(az)])
    across = rng.uniform(0.05, 0.15, 50)
    cov = _ring_cov(px, (400, 300), across[:, None, None], 3.0)
    noise = RingNoise.from_calibration(px, cov, (400, 300), scale=2.0)
    assert noise.sd_across == pytest.approx(2.0 * np.sqrt(np.median(across ** 2)))
    assert noise.sd_along == pytest.approx(6.0) and noise.n_pixels == 50
    new = np.array([[600.0, 300.0], [400.0, 100.0]])         # right of and above the centre
    c = noise.covariance(new)
    np.testing.assert_allclose(c[0], np.diag([noise.sd_across ** 2, 36.0]), atol=1e-12)
    np.testing.assert_allclose(c[1], np.diag([36.0, noise.sd_across ** 2]), atol=1e-12)
    assert "times its scale 2 on them" in noise.describe()
    with pytest.raises(ValueError, match="scale"):
        RingNoise.from_calibration(px, cov, (400, 300), scale=0)
    with pytest.raises(ValueError, match="must match"):
        RingNoise.from_calibration(px, cov[:3], (400, 300))


def test_a_covariance_fit_gives_its_noise_to_plain_pixels():
    ds = bc.simulate_room(range_mm=1000, n_points=60, sigma_px=0.2, approx_error=0.02,
                          approx_model="gaussian", rng=1)
    cov = _ring_cov(ds.pixels, (400, 300), 0.2, 2.0)
    res = bc.calibrate_simultaneous(ds.pixels, ds.approx_points, sigma_px=1.5,
                                    sigma_scene=ds.sigma_scene, pixel_cov=cov)
    noise = res.ring_noise()
    assert noise.scale == 1.5 and noise.sd_across == pytest.approx(0.3, rel=0.02)
    _, plain = res.reconstruct(ds.pixels)                     # no covariances given
    _, own = res.reconstructor()(ds.pixels, pixel_cov=1.5 ** 2 * cov)
    np.testing.assert_allclose(np.sqrt(plain[:, 2, 2]), np.sqrt(own[:, 2, 2]), rtol=0.02)
    # sigma_px stays what it says: a noise in px for the new pixels
    _, iso = res.reconstruct(ds.pixels, sigma_px=1.5)
    assert np.median(iso[:, 2, 2] / plain[:, 2, 2]) > 4
    plain_fit = bc.calibrate_simultaneous(ds.pixels, ds.approx_points, sigma_px=0.2,
                                          sigma_scene=ds.sigma_scene)
    assert plain_fit.ring_noise() is None
