"""Input and degeneracy checks, noise collapse and the posterior predictive check."""

import warnings

import numpy as np
import pytest

import bayescal as bc
from bayescal.checks.fit import NoiseCollapseError
from bayescal.checks.inputs import DuplicateRowsWarning
from bayescal.checks.predictive import posterior_predictive_check, posterior_predictive_residuals
from bayescal.plotting.checks import plot_predictive_check


@pytest.fixture(scope="module")
def room():
    return bc.simulate_room(range_mm=1000, n_points=200, sigma_px=0.5, approx_error=0.01,
                            approx_model="gaussian", rng=0)


def _fit(ds, pixels=None, approx=None, **kw):
    kw.setdefault("sigma_px", None)
    kw.setdefault("sigma_scene", ds.sigma_scene)
    return bc.calibrate_simultaneous(ds.pixels if pixels is None else pixels,
                                     ds.approx_points if approx is None else approx, **kw)


def test_degenerate_input_refused(room):
    with pytest.raises(ValueError, match="at least 4 laser points, got N=3"):
        _fit(room, room.pixels[:3], room.approx_points[:3], sigma_scene=10.0)
    az = np.arctan2(room.pixels[:, 1] - 300, room.pixels[:, 0] - 400)
    narrow = np.abs(az) < np.radians(15)              # a 30-degree sector
    with pytest.raises(ValueError, match="within .* degrees of azimuth"):
        _fit(room, room.pixels[narrow], room.approx_points[narrow], sigma_scene=10.0)
    with pytest.raises(ValueError, match="sigma_scene is inf everywhere"):
        _fit(room, sigma_scene=np.inf)
    apx = room.approx_points.copy()
    apx[7, :2] = 0.0
    with pytest.raises(ValueError, match="rows 7 lie on the sensor axis"):
        _fit(room, approx=apx)
    apx = room.approx_points.copy()
    apx[[4, 9], 1] = np.nan
    with pytest.raises(ValueError, match=r"approx_points must contain only finite values; "
                                         r"rows 4, 9"):
        _fit(room, approx=apx)
    with pytest.raises(ValueError, match="max_iter must be a positive integer, got 0"):
        _fit(room, max_iter=0)


def test_duplicate_rows_warn_with_their_rows(room):
    pix = np.vstack([room.pixels, room.pixels[[5]]])
    apx = np.vstack([room.approx_points, room.approx_points[[5]]])
    ss = np.vstack([room.sigma_scene, room.sigma_scene[[5]]])
    with pytest.warns(DuplicateRowsWarning, match=r"rows 5, 200"):
        bc.calibrate_simultaneous(pix, apx, sigma_px=0.5, sigma_scene=ss)
    with warnings.catch_warnings():
        warnings.simplefilter("error", DuplicateRowsWarning)
        _fit(room, sigma_px=0.5)                          # no duplicates: no warning


def test_pixel_noise_the_data_bound_only_from_above_is_fitted_at_that_bound(room):
    """A scene noise of 500 % leaves the pixel noise undetermined below about 3 px: without
    the noise check the MAP ended at sigma_px ~ 1e-11 px and reported it as converged; it is
    now fitted at the largest level the data allow, with a warning, and its sds are those of
    a fit given the true 0.5 px (the scene says nothing: the priors set them)."""
    ss = 5.0 * np.abs(room.approx_points) + 1.0
    with pytest.warns(bc.NoiseUndeterminedWarning, match=r"not determined .* largest"):
        res = _fit(room, sigma_scene=ss)
    assert 1.0 < res.extras["sigma_px_ceiling"] < 5.0
    given = _fit(room, sigma_scene=ss, sigma_px=0.5)
    sd = np.sqrt(np.diag(res.covariance_identifiable))
    assert np.all(sd >= 0.99 * np.sqrt(np.diag(given.covariance_identifiable)))


def test_pixel_noise_that_the_data_cannot_fix_is_refused(room):
    """A scene noise of 1e5 mm: the likelihood is flat in sigma_px up to its prior's upper
    bound, so nothing bounds it and the fit refuses, naming the rows."""
    with pytest.raises(NoiseCollapseError, match=r"sigma_px ended at .* lower bound") as ei:
        _fit(room, sigma_scene=np.full_like(room.approx_points, 1e5))
    assert ei.value.name == "sigma_px" and len(ei.value.rows) == 5
    assert isinstance(ei.value, ValueError)


def _laplace_draws(ds, res, S, rng):
    """Draws of (params, points) from the MAP's Laplace approximation."""
    a = rng.multivariate_normal(res.params.to_array(), res.covariance(), S)
    L = np.linalg.cholesky(res.extras["point_covariance"] + 1e-9 * np.eye(3))
    P = res.points + np.einsum("nij,snj->sni", L, rng.standard_normal((S,) + res.points.shape))
    return a, P


def _check(ds, res, rng, pixels=None, sigma_scene=None):
    pixels = ds.pixels if pixels is None else pixels
    sigma_scene = ds.sigma_scene if sigma_scene is None else sigma_scene
    a, P = _laplace_draws(ds, res, 40, rng)
    pr, sr = posterior_predictive_residuals(a, P, pixels, ds.approx_points,
                                            sigma_px=res.extras["noise"]["sigma_px"],
                                            sigma_scene=sigma_scene)
    az = np.arctan2(ds.approx_points[:, 1], ds.approx_points[:, 0])
    return posterior_predictive_check(pr, sr, azimuth=az, rng=rng, alpha=0.001)


def test_predictive_check_passes_data_from_the_model(room, rng):
    """Data simulated from the model: no discrepancy at p < 0.001 (three statistics: a
    false failure about 0.3 % of seeds; the seed is fixed)."""
    res = _fit(room, sigma_px=0.5, outliers=False)
    chk = _check(room, res, rng)
    assert chk["fits"], chk["message"]
    assert chk["point_chi2"].shape == (200,)
    fig = plot_predictive_check(chk, azimuth=np.zeros(200), outlier_prob=res.outlier_prob)
    assert fig.axes


def test_predictive_check_flags_wall_errors_and_heavy_tails(rng):
    """Scene errors shared per wall (7 walls, 3 %) given as independent: flagged (by the
    sum of squares and the tails). Pixel noise from a Student t(2): the tail fraction is."""
    ds = bc.simulate_room(range_mm=1000, n_points=200, sigma_px=0.5, approx_error=0.03,
                          approx_model="wall", rng=1)
    ss = np.broadcast_to(0.03 * np.abs(ds.approx_points) + 1.0, (200, 3)).copy()
    ss[:, 2] = np.inf
    res = _fit(ds, sigma_px=0.5, sigma_scene=ss, outliers=False)
    chk = _check(ds, res, rng, sigma_scene=ss)
    assert not chk["fits"] and chk["message"].startswith("MODEL DOES NOT FIT")
    ds2 = bc.simulate_room(range_mm=1000, n_points=200, sigma_px=0.0, approx_error=0.01,
                           approx_model="gaussian", rng=2)
    pix = ds2.pixels + 0.35 * rng.standard_t(2, size=ds2.pixels.shape)
    res2 = _fit(ds2, pix, sigma_px=0.5, outliers=False)
    chk2 = _check(ds2, res2, rng, pixels=pix)
    assert not chk2["fits"] and "|z| > 3" in chk2["message"]
