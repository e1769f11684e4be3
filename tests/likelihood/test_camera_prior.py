"""The camera's prior: a camera calibration's intrinsics and covariance as one correlated
normal on (xi, gamma_u, gamma_v, u0, v0), phi keeping its own prior."""

import numpy as np
import pytest
from scipy import stats

import bayescal as bc
from bayescal.likelihood.priors import Prior, as_prior
from bayescal.sensor.parameters import (
    CAMERA_NAMES,
    camera_moments,
    from_identifiable,
    identifiable_jacobian,
)

PAPER = bc.SensorParams.paper()
THETA0 = PAPER.to_identifiable()
SD = np.array([0.004, 0.6, 0.6, 0.4, 0.4])
CORR = np.array([[1.0, 0.9, 0.9, 0.0, 0.0],
                 [0.9, 1.0, 0.8, 0.1, 0.0],
                 [0.9, 0.8, 1.0, 0.0, -0.1],
                 [0.0, 0.1, 0.0, 1.0, 0.2],
                 [0.0, 0.0, -0.1, 0.2, 1.0]])
COV = CORR * np.outer(SD, SD)


class StandInCamera:
    """What a camera calibration offers the laser stage: ``intrinsics`` and ``covariance()``
    (its first five rows in CAMERA_NAMES' order; here with two pose rows after them)."""

    def __init__(self, mean, cov):
        self.intrinsics = dict(zip(CAMERA_NAMES, mean, strict=True))
        self._cov = np.pad(cov, ((0, 2), (0, 2))) + np.diag([0.0] * 5 + [1.0, 1.0])

    def covariance(self):
        return self._cov


def _camera(mean=None):
    return StandInCamera(THETA0[:5] if mean is None else mean, COV)


def test_camera_moments_read_a_calibration_or_a_pair():
    m, c = camera_moments(_camera())
    np.testing.assert_array_equal(m, THETA0[:5])
    np.testing.assert_array_equal(c, COV)
    m2, c2 = camera_moments((THETA0[:5], COV))
    np.testing.assert_array_equal(m2, m)
    np.testing.assert_array_equal(c2, c)


@pytest.mark.parametrize("bad, kind, words", [
    (object(), TypeError, "camera must be a camera calibration"),
    ((THETA0[:5], -COV), ValueError, "not positive definite"),
    ((THETA0[:4], COV), ValueError, "shape (5,)"),
    ((THETA0[:5] * np.nan, COV), ValueError, "finite"),
])
def test_camera_moments_refuse_bad_input_naming_it(bad, kind, words):
    with pytest.raises(kind, match=words.replace("(", r"\(").replace(")", r"\)")):
        camera_moments(bad)


def test_camera_moments_name_a_missing_intrinsic():
    cam = _camera()
    del cam.intrinsics["u0"]
    with pytest.raises(ValueError, match="has no u0"):
        camera_moments(cam)


def test_camera_prior_refuses_the_priors_it_replaces():
    with pytest.raises(ValueError, match="alpha_u"):
        Prior({"alpha_u": stats.norm(55, 1)}, camera=_camera())
    p = Prior({"h": stats.norm(210, 5)}, camera=_camera())     # h, beta, phi, pose: allowed
    assert float(p.dists["h"].mean()) == 210.0
    again = Prior(p)                                           # a copy keeps the camera
    np.testing.assert_array_equal(again.camera[1], COV)
    assert as_prior(p) is p


def test_logpdf_theta_is_the_camera_normal_times_h_beta_and_phi_mass():
    prior = Prior(camera=_camera())
    rng = np.random.default_rng(0)
    th = THETA0 + np.concatenate([rng.multivariate_normal(np.zeros(5), COV, 4),
                                  rng.normal(0, [5.0, 0.01], (4, 2))], axis=1)
    d = prior.dists
    want = (stats.multivariate_normal(THETA0[:5], COV).logpdf(th[:, :5])
            + d["h"].logpdf(th[:, 5]) + d["beta"].logpdf(th[:, 6]) + d["phi"].logsf(-th[:, 0]))
    np.testing.assert_allclose(prior.logpdf_theta(th), want, rtol=1e-12)
    # the paper-parameter density: the same density of (theta, phi) times (xi + phi)^2
    phi = np.array([-0.1, 0.0, 0.05, 0.2])
    a = from_identifiable(th, phi)
    want_a = (want - d["phi"].logsf(-th[:, 0]) + d["phi"].logpdf(phi)
              + 2 * np.log(th[:, 0] + phi))
    np.testing.assert_allclose(prior.logpdf(a), want_a, rtol=1e-12)


def test_theta_residuals_whiten_the_camera_and_their_jacobian_is_exact(numdiff):
    prior = Prior(camera=_camera())
    th = THETA0 + np.array([0.003, -0.5, 0.4, 0.3, -0.2, 4.0, 0.01])
    phi = 0.07
    r, J = prior.theta_residuals(th, phi, jacobian=True)
    d = th[:5] - THETA0[:5]
    np.testing.assert_allclose(r[:5] @ r[:5], d @ np.linalg.solve(COV, d), rtol=1e-10)
    # half the squared residuals fall as the log prior of (theta, phi) rises
    lp = prior.logpdf_theta(th) - prior.dists["phi"].logsf(-th[0]) + prior.dists["phi"].logpdf(
        phi)
    th2 = th + np.array([-0.001, 0.2, 0.1, -0.1, 0.1, -2.0, -0.005])
    r2 = prior.theta_residuals(th2, 0.01)
    lp2 = (prior.logpdf_theta(th2) - prior.dists["phi"].logsf(-th2[0])
           + prior.dists["phi"].logpdf(0.01))
    np.testing.assert_allclose(0.5 * (r @ r - r2 @ r2), lp2 - lp, rtol=1e-10)
    num = numdiff(lambda x: prior.theta_residuals(x[:7], x[7]), np.append(th, phi), 1e-6)
    np.testing.assert_allclose(J, num, rtol=1e-6, atol=1e-8)
    # on the paper parameters: the same rows, chained through from_identifiable
    a = from_identifiable(th, phi)
    ra, Ja = prior.residuals(a, jacobian=True)
    np.testing.assert_allclose(ra, r, rtol=1e-12)
    np.testing.assert_allclose(Ja @ identifiable_jacobian(th, phi), J, rtol=1e-9, atol=1e-12)


def test_phi_draws_follow_its_prior_truncated_to_the_domain():
    prior = Prior({"phi": stats.norm(0.0, 0.5)}, camera=_camera(THETA0[:5] * [0.5, 1, 1, 1, 1]))
    th = np.tile(THETA0, (4000, 1))
    th[:, 0] = 0.5
    phi = prior.sample_phi(th, rng=1)
    assert np.all(phi > -0.5)
    trunc = stats.truncnorm(-1.0, np.inf, loc=0.0, scale=0.5)
    # KS test at the 1e-3 level: a false failure once in a thousand runs
    assert stats.kstest(phi, trunc.cdf).pvalue > 1e-3


def test_prior_draws_and_marginals_follow_the_camera():
    prior = Prior(camera=_camera())
    a = prior.sample(20000, rng=2)
    th = bc.sensor.parameters.to_identifiable(a)
    # means within 4 standard errors, covariance within 5 % (n = 20000: se ~1 %)
    np.testing.assert_array_less(np.abs(th[:, :5].mean(0) - THETA0[:5]), 4 * SD / np.sqrt(2e4))
    np.testing.assert_allclose(np.cov(th[:, :5], rowvar=False)[np.diag_indices(5)], SD**2,
                               rtol=0.05)
    # the marginals kept for summaries: exact for xi, u0, v0; alpha's to first order
    for name in ("xi", "u0", "v0", "alpha_u", "alpha_v"):
        k = bc.PARAM_NAMES.index(name)
        np.testing.assert_allclose(float(prior.dists[name].std()), a[:, k].std(), rtol=0.05,
                                   err_msg=name)
    assert prior.mean().xi == THETA0[0]


def test_a_posterior_file_keeps_the_camera_prior():
    import json

    from bayescal.results.posterior_file import _prior_record, _read_prior

    prior = Prior({"h": stats.norm(210, 5)}, camera=_camera())
    back = _read_prior(json.loads(json.dumps(_prior_record(prior))))
    np.testing.assert_allclose(back.camera[0], prior.camera[0])
    np.testing.assert_allclose(back.camera[1], prior.camera[1])
    assert float(back.dists["h"].mean()) == 210.0
    th = THETA0 + 0.01
    np.testing.assert_allclose(back.logpdf_theta(th), prior.logpdf_theta(th), rtol=1e-12)
