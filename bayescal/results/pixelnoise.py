"""The pixel noise a calibration measured, for new pixels that come without their own.

A calibration from extracted laser pixels weighs each pixel by its 2x2 covariance (the
extractor's: small across the laser ring, large along it) times a scale, given or fitted.
Its ``sigma_px`` is then that scale, not a noise in px. New pixels without covariances
(a file of ``u, v`` only) get :class:`RingNoise`: the calibration pixels' typical variance
across the ring and along it (medians, in the frame of each pixel's direction about the
principal point, where the ring's normal points), turned to each new pixel's direction and
times the scale.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..errors import InvalidValueError

__all__ = ["RingNoise", "ring_noise_of"]


def _frames(pixels, center):
    """Unit vectors across the ring (away from ``center``) and along it, each (M, 2)."""
    d = np.asarray(pixels, float) - np.asarray(center, float)
    r = np.linalg.norm(d, axis=-1, keepdims=True)
    n = np.divide(d, r, out=np.tile([1.0, 0.0], (len(d), 1)), where=r > 0)
    return n, np.stack([-n[:, 1], n[:, 0]], axis=-1)


@dataclass(frozen=True)
class RingNoise:
    """A calibration's typical pixel noise across and along the laser ring.

    Attributes
    ----------
    center : tuple of float
        The principal point ``(u0, v0)``, px: the ring's normal at a pixel points away from it.
    sd_across, sd_along : float
        Noise sd across and along the ring, px, the scale included.
    scale : float
        The scale on the calibration's covariances included above.
    n_pixels : int
        How many calibration pixels the medians are over.
    """

    center: tuple
    sd_across: float
    sd_along: float
    scale: float
    n_pixels: int

    @classmethod
    def from_calibration(cls, pixels, pixel_cov, center, scale=1.0):
        """The medians of the calibration pixels' variances across and along the ring.

        Parameters
        ----------
        pixels : array_like, shape (N, 2)
            The calibration's pixels, px.
        pixel_cov : array_like, shape (N, 2, 2)
            Their covariances, px^2 (before the scale).
        center : array_like, shape (2,)
            Principal point, px.
        scale : float
            The scale on the covariances the calibration used or fitted (a noise of
            ``scale^2 pixel_cov``).
        """
        px = np.asarray(pixels, float)
        cov = np.asarray(pixel_cov, float)
        if px.ndim != 2 or px.shape[1] != 2 or cov.shape != (len(px), 2, 2) or not len(px):
            raise InvalidValueError(f"pixels (N, 2) and pixel_cov (N, 2, 2) must match, got "
                                    f"{px.shape} and {cov.shape}")
        s = float(scale)
        if not (np.isfinite(s) and s > 0):
            raise InvalidValueError(f"scale must be a finite positive number, got {scale!r}")
        n, t = _frames(px, center)
        across = np.einsum("ni,nij,nj->n", n, cov, n)
        along = np.einsum("ni,nij,nj->n", t, cov, t)
        return cls(tuple(float(c) for c in center), s * float(np.sqrt(np.median(across))),
                   s * float(np.sqrt(np.median(along))), s, len(px))

    def covariance(self, pixels):
        """The noise of new pixels (M, 2), px: (M, 2, 2) px^2, turned to each one's direction."""
        n, t = _frames(np.atleast_2d(np.asarray(pixels, float)), self.center)
        return (self.sd_across ** 2 * np.einsum("mi,mj->mij", n, n)
                + self.sd_along ** 2 * np.einsum("mi,mj->mij", t, t))

    def describe(self):
        """One line: what the noise is and where it comes from."""
        return (f"sd {self.sd_across:.3g} px across the ring and {self.sd_along:.3g} px along "
                f"it: the medians over the calibration's {self.n_pixels} pixel covariances, "
                f"times its scale {self.scale:.3g} on them")


def ring_noise_of(result):
    """A calibration's :class:`RingNoise`, or None when it did not weigh its pixels by
    covariances.

    Parameters
    ----------
    result : CalibrationResult or Posterior
        Least squares: its ``extras["pixel_cov"]`` and ``extras["pixels"]``, the scale it
        used (``extras["sigma_px"]``) or estimated; a posterior: its ``pixel_cov`` and
        ``pixels``, the posterior mean scale, the posterior mean principal point.
    """
    if hasattr(result, "param_samples"):
        cov = getattr(result, "pixel_cov", None)
        if cov is None:
            return None
        center = result.geometry_samples.mean(axis=0)[3:5]
        return RingNoise.from_calibration(result.pixels, cov, center,
                                          float(np.mean(result._sigma_px_samples())))
    cov, px = result.extras.get("pixel_cov"), result.extras.get("pixels")
    if cov is None or px is None:
        return None
    scale = result.extras.get("sigma_px") or result.sigma_px_estimated or 1.0
    return RingNoise.from_calibration(px, cov, (result.params.u0, result.params.v0), scale)
