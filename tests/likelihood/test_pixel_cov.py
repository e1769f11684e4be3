"""Per-point pixel covariances in the laser likelihood: whitening, gradient, calibration."""

import numpy as np
import pytest

import bayescal as bc
from bayescal.likelihood.points import LaserLikelihood


@pytest.fixture(scope="module")
def room():
    ds = bc.simulate_room(range_mm=2500, n_points=80, sigma_px=0.3, approx_error=0.02,
                          approx_model="gaussian", rng=1)
    rng = np.random.default_rng(0)
    A = rng.normal(size=(ds.n_points, 2, 2))
    cov = A @ A.transpose(0, 2, 1) * 0.05 + 0.01 * np.eye(2)
    return ds, cov


def test_isotropic_covariance_equals_scalar_sigma(room):
    ds, _ = room
    theta = bc.SensorParams.paper().to_identifiable()
    a = LaserLikelihood(ds.pixels, ds.approx_points, sigma_px=0.3, sigma_scene=ds.sigma_scene)
    cov = np.broadcast_to(0.09 * np.eye(2), (ds.n_points, 2, 2))
    b = LaserLikelihood(ds.pixels, ds.approx_points, sigma_px=1.0, sigma_scene=ds.sigma_scene,
                        pixel_cov=cov)
    q0 = a.initial_q(theta)
    np.testing.assert_allclose(b.laplace(theta, q0)[0], a.laplace(theta, q0)[0], rtol=1e-12)
    np.testing.assert_allclose(b.grad_log_marginal(theta, q0)[1],
                               a.grad_log_marginal(theta, q0)[1], rtol=1e-9, atol=1e-9)


def test_anisotropic_matches_direct_density_and_finite_differences(room):
    ds, cov = room
    theta = bc.SensorParams.paper().to_identifiable()
    lik = LaserLikelihood(ds.pixels, ds.approx_points, sigma_px=1.0,
                          sigma_scene=ds.sigma_scene, pixel_cov=cov)
    q = lik.initial_q(theta)
    # whitened pixel rows: |R_px|^2 = r^T cov^-1 r with r the raw pixel residual
    R = lik.residuals(theta, q, np.array(1.0), lik.w_scene)
    P = bc.cone_point(bc.SensorParams.paper(), q)
    r = bc.project(bc.SensorParams.paper(), P) - ds.pixels
    direct = np.einsum("ni,nij,nj->n", r, np.linalg.inv(cov), r)
    np.testing.assert_allclose(np.sum(R[:, :2] ** 2, axis=1), direct, rtol=1e-9)
    # the analytic gradient against central differences
    _, g = lik.grad_log_marginal(theta, q)
    h = 1e-6 * np.maximum(np.abs(theta), 1e-2)
    fd = [(lik.log_marginal(theta + e, q, n_iter=30) - lik.log_marginal(theta - e, q, n_iter=30))
          / (2 * e[k]) for k, e in enumerate(np.diag(h))]
    np.testing.assert_allclose(g, fd, rtol=1e-4, atol=1e-3)


@pytest.mark.parametrize("bad, match", [
    (lambda c: c[:-1], "shape"),
    (lambda c: c * np.array([[1.0, 0.0], [0.0, -1.0]]), "positive definite"),
    (lambda c: np.where(np.arange(len(c))[:, None, None] == 3, np.nan, c), "row 3"),
])
def test_bad_pixel_cov(room, bad, match):
    ds, cov = room
    with pytest.raises(ValueError, match=match):
        LaserLikelihood(ds.pixels, ds.approx_points, sigma_px=1.0, sigma_scene=ds.sigma_scene,
                        pixel_cov=bad(cov.copy()))


def test_calibrate_rejects_unsupported_combinations(room):
    ds, cov = room
    with pytest.raises(ValueError, match="scale"):
        bc.calibrate_simultaneous(ds.pixels, ds.approx_points, sigma_px=None,
                                  sigma_scene=ds.sigma_scene, pixel_cov=cov)
    with pytest.raises(TypeError, match="estimate_points=True"):
        bc.calibrate_simultaneous(ds.pixels, ds.approx_points, sigma_px=1.0,
                                  sigma_scene=ds.sigma_scene, pixel_cov=cov,
                                  estimate_points=False)


def test_floor_plan_takes_pixel_cov_through_calibrate_simultaneous(room):
    # sigma^2 I as covariances with the scale 1 is the scalar model: same fit
    ds, _ = room
    iso = np.broadcast_to(0.3**2 * np.eye(2), (len(ds.pixels), 2, 2))
    a = bc.calibrate_simultaneous(ds.pixels, ds.floor_plan, sigma_px=0.3)
    b = bc.calibrate_simultaneous(ds.pixels, ds.floor_plan, sigma_px=1.0, pixel_cov=iso)
    np.testing.assert_allclose(b.params.to_array(), a.params.to_array(), rtol=1e-6, atol=1e-6)


def test_calibration_from_an_image_with_pixel_covariances():
    # image -> extracted pixels with covariances -> least squares; approximate points: the
    # true points of the extracted pixels with 2 % (+1 mm) Gaussian error
    p = bc.SensorParams.paper()
    img, truth = bc.render_image(p, bc.room_walls(2500), rng=1, with_background=True,
                                 n_lamps=2, ghost=0.3)
    lp = bc.extract_laser(img, background=truth.background)
    k = ~lp.flagged
    pix, cov = lp.pixels[k], lp.covariance[k]
    pts = truth.points[np.argmin(np.sum((pix[:, None] - truth.pixels[None]) ** 2, -1), 1)]
    sig3 = 0.02 * np.abs(pts) + 1.0
    approx = pts + np.random.default_rng(1).normal(size=pts.shape) * sig3
    r = bc.calibrate_simultaneous(pix, approx, sigma_px=1.0, sigma_scene=sig3, pixel_cov=cov)
    z = (r.extras["theta"] - p.to_identifiable()) / np.sqrt(np.diag(r.covariance_identifiable))
    # measured (docs/images.md, 'A ring displaced as a whole'): |z| <= 1.9 here (v0 -1.9)
    assert r.converged and np.all(np.abs(z) < 3.0)
