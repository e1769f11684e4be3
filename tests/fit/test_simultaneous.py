"""Simultaneous least squares (paper section III; rung 2 of the validation ladder, stated in
docs/calibration.md, "Checks of the least squares")."""

import numpy as np
import pytest
from scipy import optimize, stats

import bayescal as bc
from bayescal.sensor.parameters import IDENTIFIABLE_NAMES

PAPER = bc.SensorParams.paper()
# a sensor away from the design values in every parameter (the priors pull it)
OTHER = bc.SensorParams(xi=0.95, phi=0.05, alpha_u=58.0, alpha_v=-52.0, u0=405.0, v0=296.0,
                        h=215.0, beta=1.0)


def _wide_prior(factor):
    """The default priors (centred on the paper's design) with sd multiplied by ``factor``."""
    return {n: stats.norm(d.mean(), d.std() * factor) for n, d in bc.default_prior().items()}


def _perturbed_starts(params, n, rng):
    """``n`` starts with every parameter off by up to +-10 % (phi, near 0: +-0.1)."""
    out = []
    for _ in range(n):
        a = params.to_array() * (1 + rng.uniform(-0.1, 0.1, 8))
        a[1] = params.phi + rng.uniform(-0.1, 0.1)
        out.append(bc.SensorParams.from_array(a))
    return out


def _exact_room(params, range_mm, n_points):
    return bc.simulate_room(params, range_mm=range_mm, n_points=n_points, sigma_px=0.0,
                            approx_error=0.0, approx_model="gaussian", rng=1)


# -- noise-free recovery --------------------------------------------------------------------


@pytest.mark.parametrize("range_mm", [1000, 5000])
def test_noise_free_recovery_from_20_random_starts(range_mm, rng):
    """Exact pixels and exact approximate points: the 7 identifiable parameters come back to
    1e-6 relative and every point to 1e-6 of the range, from all 20 starts.

    The true sensor is away from the design, so the priors (sd x 1000 here) pull the solution
    by (prior gradient) / (data information) ~ 2e-10 relative (measured; the pull falls as
    the factor squared: 2e-8 at x 100). With the default priors it is 9e-5 (the MAP is not
    the truth then, by construction).
    """
    ds = _exact_room(OTHER, range_mm, 100)
    theta = OTHER.to_identifiable()
    prior = _wide_prior(1000.0)
    for init in _perturbed_starts(OTHER, 20, rng):
        res = bc.calibrate_simultaneous(ds.pixels, ds.approx_points, sigma_px=1e-3,
                                        sigma_scene=1.0, prior=prior, init=init)
        assert res.converged
        np.testing.assert_allclose(res.extras["theta"], theta, rtol=1e-6, atol=0)
        np.testing.assert_allclose(res.params.to_identifiable(), theta, rtol=1e-6, atol=0)
        # the paper's 3N + 8 unknowns: the jointly estimated points are the true ones
        np.testing.assert_allclose(res.points, ds.points, rtol=0, atol=1e-6 * range_mm)
        assert res.points.shape == (100, 3)
        assert res.extras["point_covariance"].shape == (100, 3, 3)


def test_noise_free_recovery_at_the_design_values_with_default_priors(rng):
    """Truth at the prior means: the default priors do not pull, recovery is exact (5 starts;
    the 20-start test above is the demanding one)."""
    ds = _exact_room(PAPER, 5000, 60)
    for init in _perturbed_starts(PAPER, 5, rng):
        res = bc.calibrate_simultaneous(ds.pixels, ds.approx_points, sigma_px=1e-3,
                                        sigma_scene=1.0, init=init)
        np.testing.assert_allclose(res.params.to_array(), PAPER.to_array(), rtol=1e-6,
                                   atol=1e-9)
        np.testing.assert_allclose(res.points, ds.points, rtol=0, atol=1e-3)


def test_fixed_points_variant_recovers_the_truth_on_exact_points(rng):
    """estimate_points=False: the points are taken as exact and only theta is fitted."""
    ds = _exact_room(OTHER, 1000, 100)
    theta = OTHER.to_identifiable()
    for init in _perturbed_starts(OTHER, 5, rng):
        res = bc.calibrate_simultaneous(ds.pixels, ds.points, sigma_px=1e-3, sigma_scene=1.0,
                                        prior=_wide_prior(1000.0), init=init,
                                        estimate_points=False)
        assert res.converged and res.n_unknowns == 7
        np.testing.assert_allclose(res.extras["theta"], theta, rtol=1e-6, atol=0)
        # the points returned are the triangulated pixels
        np.testing.assert_allclose(res.points, ds.points, rtol=0, atol=1e-3)


# -- covariance against re-fits (rung 2: docs/calibration.md, "Checks of the least squares") --

#: the re-fit setting: small room, 100 points, 0.3 px, 2 % Gaussian approximate points.
#: Priors x 1000 wider than the default: the Laplace covariance of a MAP with informative
#: priors is the *posterior's* and is wider than the spread of re-fits by ~28 % (measured on
#: xi, gamma, h, beta with the default priors), which is correct Bayesian behaviour, not a
#: miscalibrated covariance; with weak priors both must agree.
REFIT = {"range_mm": 1000, "n_points": 100, "sigma_px": 0.3, "approx_error": 0.02}


def _refits(m, seed0):
    prior = _wide_prior(1000.0)
    thetas, covs, points, pcovs, sig_hat, dof = [], [], [], [], [], None
    flags = []
    for k in range(m):
        ds = bc.simulate_room(PAPER, approx_model="gaussian", rng=seed0 + k, **REFIT)
        res = bc.calibrate_simultaneous(ds.pixels, ds.approx_points, sigma_px=REFIT["sigma_px"],
                                        sigma_scene=ds.sigma_scene, prior=prior)
        thetas.append(res.extras["theta"])
        covs.append(res.covariance_identifiable)
        points.append(res.points)
        pcovs.append(res.extras["point_covariance"])
        sig_hat.append(res.sigma_px_estimated)
        flags.append(np.zeros(len(res.points), bool) if res.outlier_prob is None
                     else np.asarray(res.outlier_prob) > 0.5)
        dof = res.n_residuals - res.n_unknowns
    # flags (m, N): the rows each fit set aside as outliers
    return (np.array(thetas), np.array(covs), np.array(points), np.array(pcovs),
            np.array(sig_hat), dof, np.array(flags))


def _point_direction_variances(points, pcovs, idx, flags=None):
    """Per point in ``idx``: sample variance of the re-fitted points along each eigenvector
    of the (re-fit averaged) predicted 3x3 covariance, and the eigenvalues; with ``flags``
    (m, N), each point over the re-fits that did not set it aside as an outlier (a row set
    aside keeps only what the pixel says of its point: its covariance is not the claim)."""
    if flags is not None:
        out = [_point_direction_variances(points[~flags[:, i]], pcovs[~flags[:, i]], [i])
               for i in idx]
        return np.concatenate([v for v, _ in out]), np.concatenate([e for _, e in out])
    e, V = np.linalg.eigh(pcovs[:, idx].mean(axis=0))               # (k, 3), (k, 3, 3)
    d = points[:, idx] - points[:, idx].mean(axis=0)
    proj = np.einsum("kji,mkj->mki", V, d)
    return proj.var(axis=0, ddof=1), e


def _sd_ratio_band(m, n_tests, ffr):
    """Two-sided band of (sample sd / true sd) over ``m`` draws: sqrt(chi2(m - 1) / (m - 1))
    quantiles, Bonferroni over ``n_tests`` at a total false-failure rate ``ffr``."""
    a = ffr / n_tests
    return (np.sqrt(stats.chi2.ppf(a / 2, m - 1) / (m - 1)),
            np.sqrt(stats.chi2.ppf(1 - a / 2, m - 1) / (m - 1)))


def test_covariance_matches_the_spread_of_refits_fast():
    """40 re-fits over fresh pixel and scene noise.

    Each observed sd (7 parameters, and 3 eigen-directions of 5 points) is a sample sd of 40
    draws, so (observed / predicted)^2 ~ chi2(39) / 39 if the prediction is right; the band
    of that ratio, Bonferroni over the 22 checks, has a total false-failure rate of 1e-3
    (it spans about 0.62-1.46, so this fast test only catches gross errors: the 20 % check
    is the slow one). The estimated pixel noise of each fit must lie in its chi-square band
    (dof = residuals - unknowns; FFR 1e-3 over the 40 fits).
    """
    m = 40
    thetas, covs, points, pcovs, sig_hat, dof, _ = _refits(m, seed0=5000)
    idx = np.arange(0, REFIT["n_points"], REFIT["n_points"] // 5)
    lo, hi = _sd_ratio_band(m, 7 + 3 * len(idx), 1e-3)
    pred = np.sqrt(np.diag(covs.mean(axis=0)))
    ratio = thetas.std(axis=0, ddof=1) / pred
    assert np.all((ratio > lo) & (ratio < hi)), dict(zip(IDENTIFIABLE_NAMES, ratio, strict=True))
    var, e = _point_direction_variances(points, pcovs, idx)
    pr = np.sqrt(var / e)
    assert np.all((pr > lo) & (pr < hi)), pr
    a = 1e-3 / m
    s_lo, s_hi = (np.sqrt(stats.chi2.ppf(q, dof) / dof) for q in (a / 2, 1 - a / 2))
    r = sig_hat / REFIT["sigma_px"]
    assert np.all((r > s_lo) & (r < s_hi)), (r.min(), r.max(), s_lo, s_hi)


@pytest.mark.slow
def test_covariance_matches_the_spread_of_refits_within_20_percent():
    """Rung 2 (docs/calibration.md, "Checks of the least squares"): 200 re-fits; predicted sd
    within 20 % of the observed spread for every identifiable parameter and every point's 3
    eigen-directions (sample-sd noise at 200 draws is 5 %, so 20 % is 4 standard errors:
    FFR ~6e-5 per check before the 7 + 300 checks; measured ratios 0.93-1.11 for theta,
    0.86-1.15 over the points).

    The fit starts robust-first and sets aside a row whose misfit has p < 1e-4 (about 0.03
    rows a clean file of 300; 6 expected over these 60 000 rows): such a row's point is
    compared over the other re-fits only (one of 200 set row 71 aside: its averaged
    predicted covariance, 900 mm along the ray, made its ratio 0.13), and the rows set aside
    must be no more than the cut allows (at most 20, Poisson's 1e-5 tail at a mean of 6)."""
    thetas, covs, points, pcovs, _, _, flags = _refits(200, seed0=1000)
    assert flags.sum() <= 20, np.argwhere(flags)
    pred = np.sqrt(np.diag(covs.mean(axis=0)))
    np.testing.assert_allclose(thetas.std(axis=0, ddof=1), pred, rtol=0.2)
    var, e = _point_direction_variances(points, pcovs, np.arange(REFIT["n_points"]), flags)
    np.testing.assert_allclose(np.sqrt(var / e), 1.0, rtol=0.2)


def test_estimated_pixel_noise_within_10_percent():
    """mrcal's check: sigma from the residuals, RMS / sqrt(1 - unknowns / residuals).
    580 points: dof = 3N + 1 = 1741, relative sd 1 / sqrt(2 dof) = 1.7 %, so the 10 % bound
    is ~6 sd (FFR ~1e-9)."""
    ds = bc.simulate_room(range_mm=1000, sigma_px=0.3, approx_error=0.02,
                          approx_model="gaussian", rng=21)
    res = bc.calibrate_simultaneous(ds.pixels, ds.approx_points, sigma_px=0.3,
                                    sigma_scene=ds.sigma_scene)
    np.testing.assert_allclose(res.sigma_px_estimated, 0.3, rtol=0.1)


# -- priors at large range, identifiability ------------------------------------------------------


def test_large_room_needs_the_priors():
    """Fact 3 (docs/model.md, "Measured facts": least squares needs priors at large range)
    on the paper's protocol (fig9 approximate points: no z information,
    5000 mm, 5 %, 0.1 px). With priors of sd x 10^4 (practically none) the solver wanders off
    along the beta/h direction the data cannot fix (measured: h = 463 mm, beta = 0.78, no
    convergence in 200 iterations); with the default priors it converges and every
    identifiable parameter is within 4 of its standard deviations of the truth."""
    ds = bc.simulate_room(range_mm=5000, sigma_px=0.1, approx_error=0.05, rng=3)
    sigma_scene = np.maximum(ds.sigma_scene, 1.0)
    bad = bc.calibrate_simultaneous(ds.pixels, ds.approx_points, sigma_px=0.1,
                                    sigma_scene=sigma_scene, prior=_wide_prior(1e4),
                                    raise_on_failure=False)
    assert (not bad.converged) or abs(bad.params.h - PAPER.h) > 100.0
    good = bc.calibrate_simultaneous(ds.pixels, ds.approx_points, sigma_px=0.1,
                                     sigma_scene=sigma_scene)
    assert good.converged
    z = (good.extras["theta"] - PAPER.to_identifiable()) / np.sqrt(
        np.diag(good.covariance_identifiable))
    assert np.all(np.abs(z) < 4), dict(zip(IDENTIFIABLE_NAMES, z, strict=True))
    # the data alone leave a second near-null direction, dominated by beta
    dirs = [set(d["components"]) for d in good.identifiability.null_directions]
    assert any("beta" in d for d in dirs)


def test_identifiability_report_names_the_phi_alpha_ridge():
    ds = bc.simulate_room(range_mm=1000, n_points=100, sigma_px=0.3, approx_error=0.02,
                          approx_model="gaussian", rng=2)
    res = bc.calibrate_simultaneous(ds.pixels, ds.approx_points, sigma_px=0.3,
                                    sigma_scene=ds.sigma_scene)
    nulls = res.identifiability.null_directions
    assert len(nulls) == 1
    assert set(nulls[0]["components"]) == {"phi", "alpha_u", "alpha_v"}
    text = res.summary()
    assert "not determined by the data" in text and "phi" in text
    # the data do not see phi: at the MAP it minimises the prior alone along the ridge
    # (theta fixed), and its sd is the ridge's, 1 / sqrt(1/0.1^2 + 2 (55 / 5.5)^2) = 0.0577
    theta = res.extras["theta"]
    prior = bc.Prior()
    phi = optimize.minimize_scalar(
        lambda f: -prior.logpdf(bc.SensorParams.from_identifiable(theta, f).to_array()),
        bracket=(-0.1, 0.1), tol=1e-12).x
    np.testing.assert_allclose(res.params.phi, phi, rtol=0, atol=1e-6)
    s = theta[0] + res.params.phi
    ridge_sd = 1 / np.sqrt(1 / 0.1**2 + (res.params.alpha_u / s / 5.5) ** 2
                           + (res.params.alpha_v / s / 5.5) ** 2)
    np.testing.assert_allclose(res.std[1], ridge_sd, rtol=0.01)


# -- inferred noise levels --------------------------------------------------------------------


def _matched_room(range_mm, n_points, sigma_px, kappa, seed):
    """Data from the model's own inferred-noise likelihood: scene sd = kappa * rho per axis."""
    ds = _exact_room(PAPER, range_mm, n_points)
    rng = np.random.default_rng(seed)
    rho = np.hypot(ds.points[:, 0], ds.points[:, 1])
    pixels = ds.pixels + sigma_px * rng.standard_normal(ds.pixels.shape)
    approx = ds.points + kappa * rho[:, None] * rng.standard_normal(ds.points.shape)
    return pixels, approx


def test_inferred_noise_recovers_the_simulated_levels():
    """sigma_px = None and sigma_scene = None on data simulated from that model.

    The noise levels maximise the collapsed likelihood at the MAP; that estimator has no
    closed-form variance, so its spread was measured: 30 replications of this setting
    (1000 mm, 300 points, 0.3 px, kappa 0.02) gave means 0.961 and 1.004 of the truth and
    sd 8.5 % (sigma_px) and 3.3 % (kappa). Bounds of 4 of those sd (34 %, 13.2 %): FFR
    ~1e-4 if the estimates are Gaussian. See the slow test for a t-test on the mean.
    """
    pixels, approx = _matched_room(1000, 300, 0.3, 0.02, seed=8)
    res = bc.calibrate_simultaneous(pixels, approx, sigma_px=None, sigma_scene=None)
    noise = res.extras["noise"]
    np.testing.assert_allclose(noise["sigma_px"], 0.3, rtol=4 * 0.085)
    np.testing.assert_allclose(noise["kappa"], 0.02, rtol=4 * 0.033)


@pytest.mark.slow
def test_inferred_noise_is_unbiased_over_replications():
    """20 replications: the mean estimate of each noise level within t(19) at 0.9995 of the
    truth (two-sided FFR 1e-3 per level)."""
    est = []
    for k in range(20):
        pixels, approx = _matched_room(1000, 300, 0.3, 0.02, seed=100 + k)
        noise = bc.calibrate_simultaneous(pixels, approx, sigma_px=None,
                                          sigma_scene=None).extras["noise"]
        est.append((noise["sigma_px"] / 0.3, noise["kappa"] / 0.02))
    est = np.array(est)
    half = stats.t.ppf(1 - 5e-4, len(est) - 1) * est.std(axis=0, ddof=1) / np.sqrt(len(est))
    assert np.all(np.abs(est.mean(axis=0) - 1.0) < half), (est.mean(axis=0), half)


# -- bad input -------------------------------------------------------------------------------


@pytest.fixture(scope="module")
def small():
    return bc.simulate_room(range_mm=1000, n_points=40, sigma_px=0.3, approx_error=0.02,
                            approx_model="gaussian", rng=4)


def _fit(ds, **kw):
    kw.setdefault("sigma_px", 0.3)
    kw.setdefault("sigma_scene", ds.sigma_scene)
    pixels = kw.pop("pixels", ds.pixels)
    approx = kw.pop("approx", ds.approx_points)
    return bc.calibrate_simultaneous(pixels, approx, **kw)


def test_too_few_points_raises(small):
    with pytest.raises(ValueError, match=r"at least 4 laser points, got N=3"):
        _fit(small, pixels=small.pixels[:3], approx=small.approx_points[:3],
             sigma_scene=small.sigma_scene[:3])


def test_points_at_one_azimuth_raise(small):
    pixels = np.repeat(small.pixels[:1], 10, axis=0) + np.linspace(0, 0.01, 10)[:, None]
    approx = np.repeat(small.approx_points[:1], 10, axis=0)
    with pytest.raises(ValueError, match="one azimuth"):
        _fit(small, pixels=pixels, approx=approx, sigma_scene=1.0)


def test_non_finite_and_mismatched_input_raise(small):
    pixels = small.pixels.copy()
    pixels[3, 1] = np.nan
    with pytest.raises(ValueError, match=r"pixels must contain only finite values; rows 3 "):
        _fit(small, pixels=pixels)
    approx = small.approx_points.copy()
    approx[0, 2] = np.inf
    with pytest.raises(ValueError, match="approx_points must contain only finite"):
        _fit(small, approx=approx)
    with pytest.raises(ValueError, match=r"same length N, got \(40, 2\) and \(39, 3\)"):
        _fit(small, approx=small.approx_points[:39], sigma_scene=1.0)
    with pytest.raises(ValueError, match=r"shape \(\.\.\., 2\)"):
        _fit(small, pixels=small.approx_points)
    with pytest.raises(ValueError, match=r"broadcastable to \(N, 3\)"):
        _fit(small, sigma_scene=np.ones(5))
    with pytest.raises(ValueError, match="sigma_scene must be positive"):
        _fit(small, sigma_scene=-1.0)
    with pytest.raises(ValueError, match="sigma_px must be a finite positive"):
        _fit(small, sigma_px=0.0)


def test_bad_prior_and_init_raise(small):
    with pytest.raises(ValueError, match=r"unknown parameter name\(s\) \['focal'\]"):
        _fit(small, prior={"focal": stats.norm(1, 1)})
    with pytest.raises(TypeError, match=r"prior\['h'\] must be a scipy.stats frozen"):
        _fit(small, prior={"h": (200.0, 20.0)})
    with pytest.raises(TypeError, match="init must be a SensorParams or None, got dict"):
        _fit(small, init=PAPER.as_dict())
    with pytest.raises(ValueError, match="estimate_points=False needs sigma_px and sigma_scene"):
        _fit(small, sigma_px=None, estimate_points=False)


def test_offset_sd_adds_to_the_principal_point_only():
    # a translation shared by every pixel is a shift of (u0, v0): the fit is unchanged and
    # offset_sd**2 is added to their variances, nothing else (exact to rounding)
    ds = bc.simulate_room(range_mm=1000, n_points=60, sigma_px=0.3, approx_error=0.02,
                          approx_model="gaussian", rng=5)
    a = bc.calibrate_simultaneous(ds.pixels, ds.approx_points, sigma_px=0.3,
                                  sigma_scene=ds.sigma_scene)
    b = bc.calibrate_simultaneous(ds.pixels, ds.approx_points, sigma_px=0.3,
                                  sigma_scene=ds.sigma_scene, offset_sd=0.05)
    np.testing.assert_array_equal(b.params.to_array(), a.params.to_array())
    extra = np.zeros((7, 7))
    extra[3, 3] = extra[4, 4] = 0.05 ** 2
    np.testing.assert_allclose(b.covariance_identifiable - a.covariance_identifiable, extra,
                               atol=1e-15)
    assert b.extras["offset_sd"] == 0.05 and a.extras["offset_sd"] == 0.0
    d8 = b.covariance() - a.covariance()
    np.testing.assert_allclose(np.diag(d8), [0, 0, 0, 0, 0.05 ** 2, 0.05 ** 2, 0, 0], atol=1e-15)
    with pytest.raises(ValueError, match="offset_sd"):
        bc.calibrate_simultaneous(ds.pixels, ds.approx_points, sigma_px=0.3,
                                  sigma_scene=ds.sigma_scene, offset_sd=-1.0)


def test_an_unconverged_fit_carries_the_offset_too():
    # the command line saves the result a ConvergenceError carries: it must hold the offset
    # like a converged one, on approximate points and on a floor plan
    ds = bc.simulate_room(range_mm=1000, n_points=60, sigma_px=0.3, approx_error=0.02,
                          approx_model="wall", rng=5)
    for data, kw in ((ds.approx_points, {"sigma_scene": ds.sigma_scene}), (ds.floor_plan, {})):
        with pytest.raises(bc.ConvergenceError) as info:
            bc.calibrate_simultaneous(ds.pixels, data, sigma_px=0.3, max_iter=1,
                                      offset_sd=0.05, **kw)
        res = info.value.result
        assert res.extras["offset_sd"] == 0.05
        assert np.all(np.diag(res.covariance_identifiable)[3:5] >= 0.05 ** 2)
