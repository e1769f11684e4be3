"""bayescal's collapsed posterior against an independent full-joint NUTS run (NumPyro).

The reference (:mod:`bayescal.mcmc.nuts`) shares no model code with bayescal: it
writes the joint over the eight paper parameters and all 2N scene coordinates
in JAX from the paper's equations and samples it with NUTS. Skipped when jax or
numpyro cannot be imported (``pip install bayescal[nuts]``).

Tolerances (the brief's: means within 0.15 NUTS sd, sds within 12 %), against
the Monte-Carlo error of both runs: NUTS gives >= ~600 effective samples of every
parameter here and bayescal >= 1000, so the difference of means has a standard
error of about sqrt(1/600 + 1/1000) = 0.05 sd (0.15 is 3 standard errors:
a false failure about once in 370 per parameter) and the ratio of sds about
sqrt(1/1200 + 1/2000) = 0.037 (12 % is 3.3 standard errors).
"""

import numpy as np
import pytest

import bayescal as bc
from bayescal.mcmc.nuts import nuts_available, sample_nuts
from bayescal.sensor.parameters import IDENTIFIABLE_NAMES, to_identifiable

pytestmark = [pytest.mark.slow,
              pytest.mark.skipif(not nuts_available(), reason="jax/numpyro not installed")]

SCENES = {
    # the paper's Fig. 9 protocol: approximate (x, y) from the walls, no z
    "z_unknown": dict(range_mm=1000.0, n_points=300, sigma_px=0.5, approx_error=0.03,
                      approx_model="fig9"),
    # approximate 3D points with independent errors on every axis
    "z_known": dict(range_mm=2500.0, n_points=300, sigma_px=0.2, approx_error=0.03,
                    approx_model="gaussian"),
}


@pytest.mark.parametrize("scene", sorted(SCENES))
def test_collapsed_posterior_matches_full_joint_nuts(scene):
    kw = SCENES[scene]
    ds = bc.simulate_room(rng=3, **kw)
    sigma_scene = np.maximum(ds.sigma_scene, 1.0)      # no near-exact scene rows near x = 0
    prior = bc.Prior()
    ref = sample_nuts(ds.pixels, ds.approx_points, sigma_px=kw["sigma_px"],
                      sigma_scene=sigma_scene, prior=prior, q_init=ds.approx_points[:, :2],
                      num_warmup=500, num_samples=1000, num_chains=2, rng=0)
    assert np.all(ref["r_hat"] < 1.02), f"NUTS reference not converged: r_hat {ref['r_hat']}"
    assert np.min(ref["ess"]) > 400, f"NUTS reference too short: ESS {ref['ess']}"
    post = bc.sample_posterior(ds.pixels, ds.approx_points, sigma_px=kw["sigma_px"],
                               sigma_scene=sigma_scene, prior=prior, rng=1, progress=False)
    t_ref = to_identifiable(ref["params"])
    t_bc = to_identifiable(post.param_samples)
    sd_ref = t_ref.std(axis=0)
    dmean = (t_bc.mean(axis=0) - t_ref.mean(axis=0)) / sd_ref
    ratio = t_bc.std(axis=0) / sd_ref
    table = "\n".join(f"{n:8s} dmean/sd {d:+.3f}  sd ratio {r:.3f}"
                      for n, d, r in zip(IDENTIFIABLE_NAMES, dmean, ratio, strict=True))
    assert np.all(np.abs(dmean) < 0.15), table
    assert np.all(np.abs(ratio - 1) < 0.12), table
    # the points too: posterior means of every point within 0.15 NUTS sd on each axis
    p_ref, p_bc = ref["points"], post.point_samples
    d_pts = (p_bc.mean(axis=0) - p_ref.mean(axis=0)) / p_ref.std(axis=0)
    # 900 coordinates: compare the spread, not the worst one (the max of 900 normals with
    # standard error 0.05 sd reaches ~0.16 by chance)
    rms = np.sqrt(np.mean(d_pts ** 2))
    assert rms < 0.1, f"RMS point mean difference {rms:.3f} NUTS sd"


def test_misaligned_posterior_matches_full_joint_nuts():
    """The same comparison for model="misaligned" on a sensor tilted (1, 0.5) deg with a
    (5, -5) mm offset (z unknown): the 7 identifiable parameters and the 4 of the pose."""
    kw = dict(range_mm=2500.0, n_points=300, sigma_px=0.2, approx_error=0.03,
              approx_model="fig9")
    ds = bc.simulate_room(rng=5, tilt=tuple(np.radians([1.0, 0.5])), offset=(5.0, -5.0), **kw)
    sigma_scene = np.maximum(ds.sigma_scene, 1.0)
    prior = bc.Prior()
    ref = sample_nuts(ds.pixels, ds.approx_points, sigma_px=kw["sigma_px"],
                      sigma_scene=sigma_scene, prior=prior, q_init=ds.approx_points[:, :2],
                      num_warmup=500, num_samples=1000, num_chains=2, rng=0,
                      model="misaligned")
    assert np.all(ref["r_hat"] < 1.02), f"NUTS reference not converged: r_hat {ref['r_hat']}"
    assert np.min(ref["ess"]) > 400, f"NUTS reference too short: ESS {ref['ess']}"
    post = bc.sample_posterior(ds.pixels, ds.approx_points, sigma_px=kw["sigma_px"],
                               sigma_scene=sigma_scene, prior=prior, rng=1, progress=False,
                               model="misaligned")
    t_ref = np.c_[to_identifiable(ref["params"]), ref["laser"]]
    t_bc = post.geometry_samples
    sd_ref = t_ref.std(axis=0)
    dmean = (t_bc.mean(axis=0) - t_ref.mean(axis=0)) / sd_ref
    ratio = t_bc.std(axis=0) / sd_ref
    table = "\n".join(f"{n:8s} dmean/sd {d:+.3f}  sd ratio {r:.3f}"
                      for n, d, r in zip(IDENTIFIABLE_NAMES + bc.POSE_NAMES, dmean, ratio,
                                         strict=True))
    print("\n" + table)
    assert np.all(np.abs(dmean) < 0.15), table
    assert np.all(np.abs(ratio - 1) < 0.12), table
    d_pts = (post.point_samples.mean(axis=0) - ref["points"].mean(axis=0)) \
        / ref["points"].std(axis=0)
    rms = np.sqrt(np.mean(d_pts ** 2))
    assert rms < 0.1, f"RMS point mean difference {rms:.3f} NUTS sd"
