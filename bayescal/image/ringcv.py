"""Whether an extracted ring's covariances match its real scatter: a cross-validation that
needs no truth (:func:`ring_cross_validation`).

A laser ring is a smooth closed curve; its points' errors are correlated over a few
neighbouring profiles only. So blocks of neighbouring azimuths, each longer than that
correlation, are left out one at a time, the curve is fitted through the points on either
side of the block (a robust local quadratic of the radius over azimuth about the ring's own
centre, a guard of a few px left between them), and each held-out point's residual across
the ring is compared with its stated sd and the prediction's: ``z = residual / sqrt(var_point
+ var_prediction)``. When the stated covariances are honest the z rms is near 1 (measured in
``docs/images.md`` against the truth of rendered images). Errors shared over longer
stretches of the ring than the fit's reach (a translation, a scale) are indistinguishable
from the ring's shape and are not seen.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..errors import InvalidValueError
from .ring import circle_fit

__all__ = ["RingCV", "ring_cross_validation", "ring_cv_line", "CV_BLOCK_PX", "CV_GUARD_PX",
           "CV_REACH_PX", "CV_KINK", "CV_KINK_PX"]

#: length of a held-out block along the ring, px: longer than the errors' correlation
#: (neighbouring profiles 1.6-2 px apart: lag-1 0.2-0.68, lag 4 at most 0.15, measured on
#: real frames and three renderers; docs/images.md)
CV_BLOCK_PX = 8.0
#: points within this of a block (px along the ring) are left out of its fit as well: they
#: share part of the block's edge points' errors
CV_GUARD_PX = 3.0
#: how far beyond the guard, each side, the fit reaches, px along the ring: short enough
#: that a quadratic follows the ring (a room's corner bends it), long enough for ~10 points
#: each side
CV_REACH_PX = 12.0
#: a room's corner kinks the ring: a hinge |x| at a block's middle, fitted with a quadratic
#: through the points on either side (from CV_GUARD_PX to CV_KINK_PX beyond it), stands out
#: by more than CV_KINK sds; no block whose fit reaches that corner is scored
CV_KINK = 3.0
#: the fit that looks for a corner reaches CV_KINK_PX beyond the guard on either side
CV_KINK_PX = 16.0


@dataclass(frozen=True)
class RingCV:
    """A ring's cross-validation: one entry per held-out (unflagged) point.

    Attributes
    ----------
    index : ndarray of int, shape (M,)
        Row of each point in the extraction (``lp.pixels[index]``).
    residual : ndarray, shape (M,)
        Distance from the curve predicted by the other blocks, across the ring, px
        (positive away from the ring's centre).
    sd : ndarray, shape (M,)
        ``sqrt(point variance + prediction variance)`` across the ring, px.
    block : ndarray of int, shape (M,)
        Block of each point.
    gross_px : float
        Residuals larger than this (px) are gross: left out of :attr:`z_rms`.
    """

    index: np.ndarray
    residual: np.ndarray
    sd: np.ndarray
    block: np.ndarray
    gross_px: float = 1.0

    @property
    def z(self):
        """ndarray, shape (M,): residual over its sd."""
        return self.residual / self.sd

    @property
    def n_held_out(self):
        """int: points predicted (unflagged points with enough neighbours)."""
        return len(self.residual)

    @property
    def gross(self):
        """float: fraction of the held-out points farther than ``gross_px`` from the curve."""
        return float(np.mean(np.abs(self.residual) > self.gross_px)) if len(self.z) else np.nan

    @property
    def z_rms(self):
        """float: rms of z over the non-gross points (1 when the covariances are honest)."""
        good = np.abs(self.residual) <= self.gross_px
        return float(np.sqrt(np.mean(self.z[good] ** 2))) if good.any() else np.nan

    @property
    def robust_sd(self):
        """float: 1.4826 x the median absolute residual, px."""
        r = self.residual
        return float(1.4826 * np.median(np.abs(r - np.median(r)))) if len(r) else np.nan

    def summary(self):
        """One line: z rms, held-out points, blocks, robust scatter and gross fraction."""
        return (f"cross-validation: z rms {self.z_rms:.2f} over {self.n_held_out} held-out "
                f"points in {len(np.unique(self.block))} blocks (1 = honest covariances), "
                f"scatter {self.robust_sd:.3f} px, {100 * self.gross:.1f} % beyond "
                f"{self.gross_px:g} px")


def ring_cross_validation(lp, *, block_px=CV_BLOCK_PX, guard_px=CV_GUARD_PX,
                          reach_px=CV_REACH_PX, gross_px=1.0, iters=4):
    """Cross-validate an extraction's covariances against the ring's own smoothness.

    Parameters
    ----------
    lp : LaserPixels
        An extraction (:func:`~bayescal.image.extract.extract_laser`); its unflagged points
        are used.
    block_px : float, optional
        Length of each held-out block along the ring, px.
    guard_px : float, optional
        Gap left out of the fit on either side of a block, px.
    reach_px : float, optional
        Extent of the fit beyond the guard on each side, px.
    gross_px : float, optional
        Residuals beyond this are gross and left out of the z rms, px.
    iters : int, optional
        Biweight refits (a gross point among the neighbours does not bend the curve).

    Returns
    -------
    RingCV

    Raises
    ------
    InvalidValueError
        Fewer than 24 unflagged points, or lengths that are not positive.

    Examples
    --------
    >>> import bayescal as bc
    >>> img, truth = bc.render_image(bc.SensorParams.paper(), bc.room_walls(2500),
    ...                              with_background=True, rng=0)
    >>> cv = bc.ring_cross_validation(bc.extract_laser(img, background=truth.background))
    >>> 0.5 < cv.z_rms < 2.0
    True
    """
    for name, v in (("block_px", block_px), ("reach_px", reach_px), ("gross_px", gross_px)):
        if not np.isfinite(v) or v <= 0:
            raise InvalidValueError(f"{name} must be positive, got {v!r}")
    if not np.isfinite(guard_px) or guard_px < 0:
        raise InvalidValueError(f"guard_px must be >= 0, got {guard_px!r}")
    ok = np.nonzero(~np.asarray(lp.flagged, bool) & np.all(np.isfinite(lp.pixels), axis=1)
                    & np.isfinite(lp.sd_normal))[0]
    if len(ok) < 24:
        raise InvalidValueError(f"a cross-validation needs 24 unflagged points or more, the "
                                f"extraction has {len(ok)}")
    pts = lp.pixels[ok]
    c, R, _ = circle_fit(pts)
    if not np.isfinite(R) or R <= 0:
        c, R = np.median(pts, axis=0), float(np.median(np.hypot(*(pts - np.median(pts, 0)).T)))
    d = pts - c
    theta, r = np.arctan2(d[:, 1], d[:, 0]), np.hypot(d[:, 0], d[:, 1])
    var = lp.sd_normal[ok] ** 2
    n_blocks = max(3, int(round(2 * np.pi * R / block_px)))
    block = np.floor((theta + np.pi) / (2 * np.pi) * n_blocks).astype(int) % n_blocks
    mid = -np.pi + (np.arange(n_blocks) + 0.5) * 2 * np.pi / n_blocks
    # offsets of every point from every block's middle, px along the ring (B, N)
    off = np.angle(np.exp(1j * (theta[None, :] - mid[:, None]))) * R
    half = np.pi * R / n_blocks
    reach = half + guard_px + reach_px
    train = (np.abs(off) >= half + guard_px) & (np.abs(off) <= reach)
    coef, cov = _wls(np.stack([np.ones_like(off), off / R, (off / R) ** 2], -1), r, var,
                     train / var[None, :], iters)
    # a room's corner kinks the ring: no smooth curve predicts a block whose fit reaches one
    corner = np.abs(_kink(off / R, r, var, guard_px / R, (guard_px + CV_KINK_PX) / R,
                          iters)) > CV_KINK
    near = np.abs(np.angle(np.exp(1j * (mid[:, None] - mid[None, :])))) * R <= reach
    smooth = ~np.any(near & corner[None, :], axis=1)
    x = off[block, np.arange(len(r))] / R
    a, A = coef[block], cov[block]
    rhat = a[:, 0] + a[:, 1] * x + a[:, 2] * x ** 2
    X = np.stack([np.ones_like(x), x, x ** 2], -1)
    vhat = np.einsum("ni,nij,nj->n", X, A, X)
    cos_psi = r / np.hypot(r, a[:, 1] + 2 * x * a[:, 2])   # the curve's normal vs the radius
    enough = np.sum(train, axis=1)[block] >= 6
    keep = enough & smooth[block] & np.isfinite(rhat) & np.isfinite(vhat)
    res = (r - rhat) * cos_psi
    sd = np.sqrt(var + np.maximum(vhat, 0.0) * cos_psi ** 2)
    return RingCV(index=ok[keep], residual=res[keep], sd=sd[keep], block=block[keep],
                  gross_px=float(gross_px))


def ring_cv_line(lp):
    """One line for a report: :meth:`RingCV.summary`, or why the cross-validation was not
    run (too few unflagged points)."""
    try:
        return ring_cross_validation(lp).summary()
    except InvalidValueError as exc:
        return f"cross-validation: not run ({exc})"


def _wls(X, r, var, w0, iters):
    """Weighted least squares per block (design X (B, N, P), weights w0 (B, N)), refitted
    with Tukey's biweight on the residuals in units of their stated sds (a gross point
    among the neighbours does not bend the fit): the coefficients (B, P) and their
    covariance (B, P, P) from the stated variances of the points that carried it."""
    w = w0
    P = X.shape[-1]
    for _ in range(iters + 1):
        A = np.einsum("bn,bni,bnj->bij", w, X, X) + 1e-12 * np.eye(P)
        coef = np.linalg.solve(A, np.einsum("bn,bni,n->bi", w, X, r)[..., None])[..., 0]
        u = (r[None, :] - np.einsum("bni,bi->bn", X, coef)) / (4.685 * np.sqrt(var)[None, :])
        w = w0 * np.where(np.abs(u) < 1, (1 - u ** 2) ** 2, 0.0)
    return coef, np.linalg.inv(A)


def _kink(x, r, var, gap, reach, iters):
    """Per block middle (x: angles of the points from it, rad, (B, N)), the z-score of a
    hinge ``d |x|`` in a fit ``a + b x + c x^2 + d |x|`` through the points from ``gap`` to
    ``reach`` rad away on either side (B,), in the fits' own scale: a smooth bend is the
    quadratic's, a corner at the middle the hinge's."""
    w0 = ((np.abs(x) >= gap) & (np.abs(x) <= reach)) / var[None, :]
    X = np.stack([np.ones_like(x), x, x ** 2, np.abs(x)], -1)
    cf, cv = _wls(X, r, var, w0, iters)
    n = [np.sum((w0 > 0) & side, axis=1) for side in (x < 0, x > 0)]
    use = (n[0] >= 4) & (n[1] >= 4)
    # in the fits' own scale (the median block's misfit), so that covariances stated too
    # small or too large everywhere do not make corners of every block
    chi = np.sum(w0 * (r[None, :] - np.einsum("bni,bi->bn", X, cf)) ** 2, axis=1) / \
        np.maximum(n[0] + n[1] - 4, 1)
    scale = float(np.median(chi[use])) if use.any() else 1.0
    z = cf[:, 3] / np.sqrt(np.maximum(cv[:, 3, 3] * max(scale, 1e-12), 1e-300))
    return np.where(use, z, 0.0)
