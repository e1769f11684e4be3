"""Per-point pixel covariances with a floor plan: likelihood, least squares, inferred scale."""

import numpy as np
import pytest

import bayescal as bc
from bayescal.fit.floorplan import calibrate_plan
from bayescal.likelihood.floorplan import PlanLikelihood
from bayescal.scene.floorplan import FloorPlan


def ring_covariance(params, pixels, sd_across, sd_along):
    """(N, 2, 2) px^2: ``sd_across`` along the radius from the principal point (across the
    ring), ``sd_along`` along the ring, as the extractor gives them."""
    n = pixels - np.array([params.u0, params.v0])
    n /= np.linalg.norm(n, axis=1, keepdims=True)
    t = np.stack([-n[:, 1], n[:, 0]], axis=1)
    return (np.asarray(sd_across)[..., None, None] ** 2 * n[:, :, None] * n[:, None, :]
            + sd_along**2 * t[:, :, None] * t[:, None, :])


def ring_room(range_mm=1000.0, n_points=300, sd_across=0.1, sd_along=1.0, rng=0):
    """A room whose pixel noise has the ring covariance; returns (ds, plan, cov)."""
    ds = bc.simulate_room(range_mm=range_mm, n_points=n_points, sigma_px=0.0,
                          approx_error=0.03, approx_model="wall", rng=rng)
    cov = ring_covariance(ds.params, ds.pixels_true, sd_across, sd_along)
    noise = np.einsum("nij,nj->ni", np.linalg.cholesky(cov),
                      np.random.default_rng(rng + 100).standard_normal((n_points, 2)))
    return ds, ds.floor_plan, cov, ds.pixels_true + noise


@pytest.fixture(scope="module")
def room():
    return ring_room()


def _psi(ds, plan, extra=()):
    return np.concatenate([ds.params.to_identifiable(), plan.param_nominal, extra])


@pytest.mark.parametrize("outliers", [False, True])
def test_isotropic_covariance_equals_scalar_sigma(room, outliers):
    ds, plan, _, pixels = room
    iso = np.broadcast_to(0.3**2 * np.eye(2), (len(pixels), 2, 2))
    a = PlanLikelihood(pixels, plan, sigma_px=0.3, outliers=outliers)
    b = PlanLikelihood(pixels, plan, sigma_px=1.0, outliers=outliers, pixel_cov=iso)
    psi = _psi(ds, plan, [np.log(0.05 / 0.95)] if outliers else [])
    la, qa, Ca = a.laplace(psi)
    lb, qb, Cb = b.laplace(psi)
    assert np.isfinite(la)
    np.testing.assert_allclose(lb, la, rtol=1e-12)
    np.testing.assert_allclose(qb, qa, rtol=1e-12)
    np.testing.assert_allclose(Cb, Ca, rtol=1e-10)
    np.testing.assert_allclose(b.point_log_density(psi, qa), a.point_log_density(psi, qa),
                               rtol=1e-12)
    theta, walls = psi[:7], plan.param_nominal.reshape(-1, 2)
    t = qa[:, 0]
    k = a.hard_wall_index(walls, t)
    for x, y in zip(a.residuals(theta, walls, t, k, 0.3, jacobian=True),
                    b.residuals(theta, walls, t, k, 1.0, jacobian=True), strict=True):
        np.testing.assert_allclose(y, x, rtol=1e-12, atol=1e-12)


def test_anisotropic_whitening_matches_a_hand_computation(room, numdiff):
    ds, plan, cov, pixels = room
    lik = PlanLikelihood(pixels, plan, sigma_px=1.0, pixel_cov=cov)
    raw = PlanLikelihood(pixels, plan, sigma_px=1.0)
    theta, walls = ds.params.to_identifiable(), plan.param_nominal.reshape(-1, 2)
    t = raw._start(theta[None])[0]
    k = raw.hard_wall_index(walls, t)
    R, Jth, Jw, Jt = lik.residuals(theta, walls, t, k, 1.0, jacobian=True)
    r, rth, rw, rt = raw.residuals(theta, walls, t, k, 1.0, jacobian=True)
    P = np.linalg.inv(cov)
    # R^T R = r^T cov^-1 r, and the same metric on every Jacobian
    np.testing.assert_allclose(np.sum(R * R, 1), np.einsum("ni,nij,nj->n", r, P, r), rtol=1e-9)
    np.testing.assert_allclose(np.einsum("nk,nk->n", Jt, R),
                               np.einsum("ni,nij,nj->n", rt, P, r), rtol=1e-8, atol=1e-10)
    np.testing.assert_allclose(np.einsum("nki,nk->ni", Jth, R),
                               np.einsum("nai,nab,nb->ni", rth, P, r), rtol=1e-8, atol=1e-8)
    np.testing.assert_allclose(np.einsum("nki,nkj->nij", Jw, Jw),
                               np.einsum("nai,nab,nbj->nij", rw, P, rw), rtol=1e-8, atol=1e-14)
    # across the ring the whitened residual is the raw one over 0.1 px, along it over 1 px
    n = ds.pixels_true - [ds.params.u0, ds.params.v0]      # as ring_covariance
    n /= np.linalg.norm(n, axis=1, keepdims=True)
    across = np.einsum("ni,ni->n", r, n)
    along = r[:, 0] * -n[:, 1] + r[:, 1] * n[:, 0]
    np.testing.assert_allclose(np.sum(R * R, 1), (across / 0.1) ** 2 + (along / 1.0) ** 2,
                               rtol=1e-9)


@pytest.mark.parametrize("range_mm", [1000.0, 5000.0])
def test_anisotropic_laplace_matches_numerical_integration(range_mm):
    """Per point, the Laplace marginal (with ``log det L_i``) against a 1-D quadrature of
    the exact integrand (whitened likelihood x Jeffreys prior in the whitened metric), at
    the true walls, along-ring sd 1 px (with 5 px the azimuth's integrand is far from
    Gaussian: errors up to 0.3 nat at 1000 mm, 1.9 nat at 5000 mm; docs/images.md)."""
    ds, _, cov, pixels = ring_room(range_mm=range_mm)
    plan = FloorPlan(ds.walls, distance_sd=0.05 * range_mm, angle_sd=0.02)
    pick = np.arange(0, len(pixels), 10)
    lik = PlanLikelihood(pixels[pick], plan, sigma_px=1.2, pixel_cov=cov[pick])
    psi = _psi(ds, plan)
    per_point, q, _ = lik.laplace_per_point(psi)
    grid = q[:, 0][:, None] + np.linspace(-0.3, 0.3, 60001)[None, :]
    lp = lik.point_log_density(psi, grid.T[..., None]).T
    m = lp.max(axis=1, keepdims=True)
    log_det_cov = np.log(np.linalg.det(cov[pick]))
    brute = (m[:, 0] + np.log(np.trapezoid(np.exp(lp - m), grid, axis=1))
             - 2 * np.log(1.2) - np.log(2 * np.pi) - 0.5 * log_det_cov)
    np.testing.assert_allclose(per_point, brute, atol=1e-2)


def test_least_squares_isotropic_covariance_equals_scalar_sigma(room):
    ds, plan, _, pixels = room
    iso = np.broadcast_to(0.1**2 * np.eye(2), (len(pixels), 2, 2))
    a = calibrate_plan(pixels, plan, sigma_px=0.1)
    b = calibrate_plan(pixels, plan, sigma_px=1.0, pixel_cov=iso)
    sd = np.sqrt(np.diag(a.covariance()))
    # the same fit to round-off: within 1e-6 sd (phi, ~0, is compared in sds too)
    np.testing.assert_allclose((b.params.to_array() - a.params.to_array()) / sd, 0, atol=1e-6)
    np.testing.assert_allclose(b.covariance(), a.covariance(), rtol=1e-6, atol=1e-14)
    np.testing.assert_allclose(b.extras["walls"], a.extras["walls"], rtol=1e-8)
    np.testing.assert_allclose(b.outlier_prob, a.outlier_prob, rtol=1e-6, atol=1e-12)
    assert b.residual_rms["pixel_px"] == pytest.approx(a.residual_rms["pixel_px"], rel=1e-8)


def test_least_squares_with_ring_covariances(room):
    ds, plan, cov, pixels = room
    res = calibrate_plan(pixels, plan, sigma_px=1.0, pixel_cov=cov)
    assert res.converged
    # the MAP's whitened residual rows are L_i (project - pixels): the hand computation
    sol = res.extras["map"]
    r = bc.project(res.params, res.points) - pixels
    np.testing.assert_allclose(np.sum(sol.ne["R0"] ** 2, axis=1),
                               np.einsum("ni,nij,nj->n", r, np.linalg.inv(cov), r),
                               rtol=1e-6, atol=1e-9)
    # the pixel rms is reported in px (the whitening undone), each point weighted 1 - r_i
    keep = 1.0 - res.outlier_prob
    rms = np.sqrt(np.sum(keep[:, None] * r * r) / (2 * np.sum(keep)))
    assert res.residual_rms["pixel_px"] == pytest.approx(rms, rel=1e-6)
    # the data hold the sensor: within 4 sd of the truth for the 7 identifiable parameters
    th = ds.params.to_identifiable()
    sd = np.sqrt(np.diag(res.covariance(identifiable=True)))
    z = (res.extras["theta"] - th) / sd
    assert np.all(np.abs(z) < 4), z


def test_inferred_scale_on_the_covariances_recovers_a_known_one():
    """Covariances given as 0.25x the true ones: the inferred scale is ~2."""
    ds, plan, cov, pixels = ring_room(n_points=400, rng=2)
    res = calibrate_plan(pixels, plan, sigma_px=None, pixel_cov=0.25 * cov)
    s = res.extras["noise"]["sigma_px"]
    # 400 points, one degree of freedom each: relative sd of s ~ 1 / sqrt(800) = 3.5 %
    assert s == pytest.approx(2.0, rel=0.12)
    # the uncertainty follows the scale: the sds as with that scale given
    ref = calibrate_plan(pixels, plan, sigma_px=s, pixel_cov=0.25 * cov)
    np.testing.assert_allclose(np.sqrt(np.diag(res.covariance(identifiable=True))),
                               np.sqrt(np.diag(ref.covariance(identifiable=True))), rtol=0.05)
    # and the sensor is where the data put it: within 3.5 sd of the truth
    z = (res.extras["theta"] - ds.params.to_identifiable()) / np.sqrt(
        np.diag(res.covariance(identifiable=True)))
    assert np.all(np.abs(z) < 3.5), z


def test_bad_pixel_cov_is_refused(room):
    ds, plan, cov, pixels = room
    with pytest.raises(ValueError, match="pixel_cov must have shape"):
        PlanLikelihood(pixels, plan, sigma_px=1.0, pixel_cov=cov[:-1])
    bad = cov.copy()
    bad[7] = [[1.0, 0.0], [0.0, -1.0]]
    with pytest.raises(ValueError, match="row 7"):
        calibrate_plan(pixels, plan, sigma_px=1.0, pixel_cov=bad)
    assert isinstance(plan, FloorPlan)
