"""The ring's cross-validation (``bc.ring_cross_validation``): held-out blocks of azimuths
predicted from their neighbours, z = residual / sd; z rms 1 when the covariances are
honest, and the same as the z rms against the truth on a rendered image."""

import numpy as np
import pytest

import bayescal as bc
from bayescal.errors import InvalidValueError


def _ring(n=720, *, sd=0.15, stated=0.15, corr=0.0, corners=0, rng=0):
    """LaserPixels on an off-centre ellipse (or a rounded polygon with ``corners``), radial
    noise of sd ``sd`` (lag-1 correlation ``corr``), covariances stating ``stated``."""
    rng = np.random.default_rng(rng)
    phi = np.linspace(-np.pi, np.pi, n, endpoint=False)
    r = 220 + 15 * np.cos(2 * phi + 0.4) + 6 * np.sin(phi)
    if corners:                                      # a room's walls: a polygon's radius
        a = np.pi / corners
        r = 220 * np.cos(a) / np.cos((phi + 0.1) % (2 * a) - a)
    e = rng.standard_normal(n)
    if corr:                                         # AR(1) noise of the same sd
        for i in range(1, n):
            e[i] = corr * e[i - 1] + np.sqrt(1 - corr ** 2) * e[i]
    r = r + sd * e
    c = np.array([430.0, 300.0])
    px = c + r[:, None] * np.stack([np.cos(phi), np.sin(phi)], -1)
    t = np.stack([-np.sin(phi), np.cos(phi)], -1)
    nrm = np.stack([np.cos(phi), np.sin(phi)], -1)
    cov = stated ** 2 * nrm[:, :, None] * nrm[:, None, :] + 25.0 * t[:, :, None] * t[:, None, :]
    return bc.LaserPixels(pixels=px, covariance=cov, snr=np.full(n, 50.0),
                          flagged=np.zeros(n, bool), center=c)


def test_honest_covariances_give_z_rms_near_one():
    # ~600 held-out points: the sampling sd of an rms of unit normals is ~0.03, so 0.85-1.15
    # fails with probability < 1e-5 when the prediction's variance is right
    cv = bc.ring_cross_validation(_ring())
    assert cv.n_held_out > 500
    assert 0.85 < cv.z_rms < 1.15
    assert cv.gross == 0.0
    assert cv.z.shape == (cv.n_held_out,) and np.all(cv.sd > 0.15)
    assert "z rms" in cv.summary()


def test_covariances_twice_too_small_give_z_rms_near_two():
    cv = bc.ring_cross_validation(_ring(stated=0.075))
    assert 1.7 < cv.z_rms < 2.3


def test_blocks_longer_than_the_errors_correlation():
    # neighbouring points' errors correlated (lag 1: 0.4, as the real frames' 0.2-0.4): a
    # block of 8 px (4 points) with 3 px left out either side still sees them whole
    cv = bc.ring_cross_validation(_ring(corr=0.4))
    assert 0.85 < cv.z_rms < 1.2


def test_a_room_corner_is_left_out_not_predicted():
    # a polygonal ring (a room's walls, six corners): the blocks whose fit reaches a corner
    # are not scored, the others predict as on a smooth ring
    cv = bc.ring_cross_validation(_ring(corners=6))
    assert 0.8 < cv.z_rms < 1.25
    assert cv.n_held_out < 700


def test_too_few_points_or_bad_lengths_are_refused():
    lp = _ring(n=20)
    with pytest.raises(InvalidValueError, match="24 unflagged points"):
        bc.ring_cross_validation(lp)
    with pytest.raises(InvalidValueError, match="block_px"):
        bc.ring_cross_validation(_ring(), block_px=0)


def test_agrees_with_the_truth_on_a_rendered_image():
    # our renderer's textured 2500-mm room with its laser-off image (seed 0): z rms against
    # the truth 0.86, the cross-validation's 0.95 (measured; docs/images.md)
    p = bc.SensorParams.paper()
    img, truth = bc.render_image(p, bc.room_walls(2500), with_background=True, rng=0)
    lp = bc.extract_laser(img, background=truth.background)
    ok = ~lp.flagged
    T = truth.pixels
    t = np.roll(T, -1, 0) - np.roll(T, 1, 0)
    t /= np.linalg.norm(t, axis=1)[:, None]
    k = np.argmin(np.sum((lp.pixels[ok][:, None, :] - T[None]) ** 2, -1), 1)
    e = np.sum((lp.pixels[ok] - T[k]) * np.stack([t[k, 1], -t[k, 0]], -1), 1)
    z_truth = np.sqrt(np.mean((e / lp.sd_normal[ok]) ** 2))
    cv = bc.ring_cross_validation(lp)
    assert abs(cv.z_rms - z_truth) < 0.25
    assert 0.7 <= cv.z_rms <= 1.4
