"""The likelihood of chessboard views: per-view noise with a view-level systematic term.

View ``k`` has ``M_k`` corners; its residuals ``r_k = pixels - project_board(...)``
(``2 M_k`` numbers, u and v interleaved) are modelled as Gaussian with covariance::

    Sigma_k = sigma_k^2 I + tau^2 B_k B_k^T

``sigma_k`` is the view's own corner noise (px); ``B_k`` (``2 M_k x p``) spans a smooth
pixel displacement field over the board (polynomials of degree ``degree`` in the
board coordinates, separately in u and v, each column scaled to unit rms over the
corners), and ``tau`` (px) is the rms of that field: a per-view systematic error
(the board's print, its flatness, the mirror's departure from eq. (1) over the
patch the board covers), independent between views. ``tau = 0`` and one sigma
for all views is plain least squares. ``docs/camera.md`` argues the choice from
real views.

Every product with ``Sigma_k^-1`` goes through Woodbury with
``N_k = sigma_k^2 I_p + tau^2 B_k^T B_k``::

    X^T Sigma^-1 Y = (X^T Y - tau^2 (X^T B) N^-1 (B^T Y)) / sigma^2
    log det Sigma  = (2 M_k - p) log sigma^2 + log det N

Views with fewer corners are padded (mask), so that every array has a view axis
and any number of leading axes (walkers).
"""

from __future__ import annotations

import numpy as np

from ..errors import InvalidValueError
from ..image.views import as_views
from ..sensor.board import local_rows, log_det_left_jacobian, project_board

__all__ = ["BoardLikelihood", "NOISE_MODELS"]

#: the noise models: name -> (per-view sigma, systematic term)
NOISE_MODELS = {"plain": (False, False), "per-view": (True, False),
                "view-systematic": (True, True)}


def _basis(points, degree):
    """Polynomial displacement fields over a board: (M, 2) -> (2M, 2 * n_monomials)."""
    xy = points[:, :2]
    c = xy.mean(axis=0)
    half = np.maximum(np.ptp(xy, axis=0) / 2.0, 1e-9)
    x, y = ((xy - c) / half).T
    mono = [x ** i * y ** (d - i) for d in range(degree + 1) for i in range(d + 1)]
    F = np.stack(mono, axis=-1)
    F = F / np.sqrt(np.mean(F * F, axis=0))
    M, q = F.shape
    B = np.zeros((M, 2, 2 * q))
    B[:, 0, :q] = F
    B[:, 1, q:] = F
    return B.reshape(2 * M, 2 * q)


class BoardLikelihood:
    """Residuals, Woodbury products and the pose-integrated likelihood of board views.

    Parameters
    ----------
    views : sequence of BoardView
    degree : int
        Degree of the per-view displacement field (2: 12 columns per view).
    """

    def __init__(self, views, *, degree=2):
        views = as_views(views)
        self.views = views
        self.names = [v.name for v in views]
        self.K = len(views)
        M = max(v.n_corners for v in views)
        self.M = M
        self.mask = np.zeros((self.K, M), bool)
        self.pixels = np.zeros((self.K, M, 2))
        self.points = np.zeros((self.K, M, 3))
        self.degree = int(degree)
        if self.degree < 0:
            raise InvalidValueError(f"degree must be >= 0, got {degree!r}")
        p = (self.degree + 1) * (self.degree + 2)
        self.B = np.zeros((self.K, 2 * M, p))
        for k, v in enumerate(views):
            m = v.n_corners
            self.mask[k, :m] = True
            self.pixels[k, :m] = v.pixels
            self.points[k, :m] = v.points
            self.points[k, m:] = v.points[0]
            self.B[k, :2 * m] = _basis(v.points, self.degree)
        self.n_obs = 2 * self.mask.sum(axis=1)                       # (K,)
        self.BtB = np.einsum("kni,knj->kij", self.B, self.B)
        # B = U S V^T: Sigma^-1 = (I - U diag(t2 lam / (s2 + t2 lam)) U^T) / s2, lam = S^2
        # (rows reordered u block, v block: the layout of local_rows)
        U, S, _ = np.linalg.svd(self.B, full_matrices=False)
        self._U = np.ascontiguousarray(U.reshape(self.K, M, 2, -1).transpose(0, 2, 1, 3)
                                       .reshape(self.K, 2 * M, -1))
        self._lam = S * S                                            # (K, p)
        self._w2 = np.concatenate([self.mask, self.mask], axis=1).astype(float)
        self._pix2 = np.ascontiguousarray(np.swapaxes(self.pixels, -1, -2))   # (K, 2, M)
        self._w = np.repeat(self.mask, 2, axis=1).astype(float)     # (K, 2M)

    # ------------------------------------------------------------------ model
    def residuals(self, intrinsics, poses, *, jacobian=False):
        """Residuals ``pixels - model`` (..., K, 2M), zero on padding; Jacobians of the model.

        Returns ``r`` and, with ``jacobian=True``, ``Jk`` (..., K, 2M, 5) and ``Jp``
        (..., K, 2M, 6): derivatives of the residuals (minus the model's).
        """
        k = np.asarray(intrinsics, float)[..., None, :]
        out = project_board(k, poses, self.points, jacobian=jacobian)
        uv = out[0]
        sh = uv.shape[:-2]
        r = ((self.pixels - uv).reshape(sh + (2 * self.M,))) * self._w
        if not jacobian:
            return r
        w = self._w[..., None]
        Jk = -out[2].reshape(sh + (2 * self.M, 5)) * w
        Jp = -out[3].reshape(sh + (2 * self.M, 6)) * w
        return r, Jk, Jp

    # ------------------------------------------------------------- noise algebra
    def noise_factors(self, s2, t2):
        """Woodbury pieces for noise ``s2`` (..., K) and ``t2`` (...): N^-1 and log det Sigma."""
        s2 = np.asarray(s2, float)
        t2 = np.asarray(t2, float)[..., None]
        p = self.B.shape[-1]
        N = s2[..., None, None] * np.eye(p) + t2[..., None, None] * self.BtB
        Ninv = np.linalg.inv(N)
        logdet = (self.n_obs - p) * np.log(s2) + np.linalg.slogdet(N)[1]
        return Ninv, logdet

    def gram(self, G):
        """``(G^T G, G^T B)`` per view: G (..., K, 2M, a) -> (..., K, a, a), (..., K, a, p)."""
        Gt = np.swapaxes(G, -1, -2)
        return Gt @ G, Gt @ self.B

    def weighted(self, GG, GB, s2, t2, Ninv):
        """``G^T Sigma^-1 G`` from :meth:`gram`'s output (Woodbury)."""
        s2 = np.asarray(s2, float)[..., None, None]
        t2 = np.asarray(t2, float)[..., None, None, None]
        return (GG - t2 * (GB @ Ninv @ np.swapaxes(GB, -1, -2))) / s2

    def products(self, G, s2, t2, Ninv):
        """``G^T Sigma^-1 G`` per view: G (..., K, 2M, a) -> (..., K, a, a)."""
        return self.weighted(*self.gram(G), s2, t2, Ninv)

    # --------------------------------------------------------- poses integrated
    def pose_laplace(self, intrinsics, poses, s2, t2, *, n_steps=2):
        """Gauss-Newton on every view's pose at fixed intrinsics and noise, then Laplace.

        Parameters
        ----------
        intrinsics : ndarray, shape (..., 5)
        poses : ndarray, shape (..., K, 6)
            Starting poses.
        s2 : ndarray, shape (..., K)
        t2 : ndarray, shape (...)
        n_steps : int
            Gauss-Newton steps (each one residual and Jacobian evaluation).

        Returns
        -------
        log_marginal : ndarray, shape (..., K)
            ``log int N(r_k; 0, Sigma_k) d pose_k`` (flat pose prior), with the
            quadratic value at the last step's Gauss-Newton minimum.
        poses : ndarray, shape (..., K, 6)
            The updated poses.
        """
        Ninv, logdet = self.noise_factors(s2, t2)
        for _ in range(int(n_steps)):
            r, _, Jp = self.residuals(intrinsics, poses, jacobian=True)
            G = np.concatenate([Jp, r[..., None]], axis=-1)
            P = self.products(G, s2, t2, Ninv)
            H, g, rr = P[..., :6, :6], P[..., :6, 6], P[..., 6, 6]
            step = np.linalg.solve(H, g[..., None])[..., 0]
            poses = poses - step
        quad = rr - np.einsum("...i,...i->...", g, step)
        logdetH = np.linalg.slogdet(H)[1]
        lm = -0.5 * (quad + logdet + logdetH + (self.n_obs - 6) * np.log(2 * np.pi))
        return np.where(np.isfinite(lm), lm, -np.inf), poses

    def log_marginal(self, intrinsics, poses, s2, t2):
        """:meth:`pose_laplace`'s ``log_marginal`` with one Gauss-Newton step, cheaper.

        The same number (to rounding): the pose Jacobian is taken in local coordinates
        (:func:`~bayescal.sensor.board.local_rows`, no derivative of Rodrigues' formula)
        and the Laplace determinant carried back to the rotation vector by
        ``2 log det J_l(w)``; the Gauss-Newton minimum's quadratic value does not depend on
        the coordinates. The noise enters through the SVD of each view's field basis,
        so no ``p x p`` inverse or determinant is taken per call.

        Parameters
        ----------
        intrinsics : ndarray, shape (..., 5)
        poses : ndarray, shape (..., K, 6)
            The poses at which each view is linearised.
        s2 : ndarray, shape (..., K)
        t2 : ndarray, shape (...)

        Returns
        -------
        ndarray, shape (..., K)
        """
        s2 = np.asarray(s2, float)
        t2 = np.asarray(t2, float)[..., None, None]
        G = local_rows(np.asarray(intrinsics, float)[..., None, :], poses, self.points)
        G[..., 6, :, :] -= self._pix2                # minus the residual: signs cancel below
        G = G.reshape(G.shape[:-2] + (2 * self.M,)) * self._w2[:, None, :]    # (..., K, 7, 2M)
        GU = G @ self._U                                             # (..., K, 7, p)
        tl = t2 * self._lam
        c = tl / (s2[..., None] + tl)
        P = ((G @ np.swapaxes(G, -1, -2) - (GU * c[..., None, :]) @ np.swapaxes(GU, -1, -2))
             / s2[..., None, None])
        H, g, rr = P[..., :6, :6], P[..., :6, 6], P[..., 6, 6]
        quad = rr - np.einsum("...i,...i->...", g, np.linalg.solve(H, g[..., None])[..., 0])
        p = self.B.shape[-1]
        logdet = ((self.n_obs - p) * np.log(s2) + np.sum(np.log(s2[..., None] + tl), axis=-1)
                  + np.linalg.slogdet(H)[1] + 2.0 * log_det_left_jacobian(poses[..., :3]))
        lm = -0.5 * (quad + logdet + (self.n_obs - 6) * np.log(2 * np.pi))
        return np.where(np.isfinite(lm), lm, -np.inf)
