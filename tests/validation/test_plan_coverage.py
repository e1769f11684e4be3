"""Slow: coverage of the floor-plan intervals on wall-level errors (``docs/floorplan.md`` s. 9).

Each replication simulates a room whose approximate geometry is a rough floor plan
(``simulate_room(approx_model="wall")``: every wall's distance off by one draw of 5 % of
it, its orientation by one draw of 0.01 rad; those are the plan's sds) with fresh pixel
noise and prior centres drawn around the truth from the prior (a user's design values
are a measurement of the sensor). The 90 % and 95 % intervals of the 7 identifiable
parameters, of the 2W wall parameters and of the points' coordinates must hold the
truth within the 99 % binomial band of M replications.

``BAYESCAL_PLAN_COVERAGE_MCMC=1`` checks the MCMC intervals (``sample_posterior``, 400
draws, ``min_ess=300``) as well as the Laplace ones, and that the chains converged.
``BAYESCAL_PLAN_COVERAGE_M`` sets M: default 200 (Laplace only) or 80 (with MCMC).

Time on the 2-core machine, one process: a Laplace-only replication (both least
squares) is ~0.5 s, so the default run is ~3-4 min for both rooms; with MCMC a
replication is 5-9 s idle and median 13 s at load 5 (the chain is 95 % of it), so M = 80
is ~12-18 min per room, ~25-35 min for both (measured: 43 min at load 5-6).
The MCMC mode at M = 80 failed once in the 5000 mm room (shallow-corner seeds 1044 and
1063 left their chains unconverged, more than 2 % of M); since the corner restarts of
the least squares it passes both rooms, every chain converged (21 min; ``docs/floorplan.md``
s. 9.1).
"""

import os
import warnings

import numpy as np
import pytest
from scipy import stats

import bayescal as bc
from bayescal.scene.floorplan import FloorPlan

MCMC = os.environ.get("BAYESCAL_PLAN_COVERAGE_MCMC", "0") == "1"
M = int(os.environ.get("BAYESCAL_PLAN_COVERAGE_M", "80" if MCMC else "200"))
ROOMS = {"small": (1000.0, 0.5), "large": (5000.0, 0.1)}
LEVELS = (0.9, 0.95)


def drawn_prior(truth, rng):
    """Default-width normal priors centred at ``truth + sd * N(0, 1)``."""
    return {name: stats.norm(getattr(truth, name) + float(d.std()) * rng.standard_normal(),
                             float(d.std()))
            for name, d in bc.default_prior().items()}


def binomial_band(level, m, conf=0.99):
    """Central ``conf`` band of the covered fraction of m Bernoulli(level) trials."""
    lo, hi = stats.binom.interval(conf, m, level)
    return lo / m, hi / m


def replication(range_mm, sigma_px, seed, *, mcmc=False):
    """Inside-the-interval flags of one replication, per level and quantity.

    Returns
    -------
    dict
        ``{(method, quantity): bool array (L, k)}`` for method in ``laplace``, ``mcmc``
        and ``perpoint`` (the per-point model's Laplace intervals on the same data) and
        quantity in ``theta`` (7), ``walls`` (2W), ``points`` (3N).
    """
    rng = np.random.default_rng(seed)
    ds = bc.simulate_room(range_mm=range_mm, n_points=580, sigma_px=sigma_px,
                          approx_error=0.05, approx_model="wall", rng=seed)
    prior = drawn_prior(ds.params, rng)
    truth = {"theta": ds.params.to_identifiable(), "points": ds.points.ravel(),
             "walls": FloorPlan(ds.walls, distance_sd=1.0, angle_sd=1.0).param_nominal}
    try:
        res = bc.calibrate_simultaneous(ds.pixels, ds.floor_plan, sigma_px=sigma_px,
                                        prior=prior)
    except bc.ConvergenceError:
        return None
    sd_pts = np.sqrt(np.einsum("nii->ni", res.extras["point_covariance"])).ravel()
    lap = {"theta": (res.extras["theta"], np.sqrt(np.diag(res.covariance_identifiable))),
           "walls": (res.extras["walls"].ravel(), np.sqrt(np.diag(res.extras["wall_covariance"]))),
           "points": (res.points.ravel(), sd_pts)}
    out = {("laplace", k): _gauss_inside(*lap[k], truth[k]) for k in lap}
    sig_scene = np.maximum(0.05 * np.abs(ds.approx_points), 1.0)
    pp = bc.calibrate_simultaneous(ds.pixels, ds.approx_points, sigma_px=sigma_px,
                                   sigma_scene=sig_scene, prior=prior)
    out[("perpoint", "theta")] = _gauss_inside(
        pp.params.to_identifiable(), np.sqrt(np.diag(pp.covariance_identifiable)),
        truth["theta"])
    out[("perpoint", "points")] = _gauss_inside(
        pp.points.ravel(), np.sqrt(np.einsum("nii->ni", pp.extras["point_covariance"])).ravel(),
        truth["points"])
    if mcmc:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            post = bc.sample_posterior(ds.pixels, ds.floor_plan, sigma_px=sigma_px, prior=prior,
                                       rng=seed, min_ess=300, n_samples=400, progress=False)
        n = post.theta_samples.shape[0]
        samples = {"theta": post.theta_samples, "points": post.point_samples.reshape(n, -1),
                   "walls": post.wall_samples.reshape(n, -1)}
        out.update({("mcmc", k): _quantile_inside(samples[k], truth[k]) for k in samples})
        out[("mcmc", "converged")] = np.array([[post.converged]])
    return out


def _gauss_inside(center, sd, truth):
    z = np.abs(np.asarray(center) - truth) / sd
    return np.array([z <= stats.norm.ppf((1 + lev) / 2) for lev in LEVELS])


def _quantile_inside(samples, truth):
    out = []
    for lev in LEVELS:
        lo, hi = np.quantile(samples, [(1 - lev) / 2, (1 + lev) / 2], axis=0)
        out.append((truth >= lo) & (truth <= hi))
    return np.array(out)


def coverage_table(range_mm, sigma_px, m, *, mcmc=False, seed0=1000):
    """Covered fractions ``{(method, quantity): (L, k)}`` over the replications whose
    least squares converged; ``table["failed"]`` counts the others."""
    reps = [replication(range_mm, sigma_px, seed0 + i, mcmc=mcmc) for i in range(m)]
    ok = [r for r in reps if r is not None]
    table = {k: np.mean([r[k] for r in ok], axis=0) for k in ok[0]}
    table["failed"] = m - len(ok)
    return table


@pytest.mark.slow
@pytest.mark.parametrize("room", ["small", "large"])
def test_floor_plan_intervals_cover(room):
    """90 % / 95 % intervals of theta, walls and points within the 99 % band of M.

    Per interval and level the false-failure rate is at most 1 %; theta and the walls are
    tested one parameter at a time (7 + 14 intervals per level and method), the points
    pooled over coordinates (3N correlated indicators: the band of M is the right one
    only for each single coordinate, so the pooled fraction is checked against it).
    Not Bonferroni-corrected: were the 21 parameter intervals independent, a room
    would fail by chance with probability ~19 % at M = 200 and ~12 % at M = 80 (both
    levels, simulated); they are correlated (xi, gamma_u, gamma_v move together, and
    the MCMC checks nearly repeat the Laplace ones), so the rate is lower. With MCMC,
    least squares failures and unconverged chains may each be at most 2 % of M.
    """
    range_mm, sigma_px = ROOMS[room]
    table = coverage_table(range_mm, sigma_px, M, mcmc=MCMC)
    for key, value in table.items():              # the measured table (pytest -s shows it)
        pooled = key[-1] == "points"                  # one fraction per level: the mean
        print(room, key, np.round(np.mean(value, axis=-1) if pooled else value, 3).tolist())
    assert table["failed"] <= 0.02 * M            # least squares that did not converge
    methods = ("laplace", "mcmc") if MCMC else ("laplace",)
    if MCMC:
        n_ok = M - table["failed"]
        assert table[("mcmc", "converged")].item() * n_ok >= n_ok - 0.02 * M
    for method in methods:
        for qty in ("theta", "walls", "points"):
            cov = table[(method, qty)]
            for i, lev in enumerate(LEVELS):
                lo, hi = binomial_band(lev, M)
                frac = cov[i] if qty != "points" else np.array([cov[i].mean()])
                assert np.all((frac >= lo) & (frac <= hi)), (method, qty, lev, frac, (lo, hi))
