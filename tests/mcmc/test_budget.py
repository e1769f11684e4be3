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
