"""The floor-plan likelihood with a misaligned laser cone (tilted and offset).

:class:`~bayescal.likelihood.floorplan.PlanLikelihood` puts each laser point on its
wall at azimuth ``t`` and on the paper's aligned cone, ``z = rho / tan(beta) - h``. A
hand-assembled sensor has the cone tilted by ``(tilt_x, tilt_y)`` and its apex offset by
``(offset_x, offset_y)`` (convention: ``docs/conventions.md``); the point is then still
``(x, y) = rho (cos t, sin t)`` on the wall, with ``z`` the tilted cone's height above
``(x, y)`` (:func:`~bayescal.sensor.laser.cone_height`) and ``dz/dt = z_x dx/dt + z_y
dy/dt`` from its slopes. Everything else (the two truncated Laplace pieces per point,
the Jeffreys prior, the outlier mixture) is the aligned likelihood's.

As for approximate points (:class:`~bayescal.likelihood.misaligned.MisalignedLikelihood`),
the pose enters as the first four extra globals, and the log marginal has a gradient
(:class:`~bayescal.likelihood.plan_gradient.PlanGradient`) for the sampler's HMC move:
``psi = (theta (7), pose (4), d_0, a_0, ..., [log sigma_px], [logit w])``, with the
pose's prior from :class:`~bayescal.likelihood.priors.Prior` (``pose_dists``); ``split``
returns the 11 numbers ``(theta, pose)`` as the geometry.
"""

from __future__ import annotations

from ..errors import InvalidValueError
from ..sensor.laser import cone_height
from .floorplan import PlanLikelihood
from .misaligned import PoseGlobals
from .plan_gradient import PlanGradient

__all__ = ["MisalignedPlanLikelihood", "plan_likelihood"]


class MisalignedPlanLikelihood(PoseGlobals, PlanGradient, PlanLikelihood):
    """:class:`~bayescal.likelihood.floorplan.PlanLikelihood` on a tilted and offset cone.

    Parameters are those of the aligned likelihood, plus ``prior``, where the pose's prior
    is read (:class:`~.misaligned.PoseGlobals`).

    Notes
    -----
    The geometry ``g`` (..., 11) replaces theta in ``split``, ``points_3d`` and
    ``residuals`` (``n_geo = 11``; ``J_theta`` of the residuals (N, 2, 11)).
    ``extra_names`` starts with the four pose names (:class:`~.misaligned.PoseGlobals`).
    At zero pose every quantity equals the aligned likelihood's to rounding.
    """

    #: production shares of the sampler's HMC and independence moves, and the HMC
    #: trajectory (whitened units): more and longer HMC than the sampler's defaults (0.3,
    #: 0.6, 1.5), because this posterior is far from Gaussian along the tilt, the principal
    #: point and a shift of the walls; trajectories of 3 mixed faster by the estimated tau
    #: but their ESS failed the seed-scatter check (``docs/floorplan.md`` section 13)
    move_weights = (0.45, 0.55)
    hmc_path = 2.0
    #: steps per tuning round (the sampler's default with a gradient: 60): the mass matrix
    #: and the independence proposal are fitted from the tuning rounds' draws. At tau ~10, 60
    #: steps left ~100 independent draws for a 24 x 24 covariance and 150 were needed (the
    #: first benchmark plan's chain: max tau 17.6, not converged -> 7.7); with the ring radii
    #: net of the pose's scale (:func:`bayescal.mcmc.coordinates.pose_scale`) tau is ~3 and 80
    #: steps do: the tuning then took half the CPU, ``docs/floorplan.md`` section 13, item 8
    tune_steps = 80
    #: the first tuning round's independence acceptance from which the sampler would leave
    #: HMC out (``bayescal.mcmc.steps.IMH_FITS``, 0.15, for the others): never here. The
    #: first round from the least-squares Laplace covariance accepts 10-17 % on plans not
    #: tuned on (8-12 % on the benchmark plans), and at 15-17 % the chains without HMC had max
    #: tau 10-38 (716-2560 steps, up to 15.7 s of CPU per 1000 ESS, 6.3x the aligned plan
    #: posterior) where with HMC 1.8-4.8; the first round stays, as a warm-up (HMC from its
    #: start had max tau 3.5-9.5 against 3.0-5.6); docs/floorplan.md section 13, item 9
    imh_fits = float("inf")
    #: the production chain's smallest burn-in, a fraction of the chain (the sampler's
    #: default ``bayescal.mcmc.steps.BURN_FLOOR``, 0.25): none, the burn-in is 5 tau, as for
    #: the aligned cone with approximate points. The chain starts from the last tuning
    #: round's walkers (HMC on the same target); over the steps between 5 tau and a quarter
    #: of the chain the means agree with the rest's (z rms 0.77-1.39 over 22-26 coordinates,
    #: the largest 2.53, five plans), and the seed-scatter check of the ESS
    #: passes; docs/floorplan.md section 13, item 9
    burn_floor = 0.0
    #: sample the apparent principal point (:func:`bayescal.mcmc.coordinates.pose_shift`)
    #: and the ring radii net of the pose's scale (``pose_scale``): max tau 31 -> 6.9 here
    #: with the first (150 points; the walls as they are, not net of the pose), 8.8 -> 3.5
    #: with the second (first benchmark plan, 300 points);
    #: the per-point posterior, nearly Gaussian, gains nothing from it (measured,
    #: ``docs/floorplan.md`` section 13)
    pose_coordinates = True

    def _height(self, theta, rho, r_t, x, y, dx, dy):
        """The tilted cone's height ``z`` (..., N) above the wall point and ``dz/dt``."""
        z, zx, zy = cone_height(theta, x, y)
        return z, zx * dx + zy * dy


def plan_likelihood(model, pixels, plan, prior, **kw):
    """The floor-plan likelihood of ``model`` (``"aligned"`` or ``"misaligned"``; the
    misaligned one reads the pose prior from ``prior``); the keywords are
    :class:`~bayescal.likelihood.floorplan.PlanLikelihood`'s."""
    if model == "misaligned":
        return MisalignedPlanLikelihood(pixels, plan, prior=prior, **kw)
    if model != "aligned":
        raise InvalidValueError(f"model must be 'aligned' or 'misaligned', got {model!r}")
    return PlanLikelihood(pixels, plan, **kw)
