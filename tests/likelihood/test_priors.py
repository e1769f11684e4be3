"""Priors: defaults, overrides, the phi-marginalised prior of theta, phi's conditional."""

import numpy as np
import pytest
from scipy import integrate, stats
from scipy.special import logsumexp

import bayescal as bc
from bayescal.likelihood.priors import Prior
from bayescal.sensor.parameters import PARAM_NAMES
from bayescal.stats.densities import (
    independent_log_density,
    log_density,
    log_survival,
    logsumexp_last,
)

PAPER = bc.SensorParams.paper()
THETA0 = PAPER.to_identifiable()


def _theta(d_gu=0.0, d_gv=0.0, xi=0.97):
    """theta near the paper's with relative shifts of gamma_u, gamma_v."""
    th = THETA0.copy()
    th[0] = xi
    th[1] *= 1 + d_gu
    th[2] *= 1 + d_gv
    return th


def _phi_integrand(prior, theta):
    """p_phi(phi) p_au(gu / s) p_av(gv / s) / s^2, s = xi + phi (the phi integrand)."""
    d = prior.dists
    xi, gu, gv = theta[:3]

    def f(phi):
        s = xi + phi
        return (d["phi"].pdf(phi) * d["alpha_u"].pdf(gu / s) * d["alpha_v"].pdf(gv / s)
                / s**2)

    return f


def _brute_logpdf_theta(prior, theta):
    d = prior.dists
    integral, _ = integrate.quad(_phi_integrand(prior, theta), -theta[0] + 1e-12, np.inf,
                                 epsabs=0, epsrel=1e-12, limit=200)
    return (np.log(integral) + d["xi"].logpdf(theta[0]) + d["u0"].logpdf(theta[3])
            + d["v0"].logpdf(theta[4]) + d["h"].logpdf(theta[5]) + d["beta"].logpdf(theta[6]))


# -- defaults and overrides ---------------------------------------------------------------


def test_default_prior_values_match_the_documented_table():
    prior = bc.default_prior()
    assert list(prior) == list(PARAM_NAMES)
    means = {n: float(d.mean()) for n, d in prior.items()}
    sds = {n: float(d.std()) for n, d in prior.items()}
    np.testing.assert_allclose([means[n] for n in PARAM_NAMES], PAPER.to_array(), rtol=1e-15)
    expected_sd = {"xi": 0.05, "phi": 0.1, "alpha_u": 5.5, "alpha_v": 5.5, "u0": 10.0,
                   "v0": 10.0, "h": 20.0, "beta": 0.05}
    for name in PARAM_NAMES:
        assert prior[name].dist.name == "norm"
        np.testing.assert_allclose(sds[name], expected_sd[name], rtol=1e-12, err_msg=name)


def test_default_prior_relative_tolerances_follow_the_nominal_design():
    nominal = bc.SensorParams(xi=0.8, phi=0.3, alpha_u=62.0, alpha_v=-48.0, u0=410.0,
                              v0=290.0, h=160.0, beta=1.1)
    prior = bc.default_prior(nominal)
    np.testing.assert_allclose([prior[n].mean() for n in PARAM_NAMES], nominal.to_array(),
                               rtol=1e-15)
    # alpha_u, alpha_v and h: 10 % of |design value|; the rest absolute
    np.testing.assert_allclose([prior[n].std() for n in ("alpha_u", "alpha_v", "h")],
                               [6.2, 4.8, 16.0], rtol=1e-12)
    np.testing.assert_allclose(prior["xi"].std(), 0.05, rtol=1e-12)


def test_prior_override_by_name_keeps_the_other_defaults():
    h_prior = stats.norm(150.0, 5.0)
    prior = Prior({"h": h_prior, "beta": stats.uniform(0.9, 0.3)})
    assert prior.dists["h"] is h_prior
    assert prior.dists["beta"].dist.name == "uniform"
    default = bc.default_prior()
    for name in set(PARAM_NAMES) - {"h", "beta"}:
        assert prior.dists[name].mean() == default[name].mean()
        assert prior.dists[name].std() == default[name].std()
    np.testing.assert_allclose(prior.std()[PARAM_NAMES.index("h")], 5.0, rtol=1e-12)
    assert prior.mean().h == 150.0
    # a Prior passed in again is taken as it is
    assert Prior(prior).dists["h"] is h_prior


def test_prior_rejects_unknown_names_and_non_distributions():
    with pytest.raises(ValueError, match=r"unknown parameter name.*'focal'"):
        Prior({"focal": stats.norm(1, 1)})
    with pytest.raises(TypeError, match=r"prior\['h'\] must be a scipy.stats frozen"):
        Prior({"h": 200.0})
    with pytest.raises(TypeError, match="prior must be a dict"):
        Prior([stats.norm(1, 1)])
    # an unfrozen distribution has logpdf/ppf/rvs too, but evaluates at loc=0, scale=1
    with pytest.raises(TypeError, match=r"prior\['xi'\] must be a frozen.*unfrozen 'norm'"):
        Prior({"xi": stats.norm})


def test_logpdf_paper_parameters_is_the_sum_of_the_marginals():
    prior = Prior()
    a = PAPER.to_array() + np.array([0.01, -0.05, 2.0, 1.0, -3.0, 4.0, 10.0, 0.02])
    expected = sum(prior.dists[n].logpdf(a[k]) for k, n in enumerate(PARAM_NAMES))
    np.testing.assert_allclose(prior.logpdf(a), expected, rtol=1e-13)
    np.testing.assert_allclose(prior.logpdf(np.stack([a, a])), [expected, expected], rtol=1e-13)


# -- the prior of theta with phi integrated out -------------------------------------------


@pytest.mark.parametrize("shift", [(0.0, 0.0), (0.1, 0.1), (-0.15, 0.05), (0.3, -0.2)],
                         ids=["design", "gamma+10%", "mixed", "gamma+30%/-20%"])
def test_logpdf_theta_matches_brute_force_integral(shift):
    """64 equal-probability nodes (midpoint rule in phi's quantile space) against adaptive
    quadrature: measured errors 2e-5 .. 1.8e-3 in log density over these points, falling
    about as n^-1.6 with the number of nodes, so 1024 nodes must be 30x closer."""
    theta = _theta(*shift)
    exact = _brute_logpdf_theta(Prior(), theta)
    np.testing.assert_allclose(Prior().logpdf_theta(theta), exact, rtol=0, atol=5e-3)
    np.testing.assert_allclose(Prior(n_phi=1024).logpdf_theta(theta), exact, rtol=0,
                               atol=1e-4)


@pytest.mark.xfail(strict=True, reason="the quantile-midpoint quadrature has no node beyond "
                   "~2.4 prior sd of phi: where the data put gamma 50 % off the design, phi's "
                   "conditional lies past the last node and log p(theta) is off by ~1.2")
def test_logpdf_theta_in_the_far_tail():
    theta = _theta(0.5, 0.5)
    np.testing.assert_allclose(Prior().logpdf_theta(theta),
                               _brute_logpdf_theta(Prior(), theta), rtol=0, atol=0.05)


def test_logpdf_theta_broadcasts_and_rejects_the_unphysical():
    prior = Prior()
    th = np.stack([_theta(), _theta(0.1, 0.1)])
    out = prior.logpdf_theta(th[None])                       # (1, 2, 7) -> (1, 2)
    assert out.shape == (1, 2)
    np.testing.assert_allclose(out[0], [prior.logpdf_theta(t) for t in th], rtol=1e-14)
    bad = np.stack([_theta()] * 3)
    bad[0, 5] = -1.0                  # h <= 0
    bad[1, 6] = 1.6                   # beta >= pi / 2
    bad[2, 6] = 0.0                   # beta <= 0
    assert np.all(prior.logpdf_theta(bad) == -np.inf)


# -- phi's conditional ----------------------------------------------------------------------


def _phi_conditional_cdf(prior, theta):
    """Exact conditional CDF of phi given theta: the integrand on a fine grid (400 001
    points over 12 prior sd), cumulative Simpson, then linear interpolation (error < 1e-7)."""
    f = _phi_integrand(prior, theta)
    lo = max(-theta[0] + 1e-9, float(prior.dists["phi"].ppf(1e-12)))
    x = np.linspace(lo, float(prior.dists["phi"].isf(1e-12)), 400_001)
    c = np.concatenate([[0.0], integrate.cumulative_simpson(f(x), x=x)])
    c /= c[-1]
    return lambda v: np.interp(v, x, c)


def _grid_cdf(prior, theta, x):
    """CDF that sample_phi samples exactly: the quadrature weights spread uniformly in
    probability within each of the n quantile cells of p_phi."""
    n = len(prior._phi_nodes)
    lp = prior._alpha_terms(theta[None], prior._phi_nodes)
    w = np.exp(lp[0] - lp[0].max())
    w /= w.sum()
    u = prior.dists["phi"].cdf(x) * n
    k = np.minimum(np.floor(u).astype(int), n - 1)
    return np.concatenate([[0.0], np.cumsum(w)])[k] + w[k] * (u - k)


@pytest.mark.parametrize("shift", [(0.0, 0.0), (0.12, 0.12)], ids=["design", "gamma+12%"])
def test_sample_phi_follows_the_exact_conditional(shift):
    """sample_phi draws exactly from a piecewise approximation of the conditional (the
    quadrature weights spread uniformly in probability within each quantile cell).

    Two checks: that piecewise CDF is within 0.005 of the exact conditional CDF
    (deterministic; measured 2e-4 at the design value, 0.004 at gamma + 12 %), and a K-S test
    of 20 000 draws against it, exact under the null: false-failure rate 1e-4 per case.
    """
    prior = Prior()
    theta = _theta(*shift)
    exact = _phi_conditional_cdf(prior, theta)
    grid = np.linspace(-0.5, 0.7, 1201)
    np.testing.assert_allclose(exact(grid[[0, -1]]), [0.0, 1.0], atol=1e-6)
    assert np.max(np.abs(_grid_cdf(prior, theta, grid) - exact(grid))) < 0.005
    draws = prior.sample_phi(np.tile(theta, (20000, 1)), rng=np.random.default_rng(7))
    assert draws.shape == (20000,)
    assert stats.kstest(draws, lambda v: _grid_cdf(prior, theta, v)).pvalue > 1e-4


def test_sample_phi_moves_with_gamma():
    """gamma 12 % above design: phi's conditional mean is pulled above its prior mean."""
    prior = Prior()
    up = prior.sample_phi(np.tile(_theta(0.12, 0.12, xi=1.0), (4000, 1)), rng=1).mean()
    down = prior.sample_phi(np.tile(_theta(-0.12, -0.12, xi=1.0), (4000, 1)), rng=1).mean()
    assert up > 0.03 > -0.03 > down


# -- sampling the prior --------------------------------------------------------------------


def test_prior_sample_is_truncated_to_the_physical_domain():
    """h ~ N(10, 20) truncated to h > 0 and beta ~ N(1.5, 0.1) to beta < pi/2: K-S of the
    draws against scipy's truncated normals (alpha = 1e-4 each, two tests)."""
    prior = Prior({"h": stats.norm(10.0, 20.0), "beta": stats.norm(1.5, 0.1)})
    a = prior.sample(5000, rng=np.random.default_rng(3))
    assert a.shape == (5000, 8)
    h, beta = a[:, 6], a[:, 7]
    assert np.all(h > 0) and np.all((beta > 0) & (beta < np.pi / 2))
    assert np.all(a[:, 0] + a[:, 1] > 0)
    h_exact = stats.truncnorm((0 - 10.0) / 20.0, np.inf, loc=10.0, scale=20.0)
    b_exact = stats.truncnorm(-np.inf, (np.pi / 2 - 1.5) / 0.1, loc=1.5, scale=0.1)
    assert stats.kstest(h, h_exact.cdf).pvalue > 1e-4
    assert stats.kstest(beta, b_exact.cdf).pvalue > 1e-4


def test_prior_sample_shapes_and_seeding():
    prior = Prior()
    assert prior.sample(rng=0).shape == (8,)
    assert prior.sample((3, 4), rng=0).shape == (3, 4, 8)
    np.testing.assert_array_equal(prior.sample(10, rng=5), prior.sample(10, rng=5))
    assert not np.array_equal(prior.sample(10, rng=5), prior.sample(10, rng=6))


def test_prior_sample_without_physical_mass_raises():
    prior = Prior({"h": stats.norm(-1000.0, 1.0)})
    with pytest.raises(RuntimeError, match="almost no mass on physical parameters"):
        prior.sample(3, rng=0)


# -- least-squares form --------------------------------------------------------------------


def test_residuals_are_exact_for_normal_priors():
    prior = Prior()
    a = PAPER.to_array() + np.array([0.02, -0.1, 3.0, -2.0, 5.0, -7.0, 15.0, 0.03])
    r, J = prior.residuals(a, jacobian=True)
    mu = np.array([prior.dists[n].mean() for n in PARAM_NAMES])
    sd = prior.std()
    np.testing.assert_allclose(r, (a - mu) / sd, rtol=1e-14)
    np.testing.assert_allclose(J, np.diag(1.0 / sd), rtol=1e-14)
    # 0.5 |r|^2 is exactly the negative log density up to its constant
    np.testing.assert_allclose(0.5 * r @ r, prior.logpdf(mu) - prior.logpdf(a), rtol=1e-12)
    np.testing.assert_array_equal(prior.residuals(a), r)


def test_residuals_of_a_non_normal_prior(numdiff):
    """Other distributions: 0.5 r^2 = log p(median) - log p(a), and the derivative is right."""
    prior = Prior({"h": stats.lognorm(0.1, scale=200.0)})
    k = PARAM_NAMES.index("h")
    d = prior.dists["h"]
    for h in (150.0, 230.0):
        a = PAPER.to_array()
        a[k] = h
        r, J = prior.residuals(a, jacobian=True)
        np.testing.assert_allclose(0.5 * r[k] ** 2, d.logpdf(d.median()) - d.logpdf(h),
                                   rtol=1e-10)
        assert np.sign(r[k]) == np.sign(h - d.median())

        def rk(x, a=a):
            b = a.copy()
            b[k] = x[0]
            return prior.residuals(b)[k:k + 1]

        np.testing.assert_allclose(J[k, k], numdiff(rk, np.array([h]), 1e-3)[0, 0], rtol=1e-5)


# -- closed-form densities: the same values as scipy's ------------------------------------
# The prior's densities are closed-form numpy (bayescal.stats.densities) for the common
# families; these references are the same formulas through scipy's frozen distributions.
# Tolerance: rounding only (a few ulps of terms of size <= ~1e3), hence rtol 1e-12.

_OVERRIDES = {   # one of each closed-form family, and two scipy fallbacks (t, gamma)
    "xi": stats.uniform(0.9, 0.2),
    "phi": stats.truncnorm(-2.0, 1.5, loc=0.0, scale=0.1),
    "alpha_u": stats.lognorm(0.1, loc=0.0, scale=55.0),
    "alpha_v": stats.truncnorm(a=-3.0, b=3.0, loc=-55.0, scale=6.0),
    "u0": stats.t(4, loc=400.0, scale=10.0),
    "v0": stats.uniform(loc=280.0, scale=40.0),
    "h": stats.lognorm(s=0.1, scale=200.0),
    "beta": stats.truncnorm((0.9 - np.pi / 3) / 0.05, (1.2 - np.pi / 3) / 0.05,
                            loc=np.pi / 3, scale=0.05),
}
_CAMERA = (THETA0[:5], np.diag([0.03, 2.0, 2.0, 5.0, 5.0]) ** 2 + 1e-4)


def _scipy_logpdf_theta(prior, theta):
    """The phi-integrated prior of theta through scipy's logpdf, logsf and logsumexp."""
    d = prior.dists
    th = np.asarray(theta, dtype=float)
    ok = (th[..., 5] > 0) & (th[..., 6] > 0) & (th[..., 6] < np.pi / 2)
    if prior.camera is not None:
        mvn = stats.multivariate_normal(*prior.camera)
        out = (mvn.logpdf(th[..., :5]) + d["h"].logpdf(th[..., 5]) + d["beta"].logpdf(th[..., 6])
               + d["phi"].logsf(-th[..., 0]))
    else:
        out = sum(d[n].logpdf(th[..., k]) for k, n in ((0, "xi"), (3, "u0"), (4, "v0"),
                                                        (5, "h"), (6, "beta")))
        s = th[..., 0:1] + prior._phi_nodes
        with np.errstate(divide="ignore", invalid="ignore"):
            lp = (d["alpha_u"].logpdf(th[..., 1:2] / s) + d["alpha_v"].logpdf(th[..., 2:3] / s)
                  - 2.0 * np.log(s))
        lp = np.where(s > 0, lp, -np.inf)
        out = out + logsumexp(lp - np.log(lp.shape[-1]), axis=-1)
    return np.where(ok & np.isfinite(out), out, -np.inf)


def _random_thetas(rng, n, spread):
    """Thetas around the paper's, relative spread ``spread``: some outside every support."""
    th = THETA0 * (1 + spread * rng.standard_normal((n, 7)))
    th[::7, 0] = -0.5           # xi + phi < 0 at most nodes
    th[1::11, 5] = -10.0        # h < 0
    th[2::13, 6] = 2.0          # beta > pi/2
    return th


def _assert_same(got, want):
    got, want = np.asarray(got), np.asarray(want)
    np.testing.assert_array_equal(np.isneginf(got), np.isneginf(want))
    np.testing.assert_array_equal(np.isnan(got), np.isnan(want))
    fin = np.isfinite(want)
    np.testing.assert_allclose(got[fin], want[fin], rtol=1e-12, atol=0)


@pytest.mark.parametrize("kind", ["default", "overrides", "camera", "camera_overrides"])
def test_logpdf_theta_equals_scipy_inside_and_outside_the_support(kind):
    over = {k: v for k, v in _OVERRIDES.items() if k in ("phi", "h", "beta")}
    prior = {"default": lambda: Prior(), "overrides": lambda: Prior(_OVERRIDES),
             "camera": lambda: Prior(camera=_CAMERA),
             "camera_overrides": lambda: Prior(over, camera=_CAMERA)}[kind]()
    rng = np.random.default_rng(31)
    # the overrides' bounded supports leave few finite values beyond a 10 % spread
    for spread in (0.01, 0.05, 0.1) + ((0.3,) if kind != "overrides" else ()):
        th = _random_thetas(rng, 200, spread)
        want = _scipy_logpdf_theta(prior, th)
        assert np.isfinite(want).sum() > 20 and np.isneginf(want).sum() > 20
        _assert_same(prior.logpdf_theta(th), want)
        _assert_same(prior.logpdf_theta(th[:32].reshape(4, 8, 7)), want[:32].reshape(4, 8))
        _assert_same(prior.logpdf_theta(th[3]), want[3])
        _assert_same(prior.logpdf_theta(th[3:4]), want[3:4])


def test_logpdf_and_pose_logpdf_equal_scipy_with_overrides():
    pose = {"tilt_x": stats.uniform(-0.1, 0.2), "offset_y": stats.lognorm(0.5, loc=-10.0)}
    prior = Prior({**_OVERRIDES, **pose})
    rng = np.random.default_rng(32)
    a = PAPER.to_array() * (1 + 0.08 * rng.standard_normal((300, 8)))
    a[:, 1] = 0.15 * rng.standard_normal(300)      # phi's design value is 0
    want = sum(prior.dists[n].logpdf(a[:, k]) for k, n in enumerate(PARAM_NAMES))
    assert np.isfinite(want).sum() > 20 and np.isneginf(want).sum() > 20
    _assert_same(prior.logpdf(a), want)
    p = 0.1 * rng.standard_normal((300, 4)) * [1, 1, 100, 100]
    want = sum(prior.pose_dists[n].logpdf(p[:, k])
               for k, n in enumerate(("tilt_x", "tilt_y", "offset_x", "offset_y")))
    assert np.isfinite(want).sum() > 20 and np.isneginf(want).sum() > 20
    _assert_same(prior.logpdf_pose(p), want)


@pytest.mark.parametrize("dist", [
    stats.norm(3.0, 0.2), stats.norm(loc=-1e3, scale=50.0), stats.uniform(-1.0, 3.0),
    stats.truncnorm(-0.5, 2.0, loc=1.0, scale=2.0), stats.truncnorm(1.0, np.inf),
    stats.lognorm(0.7), stats.lognorm(1.3, loc=-2.0, scale=4.0), stats.gamma(2.0, scale=3.0),
])
def test_log_density_and_survival_equal_scipy(dist):
    rng = np.random.default_rng(33)
    lo, hi = dist.ppf([1e-6, 1 - 1e-6])
    x = np.concatenate([rng.uniform(lo - (hi - lo), hi + (hi - lo), 500), dist.support(),
                        [np.nan, -np.inf, np.inf]])
    with np.errstate(all="ignore"):
        _assert_same(log_density(dist)(x), dist.logpdf(x))
        _assert_same(log_survival(dist)(x[np.isfinite(x)]), dist.logsf(x[np.isfinite(x)]))
    _assert_same(log_density(dist)(x[:50].reshape(5, 10)), dist.logpdf(x[:50]).reshape(5, 10))
    mixed = [dist, stats.norm(1.0, 2.0), stats.norm(-3.0, 0.5)]
    xs = rng.standard_normal((6, 4, 5)) * 3
    want = sum(d.logpdf(xs[..., c]) for d, c in zip(mixed, (4, 0, 2), strict=True))
    _assert_same(independent_log_density(mixed, [4, 0, 2])(xs), want)


def test_logsumexp_last_equals_scipy():
    rng = np.random.default_rng(34)
    a = 300 * rng.standard_normal((5, 3, 64))
    a[0, 0] = -np.inf                     # a row all -inf
    a[1, :, ::2] = -np.inf
    a[2, 1, 5] = 800.0                    # one term far above the rest
    _assert_same(logsumexp_last(a), logsumexp(a, axis=-1))
