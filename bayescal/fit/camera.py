"""Calibrating the camera from board views: least squares in per-view blocks, noise by REML.

Unknowns: the five intrinsics ``k`` and one pose per view. Each view couples only to
``k``, so its 6x6 pose block is eliminated by a Schur complement (as
:mod:`bayescal.fit.schur` eliminates each laser point's coordinates) and an
iteration costs O(views). The noise of :class:`~bayescal.likelihood.boards.BoardLikelihood`
(per-view ``sigma_k`` and the systematic amplitude ``tau``) is estimated by
restricted maximum likelihood: the likelihood with ``k`` and every pose integrated
out in the linearised model, alternated with the fit until the noise settles. The
covariance of ``k`` is the inverse Schur complement at the final noise, so the
least-squares result carries the same noise model as the posterior.
"""

from __future__ import annotations

import numpy as np
from scipy.optimize import minimize

from ..errors import BayescalWarning, DegenerateInputError, InvalidValueError
from ..image.views import as_views
from ..likelihood.boards import NOISE_MODELS, BoardLikelihood
from ..results.camera import CameraResult
from ..sensor.board import CAMERA_NAMES
from .camera_start import start_camera
from .schur import damped_step

__all__ = ["calibrate_camera", "camera_normal_equations", "solve_camera", "estimate_noise",
           "sandwich_covariance"]

#: bounds of the noise levels, px
NOISE_BOUNDS = (1e-4, 1e3)


def camera_normal_equations(lik, k, poses, s2, t2):
    """Per-view normal-equation blocks of ``[Jk, Jp, r]`` weighted by ``Sigma_k^-1``.

    Returns
    -------
    ndarray, shape (K, 12, 12)
        ``G^T Sigma^-1 G`` with ``G = [Jk (5), Jp (6), r (1)]`` per view.
    """
    r, Jk, Jp = lik.residuals(k, poses, jacobian=True)
    G = np.concatenate([Jk, Jp, r[..., None]], axis=-1)
    Ninv, _ = lik.noise_factors(s2, t2)
    return lik.products(G, s2, t2, Ninv)


def _schur(P, lam=0.0):
    """Schur complement on the intrinsics, its right-hand side and the pose solves."""
    A = P[:, :5, :5].sum(axis=0)
    B, C = P[:, :5, 5:11], P[:, 5:11, 5:11].copy()
    gk, gp = P[:, :5, 11].sum(axis=0), P[:, 5:11, 11]
    A = A + lam * np.diag(np.diag(A))
    C[:, np.arange(6), np.arange(6)] *= 1.0 + lam
    Cinv = np.linalg.inv(C)
    BC = np.einsum("kij,kjl->kil", B, Cinv)
    S = A - np.einsum("kil,kjl->ij", BC, B)
    rhs = gk - np.einsum("kil,kl->i", BC, gp)
    return S, rhs, Cinv, B, gp


def _step(P, lam):
    S, rhs, Cinv, B, gp = _schur(P, lam)
    dk = -np.linalg.solve(S, rhs)
    dp = -np.einsum("kij,kj->ki", Cinv, gp + np.einsum("kji,j->ki", B, dk))
    return dk, dp


def solve_camera(lik, k0, poses0, s2, t2, *, max_iter=100, xtol=1e-10):
    """Levenberg-Marquardt on the intrinsics and every pose at fixed noise.

    Returns
    -------
    k : ndarray, shape (5,)
    poses : ndarray, shape (K, 6)
    P : ndarray, shape (K, 12, 12)
        Normal-equation blocks at the solution.
    n_iter : int
    """
    k, poses = np.array(k0, float), np.array(poses0, float)
    lam = 1e-3

    def cost_of(step):
        r = lik.residuals(k + step[0], poses + step[1])
        Ninv, _ = lik.noise_factors(s2, t2)
        c = 0.5 * np.sum(lik.products(r[..., None], s2, t2, Ninv))
        return c if np.isfinite(c) else np.inf

    P = camera_normal_equations(lik, k, poses, s2, t2)
    n_iter = 0
    for n_iter in range(1, max_iter + 1):  # noqa: B007 (the count is returned)
        cost = 0.5 * P[:, 11, 11].sum()
        step, new, lam, _ = damped_step(lambda lm, P=P: _step(P, lm), cost_of, cost, lam)
        if step is None:
            break
        k, poses = k + step[0], poses + step[1]
        P = camera_normal_equations(lik, k, poses, s2, t2)
        lam = max(lam / 10.0, 1e-12)
        small = np.max(np.abs(step[0]) / (np.abs(k) + 1.0)) < xtol
        if small or cost - new < 1e-14 * max(cost, 1.0):
            break
    return k, poses, P, n_iter


def _noise_values(eta, K, model):
    """(s2 per view, t2) from log noise levels ``eta`` of a noise model."""
    per_view, systematic = NOISE_MODELS[model]
    s = np.exp(eta[:K]) if per_view else np.full(K, np.exp(eta[0]))
    t = np.exp(eta[-1]) if systematic else 0.0
    return s * s, t * t


def restricted_loglik(lik, gram, eta, model):
    """REML log likelihood of the noise levels in the model linearised at ``G``.

    ``gram`` is ``lik.gram(G)`` of ``G`` (K, 2M, 12) = ``[Jk, Jp, r]``; ``k`` and the poses
    are integrated out
    with flat priors, which makes the per-view noise levels unbiased for the
    degrees of freedom the fit uses.
    """
    s2, t2 = _noise_values(eta, lik.K, model)
    Ninv, logdet = lik.noise_factors(s2, t2)
    P = lik.weighted(*gram, s2, t2, Ninv)
    try:
        S, rhs, Cinv, B, gp = _schur(P)
        quad = (P[:, 11, 11].sum() - np.einsum("ki,kij,kj->", gp, Cinv, gp)
                - rhs @ np.linalg.solve(S, rhs))
        ld = np.sum(np.linalg.slogdet(P[:, 5:11, 5:11])[1]) + np.linalg.slogdet(S)[1]
    except np.linalg.LinAlgError:
        return -np.inf
    n = lik.n_obs.sum() - 5 - 6 * lik.K
    val = -0.5 * (quad + logdet.sum() + ld + n * np.log(2 * np.pi))
    return val if np.isfinite(val) else -np.inf


def _n_eta(K, model):
    per_view, systematic = NOISE_MODELS[model]
    return (K if per_view else 1) + int(systematic)


def estimate_noise(lik, k, poses, eta0, model):
    """Maximise :func:`restricted_loglik` over the log noise levels (linearised at k, poses)."""
    r, Jk, Jp = lik.residuals(k, poses, jacobian=True)
    gram = lik.gram(np.concatenate([Jk, Jp, r[..., None]], axis=-1))
    lo, hi = np.log(NOISE_BOUNDS)
    res = minimize(lambda e: -restricted_loglik(lik, gram, e, model), eta0, method="L-BFGS-B",
                   bounds=[(lo, hi)] * len(eta0))
    return res.x, gram


def _noise_hessian(lik, gram, eta, model, h=1e-3):
    """Hessian of -REML in the noise levels (natural units, px) by central differences."""
    x = np.exp(eta)
    n = len(x)

    def f(v):
        return -restricted_loglik(lik, gram, np.log(np.maximum(v, 1e-12)), model)

    H = np.empty((n, n))
    e = np.eye(n) * h * x
    for i in range(n):
        for j in range(i, n):
            num = (f(x + e[i] + e[j]) - f(x + e[i] - e[j])
                   - f(x - e[i] + e[j]) + f(x - e[i] - e[j]))
            H[i, j] = H[j, i] = num / (4 * e[i, i] * e[j, j])
    return H


def _image_size(views, image_size):
    """``((width, height), how)``: given, the views' own, or (``"corners"``) a guess from the
    corners' extent that a camera file then does not record as the image's size."""
    if image_size is not None:
        size = tuple(int(s) for s in image_size)
        if len(size) != 2 or min(size) <= 0:
            raise InvalidValueError(f"image_size must be (width, height) > 0, got {image_size!r}")
        return size, "given"
    sizes = {v.image_size for v in views if v.image_size is not None}
    if len(sizes) > 1:
        raise InvalidValueError(f"views come from images of different sizes {sorted(sizes)}; "
                                "pass image_size")
    if sizes:
        return sizes.pop(), "views"
    px = np.concatenate([v.pixels for v in views])
    return (int(np.ceil(px[:, 0].max())) + 1, int(np.ceil(px[:, 1].max())) + 1), "corners"


def _fit_noise_loop(lik, k, poses, model, max_outer):
    """Alternate the fit at fixed noise and REML on the noise until the noise settles."""
    r = lik.residuals(k, poses)
    rms = np.sqrt(np.sum(r * r) / lik.n_obs.sum())
    eta = np.full(_n_eta(lik.K, model), np.log(max(rms, 1e-3)))
    s2, t2 = _noise_values(eta, lik.K, model)
    for _ in range(max_outer):
        k, poses, P, _ = solve_camera(lik, k, poses, s2, t2)
        new, G = estimate_noise(lik, k, poses, eta, model)
        done = np.max(np.abs(new - eta)) < 1e-4
        eta = new
        s2, t2 = _noise_values(eta, lik.K, model)
        if done:
            break
    k, poses, P, _ = solve_camera(lik, k, poses, s2, t2)
    return k, poses, eta, P


def calibrate_camera(views, *, image_size=None, noise="view-systematic", degree=2, init=None,
                     signs=(1.0, -1.0), estimator="weighted", max_outer=20):
    """Calibrate the camera's five intrinsics from chessboard views (least squares).

    Parameters
    ----------
    views : sequence of BoardView
        One or more views (every one is used; a view that cannot be fitted is an error
        naming it). A view's per-corner ``covariance`` is not used: the noise is inferred.
    image_size : tuple of int, optional
        ``(width, height)``, px (default: the views' own, else the corners' extent).
    noise : {"view-systematic", "per-view", "plain"}
        The noise model (:mod:`bayescal.likelihood.boards`): per-view noise plus a per-view
        systematic displacement field (default), per-view noise only, or one noise level.
    degree : int
        Degree of the per-view systematic field (default 2).
    init : dict or array_like, optional
        Start intrinsics ``{xi, gamma_u, gamma_v, u0, v0}`` (default: the scan of
        :func:`~bayescal.fit.camera_start.start_camera`).
    signs : tuple of float
        Signs of ``(gamma_u, gamma_v)`` for the start. A planar board cannot tell them
        (a reflection of frame C and of the board's normal leave every pixel unchanged);
        the default is the paper's convention, ``alpha_u > 0``, ``alpha_v < 0``.
    estimator : {"weighted", "gls"}
        With the systematic term: ``"weighted"`` (default) fits with each view weighted by
        its own noise level (``noise="per-view"``) and states the covariance of that
        estimate under the full noise model (a sandwich); ``"gls"`` weights by the full
        model. On the real views of ``docs/camera.md`` the generalised estimate moved
        6.7 px (in projected directions) from the weighted one, more than the model
        allows, while the weighted one agrees with an independent fit; see there.
    max_outer : int
        Most alternations between the fit and the noise estimate.

    Returns
    -------
    CameraResult
    """
    views = as_views(views)
    if noise not in NOISE_MODELS:
        raise InvalidValueError(f"noise must be one of {sorted(NOISE_MODELS)}, got {noise!r}")
    if estimator not in ("weighted", "gls"):
        raise InvalidValueError(f"estimator must be 'weighted' or 'gls', got {estimator!r}")
    size, size_how = _image_size(views, image_size)
    lik = BoardLikelihood(views, degree=degree)
    fixed = None
    if init is not None:
        if isinstance(init, dict) and not set(CAMERA_NAMES) <= set(init):
            raise InvalidValueError(f"init must give the 5 intrinsics {CAMERA_NAMES}, got {init!r}")
        fixed = np.array([init[n] for n in CAMERA_NAMES] if isinstance(init, dict) else init,
                         float)
        if fixed.shape != (5,) or not np.all(np.isfinite(fixed)):
            raise InvalidValueError(f"init must give the 5 intrinsics {CAMERA_NAMES}, got {init!r}")
    try:
        k0, poses0 = start_camera(lik, size, signs=signs, fixed=fixed)
        if noise == "view-systematic" and estimator == "weighted":
            k, poses, eta_w, P = _fit_noise_loop(lik, k0, poses0, "per-view", max_outer)
            eta, _ = estimate_noise(lik, k, poses, np.append(eta_w, np.log(0.1)), noise)
            return _checked(_result(lik, k, poses, eta, P, noise, size, weights_eta=eta_w),
                            size_how)
        k, poses, eta, P = _fit_noise_loop(lik, k0, poses0, noise, max_outer)
        return _checked(_result(lik, k, poses, eta, P, noise, size), size_how)
    except np.linalg.LinAlgError as exc:    # a singular normal matrix: the views are degenerate
        raise DegenerateInputError(
            f"the {lik.K} views do not determine the camera (a singular normal matrix: {exc}); "
            "use more views, boards at several distances and tilts, or check the corners"
        ) from None


def _checked(result, size_how):
    """Record where the image size came from (``info["image_size_from"]``: ``"given"``,
    ``"views"`` or ``"corners"``, their extent: no image's size); warn when the views leave
    intrinsics undetermined (:meth:`CameraResult.unidentified`)."""
    result.info["image_size_from"] = size_how
    bad = result.unidentified()
    if bad:
        import warnings

        sd = result.std()
        warnings.warn("the views do not determine the camera: "
                      + ", ".join(f"{n} = {result.intrinsics[n]:.4g} +- {sd[n]:.3g}" for n in bad)
                      + " (sd >= |value|); check the board size and square, and use views "
                      "spread over the image", BayescalWarning, stacklevel=3)
    return result


def sandwich_covariance(lik, k, poses, s2w, s2, t2):
    """Covariance of the intrinsics fitted with weights ``1 / s2w`` under noise ``(s2, t2)``.

    The fit's normal matrix ``H`` (weights ``1 / s2w_k``) is the bread, the views' noise
    ``G^T Sigma_k G`` the meat; the poses are eliminated per view:
    ``S^-1 (sum_k T_k meat_k T_k^T) S^-1`` with ``T_k = [I, -B_k C_k^-1]``.
    """
    r, Jk, Jp = lik.residuals(k, poses, jacobian=True)
    GG, GB = lik.gram(np.concatenate([Jk, Jp], axis=-1))
    s2w = np.asarray(s2w, float)[:, None, None]
    bread = GG / s2w
    meat = (np.asarray(s2, float)[:, None, None] * GG
            + t2 * GB @ np.swapaxes(GB, -1, -2)) / s2w ** 2
    A = bread[:, :5, :5].sum(axis=0)
    B, C = bread[:, :5, 5:], bread[:, 5:, 5:]
    BC = B @ np.linalg.inv(C)
    S = A - np.einsum("kil,kjl->ij", BC, B)
    T = np.concatenate([np.broadcast_to(np.eye(5), BC.shape[:1] + (5, 5)), -BC], axis=-1)
    Si = np.linalg.inv(S)
    return Si @ np.einsum("kia,kab,kjb->ij", T, meat, T) @ Si


def _result(lik, k, poses, eta, P, noise, size, weights_eta=None):
    s2, t2 = _noise_values(eta, lik.K, noise)
    S, _, Cinv, B, _ = _schur(P)
    cov = np.linalg.inv(S)
    estimator = "least squares weighted by the noise model"
    if weights_eta is not None:
        s2w, _ = _noise_values(weights_eta, lik.K, "per-view")
        cov = sandwich_covariance(lik, k, poses, s2w, s2, t2)
        estimator = "per-view weighted least squares, covariance under the noise model"
    CB = np.einsum("kij,klj->kil", Cinv, B)                     # C^-1 B^T: (K, 6, 5)
    pose_cov = Cinv + np.einsum("kia,ab,kjb->kij", CB, cov, CB)
    r = lik.residuals(k, poses).reshape(lik.K, lik.M, 2)
    res = [r[j][lik.mask[j]] for j in range(lik.K)]
    rr, Jk, Jp = lik.residuals(k, poses, jacobian=True)
    noise_cov = _noise_cov(lik, lik.gram(np.concatenate([Jk, Jp, rr[..., None]], -1)), eta, noise)
    bad = [lik.names[j] for j in range(lik.K) if not np.all(np.isfinite(res[j]))]
    if bad or not np.all(np.isfinite(cov)):
        raise DegenerateInputError(f"the fit failed on view(s) {', '.join(bad) or 'all'}")
    return CameraResult(k, cov, poses, res, lik.names, noise=noise, sigma=np.sqrt(s2),
                        tau=np.sqrt(t2), image_size=size, pose_cov=pose_cov,
                        noise_cov=noise_cov,
                        info={"degree": lik.degree, "estimator": estimator,
                              "weight_sigma": np.sqrt(_noise_values(
                                  eta if weights_eta is None else weights_eta, lik.K,
                                  noise if weights_eta is None else "per-view")[0]).tolist()})


def _noise_cov(lik, gram, eta, noise):
    H = _noise_hessian(lik, gram, eta, noise)
    try:
        return np.linalg.inv(H)
    except np.linalg.LinAlgError:
        return np.full(H.shape, np.nan)
