"""The sampler's time budget (bayescal.mcmc.steps.run_until_converged): a chain whose
autocorrelation time keeps growing stops, not converged, at ``budget`` times the steps its
stopping rule projected after 200 steps, and says why; a healthy chain is not touched."""

import numpy as np

from bayescal.mcmc.steps import BUDGET_FACTOR, run_until_converged, seeded_sampler


class _Identity:          # sampling coordinates are the parameters themselves
    @staticmethod
    def from_sampling(x):
        return x


def _run(logp, ndim, rng, budget, max_steps=20000):
    rng = np.random.default_rng(rng)
    sampler = seeded_sampler(8, ndim, logp, rng, None)
    p0 = 0.1 * rng.standard_normal((8, ndim))
    info = run_until_converged(sampler, p0, min_ess=50, tau_factor=20, max_steps=max_steps,
                               chunk=100, progress=False, budget=budget,
                               coords=_Identity())
    return info, len(sampler.get_chain())


def test_a_healthy_chain_converges_inside_its_budget():
    info, steps = _run(lambda x: -0.5 * np.sum(x * x, axis=1), 2, 0, BUDGET_FACTOR)
    assert info["converged"] and info["stopped"] is None
    assert steps == info["n_steps"]


def _two_modes(x):
    # two narrow modes 40 sds apart along the first axis: the stretch move crosses rarely,
    # so tau grows as the chain finds the second mode
    a = -0.5 * np.sum((x - [20.0, 0.0]) ** 2, axis=1)
    b = -0.5 * np.sum((x + [20.0, 0.0]) ** 2, axis=1)
    return np.logaddexp(a, b)


def test_a_chain_whose_tau_keeps_growing_stops_on_its_budget_and_says_why():
    # seed 2: tau 14 after 200 steps (the projection: 393 steps), 64 after 1179 (seeds 1 and
    # 3 cross between the modes early and converge, the budget untouched)
    with np.errstate(all="ignore"):
        info, steps = _run(_two_modes, 2, 2, BUDGET_FACTOR, max_steps=6000)
    assert not info["converged"] and info["stopped"] is not None, info
    assert "time budget" in info["stopped"] and "autocorrelation time grew" in info["stopped"]
    first = int(info["stopped"].split("times the ")[1].split()[0])
    assert steps == info["n_steps"] <= BUDGET_FACTOR * first + 1


def test_a_floor_plan_posterior_runs_under_the_same_budget(monkeypatch):
    """sample_posterior hands its budget to the floor-plan sampler too (it used to drop it
    there): the chain runner sees the default BUDGET_FACTOR, or None when asked, and a
    chain the budget stops is reported not converged with the reason."""
    import warnings

    import bayescal as bc
    from bayescal.mcmc import collapsed

    ds = bc.simulate_room(range_mm=1000.0, n_points=40, n_walls=4, sigma_px=0.5,
                          approx_error=0.02, approx_model="gaussian", rng=0)
    seen, real = [], collapsed.run_until_converged

    def spy(*args, **kw):
        seen.append(kw["budget"])
        info = real(*args, **{**kw, "max_steps": 100})      # a short chain is enough here
        if kw["budget"] is not None:          # as if the budget had stopped it
            info.update(converged=False, stopped="stopped by its time budget (test)")
        return info

    monkeypatch.setattr(collapsed, "run_until_converged", spy)
    kw = dict(sigma_px=0.5, rng=1, progress=False, min_ess=50, tau_factor=10, n_samples=50,
              outliers=False, n_tune=20)
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        post = bc.sample_posterior(ds.pixels, ds.floor_plan, **kw)
    assert seen == [BUDGET_FACTOR] and not post.converged
    assert any("time budget" in str(w.message) for w in caught)
    bc.sample_posterior(ds.pixels, ds.floor_plan, budget=None, **kw)
    assert seen[-1] is None


def test_burn_in_is_five_tau_above_its_floor_and_at_most_half():
    from bayescal.mcmc.steps import BURN_FLOOR, _assess
    from bayescal.stats.chains import integrated_time

    # AR(1) walkers with phi = 0.6 (tau = 4): 5 tau ~ 20 steps of 400
    rng = np.random.default_rng(0)
    chain = np.zeros((400, 10, 2))
    for t in range(1, 400):
        chain[t] = 0.6 * chain[t - 1] + 0.8 * rng.standard_normal((10, 2))
    five_tau = int(np.ceil(5 * np.max(integrated_time(chain[80:]))))
    assert 10 < five_tau < 50
    assert _assess(chain, 50, 5.0, _Identity())[0] == int(BURN_FLOOR * 400) == 100
    assert _assess(chain, 50, 5.0, _Identity(), burn_floor=0.0)[0] == five_tau
    assert _assess(chain, 50, 5.0, _Identity(), burn_floor=0.9)[0] == 200     # half at most
