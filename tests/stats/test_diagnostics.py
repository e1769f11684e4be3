"""Honest ESS of an ensemble and the chain-diagnostics record."""

import numpy as np

import bayescal as bc
from bayescal.stats.chains import ChainDiagnostics, ensemble_ess


def _ar1(rng, T, W, rho, common):
    """AR(1) walkers, unit marginal variance; a share ``common`` of the variance is one
    series shared by every walker (walkers moving together)."""
    def series(n):
        e = rng.standard_normal((T, n))
        x = np.empty((T, n))
        x[0] = e[0]
        for t in range(1, T):
            x[t] = rho * x[t - 1] + np.sqrt(1 - rho**2) * e[t]
        return x
    x = np.sqrt(1 - common) * series(W) + np.sqrt(common) * series(1)
    return x[:, :, None]


def test_ensemble_ess_matches_the_truth_for_independent_and_shared_walkers():
    """AR(1) with rho = 0.8: tau = (1 + rho) / (1 - rho) = 9. Independent walkers:
    ESS = W T / 9. A shared component of variance c: Var(mean) = (c + (1 - c) / W) tau / T,
    so ESS = T / ((c + (1 - c) / W) tau). Tolerance 25 %: tau estimated from 4000 steps
    (~440 tau) with emcee's window (5 tau) has a relative sd of about
    sqrt(4 * 5 / 440) ~ 7 %; 25 % is > 3.5 sd (false-failure rate < 1e-3 per check)."""
    rng = np.random.default_rng(0)
    T, W, tau = 4000, 16, 9.0
    ess, _ = ensemble_ess(_ar1(rng, T, W, 0.8, 0.0))
    np.testing.assert_allclose(ess, W * T / tau, rtol=0.25)
    c = 0.3
    ess, t = ensemble_ess(_ar1(rng, T, W, 0.8, c))
    np.testing.assert_allclose(ess, T / ((c + (1 - c) / W) * tau), rtol=0.25)
    np.testing.assert_allclose(t, W * T / ess)


def test_posterior_carries_diagnostics_and_saves_them(tmp_path):
    ds = bc.simulate_room(range_mm=1000, n_points=60, sigma_px=0.3, approx_error=0.02,
                          approx_model="gaussian", rng=3)
    post = bc.sample_posterior(ds.pixels, ds.approx_points, sigma_px=0.3,
                               sigma_scene=ds.sigma_scene, rng=2, progress=False, min_ess=200,
                               n_samples=100)
    d = post.diagnostics
    assert isinstance(d, ChainDiagnostics) and d.converged
    assert d.n_steps - d.burn > d.tau_factor * np.max(d.tau) and np.min(d.ess) >= d.min_ess
    np.testing.assert_array_equal(d.tau, post.tau)
    assert "50 tau" in d.rule and "ESS >= 200" in d.rule
    back = bc.load_posterior(post.save(tmp_path / "p.npz"))
    assert back.diagnostics.to_dict() == d.to_dict()
    assert back.diagnostics.summary() == d.summary()
