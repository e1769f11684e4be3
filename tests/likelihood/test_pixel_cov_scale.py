"""An inferred global scale on per-point pixel covariances, approximate points.

``calibrate_simultaneous`` still refuses ``sigma_px=None`` with ``pixel_cov``; these tests
check that the likelihood and the least squares' noise loop underneath already infer the
scale (``docs/images.md``, "Per-point pixel covariances in the calibration").
"""

import sys
from pathlib import Path

import numpy as np
import pytest

import bayescal as bc
from bayescal.fit.simultaneous import _fit_map
from bayescal.likelihood.points import LaserLikelihood
from bayescal.likelihood.priors import Prior

sys.path.insert(0, str(Path(__file__).resolve().parent))
from test_plan_pixel_cov import ring_covariance  # noqa: E402


def _room(seed, along, n_points=400):
    ds = bc.simulate_room(range_mm=2500, n_points=n_points, sigma_px=0.0, approx_error=0.02,
                          approx_model="gaussian", rng=seed)
    cov = ring_covariance(ds.params, ds.pixels_true, 0.1, along)
    noise = np.einsum("nij,nj->ni", np.linalg.cholesky(cov),
                      np.random.default_rng(seed + 100).standard_normal((n_points, 2)))
    return ds, cov, ds.pixels_true + noise


@pytest.mark.parametrize("along", [1.0, 5.0])
def test_inferred_scale_recovers_a_known_one(along):
    """Covariances given as 0.25x the ones the noise was drawn from: the scale is ~2
    (measured 2.00-2.04 over seeds 0, 1 and both along-ring sds)."""
    ds, cov, pixels = _room(1, along)
    lik = LaserLikelihood(pixels, ds.approx_points, sigma_px=None, sigma_scene=ds.sigma_scene,
                          outliers=True, pixel_cov=0.25 * cov)
    prior = Prior(None)
    theta0 = prior.mean().to_identifiable()
    fit = _fit_map(lik, prior, theta0, lik.initial_q(theta0), 200)
    # 400 points, ~1 degree of freedom of pixel noise each: relative sd of s ~ 3.5 %
    assert fit.sig == pytest.approx(2.0, rel=0.12)
