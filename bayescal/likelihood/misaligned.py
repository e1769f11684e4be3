"""The per-point likelihood with a misaligned laser cone (tilted and offset).

The aligned model (:class:`~bayescal.likelihood.points.LaserLikelihood`) puts the
cone's apex at ``(0, 0, -h)`` with its axis along z. A hand-assembled sensor has the
cone tilted by ``(tilt_x, tilt_y)`` and its apex offset by ``(offset_x, offset_y)``
(convention: ``docs/conventions.md``). This likelihood adds those four numbers to the
geometry: the unknown geometry is ``g = (theta (7), pose (4))``, 11 numbers.

The latent point stays parameter-independent: its horizontal position ``q = (x, y)``
where it meets the wall, with ``z`` from the tilted cone above ``(x, y)``
(:func:`~bayescal.sensor.pose.cone_point_pose_theta`). The Jeffreys point prior
``|J_q^T J_q|^(1/2)`` keeps its form: it is the information of ``q`` in the
misaligned model (``docs/bayes.md``, "The misaligned model").

For the samplers, the pose enters as the first four *extra globals* (before the
noise levels and the outlier fraction): ``psi = (theta (7), pose (4), extras...)``,
with the pose's prior from :class:`~bayescal.likelihood.priors.Prior`
(``pose_dists``). The analytic collapsed gradient (envelope theorem) covers the pose
through the residuals' Jacobians, so the sampler keeps its gradient (HMC) move.
"""

from __future__ import annotations

import numpy as np

from ..sensor.pose import POSE_NAMES
from .points import LaserLikelihood
from .priors import Prior

__all__ = ["MisalignedLikelihood", "PoseGlobals", "N_GEO_MISALIGNED"]

#: number of geometric unknowns of the misaligned model (theta then the pose)
N_GEO_MISALIGNED = 11


class PoseGlobals:
    """The laser pose as the first four extra globals (mixin of the misaligned likelihoods).

    Put before the aligned likelihood in the bases; passes everything but ``prior`` on.

    Parameters
    ----------
    prior : Prior or dict, optional
        Where the pose's prior is read (``Prior.pose_dists``; default zero +- 2 deg
        tilt and 5 mm offset, :func:`~bayescal.likelihood.priors.default_pose_prior`).
    """

    n_geo = N_GEO_MISALIGNED

    def __init__(self, pixels, scene, *, prior=None, **kw):
        super().__init__(pixels, scene, **kw)
        self.prior = prior if isinstance(prior, Prior) else Prior(prior)

    @property
    def extra_names(self):
        """The pose's four names, then the aligned likelihood's extra globals."""
        return POSE_NAMES + super().extra_names

    def log_prior_extra(self, extra):
        """Log prior of the pose (first four entries) and of the other extra globals."""
        extra = np.asarray(extra, dtype=float)
        return (self.prior.logpdf_pose(extra[..., :4])
                + super().log_prior_extra(extra[..., 4:]))


class MisalignedLikelihood(PoseGlobals, LaserLikelihood):
    """:class:`~bayescal.likelihood.points.LaserLikelihood` on a tilted and offset cone.

    Parameters are those of the aligned likelihood, plus ``prior``, where the pose's prior
    is read (:class:`PoseGlobals`).

    Notes
    -----
    The geometry ``g`` (..., 11) replaces theta in ``residuals`` and the
    per-point terms (``n_geo = 11``); ``split`` returns it first. ``extra_names``
    starts with the four pose names (:class:`PoseGlobals`).
    """
