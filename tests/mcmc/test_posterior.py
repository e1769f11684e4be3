"""The Posterior object: I/O, summaries, covariances, reconstruction and its coverage."""

import json

import matplotlib.figure
import numpy as np
import pytest
from scipy import stats

import bayescal as bc
from bayescal.results.posterior_file import ARRAYS as _ARRAYS


@pytest.fixture(scope="module")
def room():
    return bc.simulate_room(range_mm=1000, n_points=100, sigma_px=0.3, approx_error=0.02,
                            approx_model="gaussian", rng=3)


@pytest.fixture(scope="module")
def post(room):
    return bc.sample_posterior(room.pixels, room.approx_points, sigma_px=0.3,
                               sigma_scene=room.sigma_scene, rng=1, progress=False,
                               min_ess=200, n_samples=400)


@pytest.fixture(scope="module")
def new_room():
    """Fresh laser pixels of the same sensor at other azimuths (211 points)."""
    return bc.simulate_room(range_mm=1000, n_points=211, sigma_px=0.3, approx_error=0.02,
                            approx_model="gaussian", rng=9)


# -- save / load --------------------------------------------------------------------------


def test_save_load_round_trip_is_lossless(post, tmp_path):
    path = post.save(tmp_path / "post.npz")
    back = bc.load_posterior(path)
    for name in _ARRAYS:
        np.testing.assert_array_equal(getattr(back, name), getattr(post, name), err_msg=name)
    np.testing.assert_array_equal(back.sigma_scene, post.sigma_scene)
    assert back.summary_text() == post.summary_text()
    for r_back, r in zip(back.summary_rows(), post.summary_rows(), strict=True):  # tau of phi: NaN
        assert r_back.keys() == r.keys()
        for k in r:
            np.testing.assert_array_equal(r_back[k], r[k], err_msg=f"{r['name']} {k}")
    assert back.noise_names == post.noise_names and back.sigma_px == post.sigma_px
    for attr in ("n_steps", "burn", "n_walkers", "converged", "acceptance", "imh_acceptance"):
        assert getattr(back, attr) == getattr(post, attr), attr
    for name, dist in post.prior.dists.items():
        assert back.prior.dists[name].mean() == dist.mean()
        assert back.prior.dists[name].std() == dist.std()
    np.testing.assert_array_equal(back.covariance(), post.covariance())
    # a posterior loaded from disk still reconstructs, identically for the same seed
    np.testing.assert_array_equal(back.reconstruct(post.pixels[:3], rng=0).mean,
                                  post.reconstruct(post.pixels[:3], rng=0).mean)


def test_save_refuses_to_overwrite_and_checks_the_suffix(post, tmp_path):
    path = post.save(tmp_path / "post.npz")
    with pytest.raises(FileExistsError, match="exists; pass overwrite=True"):
        post.save(path)
    post.save(path, overwrite=True)
    with pytest.raises(ValueError, match=r"path must end in \.npz, got '.*post\.txt'"):
        post.save(tmp_path / "post.txt")


def test_load_rejects_other_files(tmp_path):
    with pytest.raises(FileNotFoundError, match="no posterior file at"):
        bc.load_posterior(tmp_path / "missing.npz")
    np.savez(tmp_path / "other.npz", x=np.arange(3))
    with pytest.raises(ValueError, match=r"is not a bayescal posterior file \(no meta_json\)"):
        bc.load_posterior(tmp_path / "other.npz")
    np.savez(tmp_path / "fmt.npz", meta_json=np.array(json.dumps({"format": "else"})))
    with pytest.raises(ValueError, match="is not a bayescal posterior file"):
        bc.load_posterior(tmp_path / "fmt.npz")
    meta = {"format": "bayescal-posterior", "version": 99}
    np.savez(tmp_path / "new.npz", meta_json=np.array(json.dumps(meta)))
    with pytest.raises(ValueError, match="format version 99"):
        bc.load_posterior(tmp_path / "new.npz")


# -- summaries and covariances ------------------------------------------------------------


def test_summary_flags_the_non_identifiable_parameters(post):
    """phi, alpha_u, alpha_v: the data fix only gamma = alpha (xi + phi), so their spread is
    the phi/alpha ridge of the priors (sd ratio ~0.57 > 0.5); u0, v0 are pinned by the
    pixels (sd ratio ~0.004)."""
    rows = {r["name"]: r for r in post.summary_rows()}
    assert list(rows) == list(bc.PARAM_NAMES)
    for name in ("phi", "alpha_u", "alpha_v"):
        assert rows[name]["prior_dominated"] and not rows[name]["identifiable"], name
    for name in ("u0", "v0"):
        assert not rows[name]["prior_dominated"] and rows[name]["identifiable"], name
        assert rows[name]["sd_ratio"] < 0.05
    for r in rows.values():
        assert set(r) == {"name", "mean", "sd", "q05", "q50", "q95", "tau", "ess", "prior_sd",
                          "sd_ratio", "prior_dominated", "identifiable"}
        assert r["q05"] < r["q50"] < r["q95"]
    text = post.summary_text()
    assert text.count("PRIOR-DOMINATED") == 3
    assert "converged" in text


def test_covariances_are_symmetric_positive_semidefinite(post):
    for cov, n in ((post.covariance(), 8), (post.covariance(identifiable=True), 7),
                   (post.laplace_cov8, 8), (post.laplace_cov7, 7)):
        assert cov.shape == (n, n)
        # the Laplace 8x8 is J C J^T: symmetric up to rounding of the triple product
        np.testing.assert_allclose(cov, cov.T, rtol=0, atol=1e-12 * np.max(np.abs(cov)))
        assert np.min(np.linalg.eigvalsh(cov)) > -1e-10 * np.max(np.linalg.eigvalsh(cov))
    pc = post.point_covariance()
    assert pc.shape == (100, 3, 3)
    np.testing.assert_allclose(pc, np.swapaxes(pc, 1, 2), rtol=1e-12, atol=0)
    assert post.intervals(0.9).shape == (8, 2)
    assert post.intervals(0.9, identifiable=True).shape == (7, 2)
    assert post.point_intervals(0.9).shape == (100, 3, 2)


def test_laplace_comparison_rows(post):
    rows = post.laplace_comparison()
    assert [r["name"] for r in rows] == list(bc.PARAM_NAMES)
    for r in rows:
        assert set(r) == {"name", "map", "laplace_sd", "mcmc_mean", "mcmc_sd", "sd_ratio",
                          "disagree"}
        assert isinstance(r["disagree"], bool)
    np.testing.assert_array_equal([r["map"] for r in rows], post.map_params)


# -- reconstruction ---------------------------------------------------------------------------


def test_reconstruct_shapes(post, new_room):
    one = post.reconstruct(new_room.pixels[0], rng=0)
    assert one.mean.shape == (3,) and one.covariance.shape == (3, 3)
    assert one.intervals.shape == (3, 2)
    many = post.reconstruct(new_room.pixels[:5], rng=0)
    mean, cov = many                                       # unpacks as mean, covariance
    assert mean.shape == (5, 3) and cov.shape == (5, 3, 3)
    assert many.intervals.shape == (5, 3, 2) and many.valid.all()
    np.testing.assert_allclose(mean[0], one.mean, rtol=1e-12)      # the fast path: exact
    one_s = post.reconstruct(new_room.pixels[0], rng=0, method="sampled")
    many_s = post.reconstruct(new_room.pixels[:5], rng=0, method="sampled")
    assert one_s.intervals.shape == (3, 2) and many_s.samples.shape[1:] == (5, 3)
    np.testing.assert_allclose(many_s.mean[0], one_s.mean, rtol=0, atol=5 * np.sqrt(np.diag(
        one_s.covariance)).max() / np.sqrt(len(one_s.samples)))
    with pytest.raises(ValueError, match=r"approx_points must have shape \(M, 3\) = \(5, 3\)"):
        post.reconstruct(new_room.pixels[:5], approx_points=new_room.approx_points[:4],
                         sigma_scene=1.0)
    with pytest.raises(ValueError, match="sigma_scene is required with approx_points"):
        post.reconstruct(new_room.pixels[:5], approx_points=new_room.approx_points[:5])
    with pytest.raises(ValueError, match=r"level must lie in \(0, 1\)"):
        post.reconstruct(new_room.pixels[:5], level=1.5)


def test_reconstruct_with_approximate_points_is_tighter(post, new_room):
    sl = slice(0, 40)
    alone = post.reconstruct(new_room.pixels[sl], rng=0)
    both = post.reconstruct(new_room.pixels[sl], approx_points=new_room.approx_points[sl],
                            sigma_scene=new_room.sigma_scene[sl], rng=0)
    assert both.mean.shape == (40, 3)
    assert np.all(np.linalg.det(both.covariance) < np.linalg.det(alone.covariance))
    assert np.all(np.trace(both.covariance, axis1=1, axis2=2)
                  < np.trace(alone.covariance, axis1=1, axis2=2))


def _binomial_band(n, p, ffr):
    return stats.binom.ppf(ffr / 2, n, p) / n, stats.binom.ppf(1 - ffr / 2, n, p) / n


def test_reconstruction_intervals_cover_the_truth(post, new_room):
    """90 % intervals of 211 new pixels hold the true point ~90 % of the time, per axis.

    Per-point errors are nearly independent here (the parameters' uncertainty is ~5 % of
    each reconstruction's variance; pixel noise dominates), so the count is close to
    binomial(211, 0.9); band with FFR 1e-3 per axis (3 axes: ~3e-3 in all).
    """
    lo, hi = _binomial_band(211, 0.9, 1e-3)
    for kw in ({}, {"approx_points": new_room.approx_points,
                    "sigma_scene": new_room.sigma_scene}):
        rec = post.reconstruct(new_room.pixels, level=0.9, rng=2, **kw)
        inside = (new_room.points >= rec.intervals[..., 0]) & (
            new_room.points <= rec.intervals[..., 1])
        frac = inside.mean(axis=0)
        assert np.all((frac > lo) & (frac < hi)), (sorted(kw), frac, lo, hi)


def test_point_intervals_cover_the_calibration_points(post, room):
    """The same check for the calibrated points' own posteriors (100 points, FFR 1e-3 per
    axis)."""
    lo, hi = _binomial_band(100, 0.9, 1e-3)
    iv = post.point_intervals(0.9)
    frac = ((room.points >= iv[..., 0]) & (room.points <= iv[..., 1])).mean(axis=0)
    assert np.all((frac > lo) & (frac < hi)), frac


def test_corner_returns_a_figure(post, room):
    fig = post.corner(truth=room.params, params=["xi", "h", "beta"])
    assert isinstance(fig, matplotlib.figure.Figure)
    import matplotlib.pyplot as plt

    plt.close(fig)


def test_save_is_atomic_and_leaves_no_temporary_file(post, tmp_path, monkeypatch):
    """An interrupted save (numpy failing mid-write) leaves the previous file intact and no
    temporary file behind."""
    path = post.save(tmp_path / "p.npz")
    before = path.read_bytes()

    def broken(f, **arrays):
        f.write(b"half a file")
        raise KeyboardInterrupt

    monkeypatch.setattr(np, "savez_compressed", broken)
    with pytest.raises(KeyboardInterrupt):
        post.save(path, overwrite=True)
    assert path.read_bytes() == before
    assert sorted(p.name for p in tmp_path.iterdir()) == ["p.npz"]
