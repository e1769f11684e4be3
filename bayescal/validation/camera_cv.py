"""Cross-validation of a camera calibration, the way mrcal checks lens models.

:func:`halves_chi2`: calibrate on two disjoint sets of views, project the same
directions with both, and compare the difference with its predicted covariance
(the sum of the two predicted pixel covariances): chi-square per 2-D direction,
2 expected when the stated covariances are honest.

:func:`heldout_chi2`: calibrate on the other views, fit one view's pose from half
its corners (intrinsics fixed), predict the other half; chi-square per
coordinate of the prediction errors against their predicted covariance (the view's
noise, the pose's and the intrinsics' uncertainty), 1 expected.
"""

from __future__ import annotations

import itertools

import numpy as np

from ..fit.camera import calibrate_camera
from ..fit.camera_start import pose_from_rays
from ..likelihood.boards import BoardLikelihood

__all__ = ["halves_chi2", "heldout_chi2", "cv_directions", "all_splits", "camera_coverage"]


def cv_directions(result, *, radii=(150.0, 200.0, 250.0, 300.0), n_azimuth=16):
    """Unit rays (R * A, 3) of pixels on circles of the given radii about the centre."""
    k = result.intrinsics
    az = np.linspace(0.0, 2 * np.pi, int(n_azimuth), endpoint=False)
    rr, aa = np.meshgrid(np.asarray(radii, float), az, indexing="ij")
    px = np.stack([k["u0"] + rr * np.cos(aa), k["v0"] + rr * np.sin(aa)], -1).reshape(-1, 2)
    return result.reconstruct(px)[0]


def all_splits(n_views, *, max_splits=None):
    """Every split of ``n_views`` into two halves, sizes differing by at most one (with an
    even number, each split once: the first half holds view 0); ``max_splits`` keeps the
    first ones (generated lazily: 30 views have ~1.5e8 splits)."""
    idx = range(n_views)

    def splits():
        for c in itertools.combinations(idx, n_views // 2):
            if n_views % 2 == 0 and 0 not in c:
                continue
            yield list(c), [i for i in idx if i not in c]

    return list(itertools.islice(splits(), max_splits))


def halves_chi2(views, splits=None, *, directions=None, **fit_options):
    """Chi-square per direction between calibrations on disjoint halves of the views.

    Parameters
    ----------
    views : sequence of BoardView
    splits : list of (list of int, list of int), optional
        Index sets; default :func:`all_splits`.
    directions : ndarray, shape (D, 3), optional
        Rays to project (default :func:`cv_directions` of the fit on all the views:
        radii 150-300 px).
    **fit_options
        Passed to :func:`~bayescal.calibrate_camera` (e.g. ``noise=``).

    Returns
    -------
    dict
        ``chi2`` (per split, mean over directions, 2 expected), ``mean_shift`` (px, per
        split), ``splits``.
    """
    views = list(views)
    splits = all_splits(len(views)) if splits is None else splits
    if directions is None:
        directions = cv_directions(calibrate_camera(views, **fit_options))
    chi2, shift = [], []
    for a, b in splits:
        ra = calibrate_camera([views[i] for i in a], **fit_options)
        rb = calibrate_camera([views[i] for i in b], **fit_options)
        d = np.asarray(directions, float)
        ua, ca = ra.project(d, return_cov=True)
        ub, cb = rb.project(d, return_cov=True)
        diff = ua - ub
        c = np.einsum("ni,nij,nj->n", diff, np.linalg.inv(ca + cb), diff)
        chi2.append(float(np.mean(c)))
        shift.append(float(np.mean(np.linalg.norm(diff, axis=-1))))
    return {"chi2": np.array(chi2), "mean_shift": np.array(shift), "splits": splits}


def _halves_of(view, how):
    """Index sets (fit, predict) of a view's corners: interleaved, or the first half of the
    rows against the rest (extrapolating)."""
    m = view.n_corners
    if how == "interleaved":
        i = np.arange(m)
        return i[i % 2 == 0], i[i % 2 == 1]
    y = view.points[:, 1]
    cut = np.median(y)
    return np.flatnonzero(y < cut), np.flatnonzero(y >= cut)


def _predict_half(cam, view, fit_idx, pred_idx):
    """Prediction errors of a view's held-out corners and their covariance."""
    lik = BoardLikelihood([view], degree=cam.info.get("degree", 2))
    j = cam.view_names.index(view.name) if view.name in cam.view_names else None
    sig2 = float(np.median(cam.sigma) ** 2) if j is None else float(cam.sigma[j] ** 2)
    t2 = cam.tau ** 2
    Sigma = sig2 * np.eye(2 * view.n_corners) + t2 * lik.B[0] @ lik.B[0].T
    f = np.repeat(fit_idx, 2) * 2 + np.tile([0, 1], len(fit_idx))
    p = np.repeat(pred_idx, 2) * 2 + np.tile([0, 1], len(pred_idx))
    rays = cam.reconstruct(view.pixels[fit_idx])[0]
    pose = pose_from_rays(rays, view.points[fit_idx])
    W11 = np.linalg.inv(Sigma[np.ix_(f, f)])
    for _ in range(10):
        r, Jk, Jp = lik.residuals(cam.k, pose[None], jacobian=True)
        H = Jp[0, f].T @ W11 @ Jp[0, f]
        pose = pose - np.linalg.solve(H, Jp[0, f].T @ W11 @ r[0, f])
    r, Jk, Jp = lik.residuals(cam.k, pose[None], jacobian=True)
    A = np.linalg.solve(H, Jp[0, f].T @ W11)                     # pose error per e_f
    L = np.zeros((len(p), 2 * view.n_corners))
    L[:, p] = np.eye(len(p))
    L[:, f] -= Jp[0, p] @ A
    Lk = Jk[0, p] - Jp[0, p] @ A @ Jk[0, f]
    C = L @ Sigma @ L.T + Lk @ cam.cov @ Lk.T
    return r[0, p], C


def heldout_chi2(views, *, how="interleaved", **fit_options):
    """Chi-square per coordinate of each view's held-out corners (calibrated without it).

    Parameters
    ----------
    views : sequence of BoardView
    how : {"interleaved", "extrapolating"}
        Which corners predict which: every other corner, or the first rows the rest.
    **fit_options
        Passed to :func:`~bayescal.calibrate_camera`.

    Returns
    -------
    dict
        ``chi2`` (per view, per coordinate; 1 expected) and ``pooled`` (all views).
    """
    views = list(views)
    out, tot, n = [], 0.0, 0
    for i, v in enumerate(views):
        others = [w for j, w in enumerate(views) if j != i]
        cam = calibrate_camera(others, **fit_options)
        fit_idx, pred_idx = _halves_of(v, how)
        e, C = _predict_half(cam, v, fit_idx, pred_idx)
        c = float(e @ np.linalg.solve(C, e))
        out.append(c / len(e))
        tot, n = tot + c, n + len(e)
    return {"chi2": np.array(out), "pooled": tot / n}


def camera_coverage(n_rep, *, level=0.9, rng=None, simulate=None, **fit_options):
    """Coverage of the intrinsics' intervals over simulated replications.

    Parameters
    ----------
    n_rep : int
        Replications (each a fresh set of views).
    level : float
        Central interval level (normal, from ``covariance()``).
    rng : Generator, int or None
    simulate : dict, optional
        Options of :func:`~bayescal.simulate_views` (default: its measured structure).
    **fit_options
        Passed to :func:`~bayescal.calibrate_camera`.

    Returns
    -------
    dict
        ``hits`` (5,) intervals that held the truth, ``z`` (n_rep, 5) standardised errors.
    """
    from scipy.stats import norm

    from .._validation import resolve_rng
    from ..scene.boards import simulate_views

    rng = resolve_rng(rng)
    zq = norm.ppf(0.5 + level / 2)
    zs = []
    for _ in range(int(n_rep)):
        views, truth = simulate_views(rng=rng, **(simulate or {}))
        cam = calibrate_camera(views, **fit_options)
        zs.append((cam.k - truth["intrinsics"]) / np.sqrt(np.diag(cam.covariance())))
    z = np.array(zs)
    return {"hits": np.sum(np.abs(z) <= zq, axis=0), "z": z}
