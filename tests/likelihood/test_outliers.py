"""The per-point outlier mixture: likelihood, least squares, clean-data cost, gross errors."""

import numpy as np
import pytest
from scipy.integrate import quad, trapezoid

import bayescal as bc
from bayescal.likelihood.points import LaserLikelihood


@pytest.fixture(scope="module")
def room():
    return bc.simulate_room(range_mm=1000, n_points=580, sigma_px=0.5, approx_error=0.01,
                            approx_model="gaussian", rng=0)


def test_extra_global_and_its_prior(room):
    lik = LaserLikelihood(room.pixels, room.approx_points, sigma_px=None, sigma_scene=None,
                          outliers=True, outlier_prior=(2.0, 30.0))
    assert lik.extra_names == ("sigma_px", "kappa", "outlier_frac")
    # the Beta(2, 30) prior in logit coordinates is normalised
    f = lambda x: np.exp(lik.log_prior_extra(np.array([0.0, np.log(0.02), x])))  # noqa: E731
    np.testing.assert_allclose(quad(f, -40, 40, limit=200)[0], 1.0, rtol=1e-8)


@pytest.mark.parametrize("kw, match", [
    ({"outliers": "yes"}, "outliers"),
    ({"outlier_scale": 1.0}, "outlier_scale"),
    ({"outlier_prior": (0.0, 1.0)}, "outlier_prior"),
    ({"outlier_prior": 3}, "outlier_prior"),
])
def test_bad_outlier_options(room, kw, match):
    with pytest.raises((ValueError, TypeError), match=match):
        LaserLikelihood(room.pixels, room.approx_points, sigma_px=0.5,
                        sigma_scene=room.sigma_scene, **kw)


def test_mixture_laplace_matches_quadrature_of_the_point_density():
    """``laplace`` (mixture of the two components' Laplace marginals) and
    ``point_log_density`` (exact mixture density of q) describe one model: the 2-D
    integral of exp(point_log_density) equals the Laplace marginal, for an inlier and
    a gross outlier. Small c keeps the outlier component's q-spread where the model is
    nearly linear; the Laplace error is then the pure model's (<0.005 nats per point,
    ``tests/likelihood/test_model.py``); a wrong
    constant (a log c term) is off by >= log 4 = 1.4."""
    ds = bc.simulate_room(range_mm=2000, n_points=2, sigma_px=0.5, approx_error=0.01,
                          approx_model="gaussian", rng=3)
    apx = ds.approx_points.copy()
    x, y = apx[1, :2]
    apx[1, :2] += 20 * 15.0 * np.array([-y, x]) / np.hypot(x, y)        # 20 sd across the ray
    lik = LaserLikelihood(ds.pixels, apx, sigma_px=0.5, sigma_scene=15.0,
                          point_prior="flat", outliers=True, outlier_scale=4.0)
    psi = np.append(ds.params.to_identifiable(), np.log(0.2 / 0.8))
    lm, q, C = lik.laplace(psi, apx[:, :2], n_iter=10)
    r = lik.outlier_prob(psi, apx[:, :2], n_iter=10)
    assert r[0] < 0.5 and r[1] > 0.99
    total = 0.0
    for i in range(2):
        sd = np.sqrt(np.diag(np.linalg.inv(C[i])))
        gx = q[i, 0] + np.linspace(-10, 10, 401) * sd[0]
        gy = q[i, 1] + np.linspace(-10, 10, 401) * sd[1]
        X, Y = np.meshgrid(gx, gy, indexing="ij")
        qq = np.repeat(q[None], X.size, 0)
        qq[:, i, 0], qq[:, i, 1] = X.ravel(), Y.ravel()
        f = np.exp(lik.point_log_density(psi, qq)[:, i]).reshape(X.shape)
        total += np.log(trapezoid(trapezoid(f, gy, axis=1), gx))
    np.testing.assert_allclose(lm, total, atol=0.01)


def _fit(ds, pixels=None, approx=None, **kw):
    kw.setdefault("sigma_px", None)
    return bc.calibrate_simultaneous(ds.pixels if pixels is None else pixels,
                                     ds.approx_points if approx is None else approx,
                                     sigma_scene=ds.sigma_scene, **kw)


@pytest.mark.parametrize("sigma_px", [None, 0.5])
def test_clean_data_map_unchanged(room, sigma_px):
    """On clean data the mixture's MAP and Laplace sds are the pure model's: means within
    0.1 sd, sds within 5 % (measured: 1e-5 sd and 1e-7), and no point flagged."""
    pure = _fit(room, sigma_px=sigma_px, outliers=False)
    mix = _fit(room, sigma_px=sigma_px)
    z = (mix.params.to_array() - pure.params.to_array()) / pure.std
    assert np.max(np.abs(z)) < 0.1
    np.testing.assert_allclose(mix.std, pure.std, rtol=0.05)
    assert np.all(mix.outlier_prob < 0.5)
    assert pure.outlier_prob is None


def test_clean_data_posterior_unchanged(room):
    """The collapsed posterior with the mixture is the pure one reweighted by
    ``exp(ll_mix - ll_pure)``; over draws from the Laplace posterior of theta, the
    reweighted means move < 0.1 sd and the sds < 5 %. w is held at the prior mean 0.05
    (the largest it plausibly takes on clean data; its posterior mean is ~0.002)."""
    pure = _fit(room, sigma_px=0.5, outliers=False)
    sol = pure.extras["map"]
    kw = dict(sigma_px=0.5, sigma_scene=room.sigma_scene)
    lp = LaserLikelihood(room.pixels, room.approx_points, **kw)
    lm = LaserLikelihood(room.pixels, room.approx_points, outliers=True, **kw)
    draws = np.random.default_rng(1).multivariate_normal(sol.theta, sol.cov_theta, 400)
    ll_p = lp.laplace(draws, sol.q, n_iter=3)[0]
    x = np.full((400, 1), np.log(0.05 / 0.95))
    ll_m = lm.laplace(np.hstack([draws, x]), sol.q, n_iter=3)[0]
    lw = ll_m - ll_p
    wts = np.exp(lw - lw.max())
    wts /= wts.sum()
    mean_p, sd_p = draws.mean(0), draws.std(0)
    mean_m = wts @ draws
    sd_m = np.sqrt(wts @ (draws - mean_m) ** 2)
    assert np.max(np.abs(mean_m - mean_p) / sd_p) < 0.1
    np.testing.assert_allclose(sd_m, sd_p, rtol=0.05)


@pytest.fixture(scope="module")
def clean_fit(room):
    return _fit(room)


def _gross_cases(ds):
    a1 = ds.approx_points.copy()
    a1[10, 0] += 5000.0                                   # approximate point off by 5 m
    a2 = ds.approx_points.copy()
    a2[20, 0] *= 10.0                                     # 10x typo in one x
    p3 = ds.pixels.copy()
    p3[[30, 300]] = p3[[300, 30]]                         # two swapped rows
    p4 = ds.pixels.copy()
    p4[40] = [200.0, 150.0]                               # a spurious pixel
    return {"off5000": (None, a1, [10]), "typo10x": (None, a2, [20]),
            "swapped": (p3, None, [30, 300]), "spurious": (p4, None, [40])}


@pytest.mark.parametrize("case", ["off5000", "typo10x", "swapped", "spurious"])
def test_gross_errors_flagged_and_harmless(room, clean_fit, case):
    """sigma_px inferred (the CLI default). The bad rows get outlier_prob > 0.5, at most
    1 % of the clean ones do, the parameters stay within 0.5 sd of the clean file's fit
    (measured <= 0.15 sd: one point of 580 less) and the clean rows' reconstruction error
    within 5 % of the clean fit's (measured < 0.1 %)."""
    pixels, approx, bad = _gross_cases(room)[case]
    clean = clean_fit
    res = _fit(room, pixels, approx)
    good = np.setdiff1d(np.arange(len(room.pixels)), bad)
    assert np.all(res.outlier_prob[bad] > 0.5)
    assert np.mean(res.outlier_prob[good] > 0.5) <= 0.01
    z = (res.params.to_array() - clean.params.to_array()) / clean.std
    assert np.max(np.abs(z[np.isfinite(z)])) < 0.5
    e = bc.reconstruction_error(res.points[good], room.points[good])
    e0 = bc.reconstruction_error(clean.points[good], room.points[good])
    assert e < 1.05 * e0
    assert abs(res.extras["noise"]["sigma_px"] / clean.extras["noise"]["sigma_px"] - 1) < 0.05
