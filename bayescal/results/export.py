"""Posterior samples for other tools: ArviZ.

ArviZ changed its interface at 1.0 (the ``arviz-base`` rewrite, what Python >= 3.12
installs): ``from_dict`` takes ``{group: {variable: array}}`` and returns a
``DataTree`` where 0.x took ``posterior=`` and returned an ``InferenceData``. Both are
supported, told apart by ``from_dict``'s signature, and so is ``arviz_base`` itself
(which ArviZ >= 1.0 re-exports).
"""

from __future__ import annotations

import inspect

from ..errors import MissingDependencyError
from ..sensor.parameters import PARAM_NAMES
from ..sensor.pose import POSE_NAMES

__all__ = ["to_inference_data", "posterior_dict"]


def posterior_dict(posterior):
    """The posterior group as ``{name: array}``, one chain: ``(1, S)`` per parameter, noise
    level and (misaligned model) laser-pose coordinate, ``points`` ``(1, S, N, 3)`` mm."""
    post = {n: posterior.param_samples[None, :, k] for k, n in enumerate(PARAM_NAMES)}
    post["points"] = posterior.point_samples[None]
    for n, v in posterior.noise_values().items():
        post[n] = v[None]
    if getattr(posterior, "model", "aligned") == "misaligned":
        for k, n in enumerate(POSE_NAMES):
            post[n] = posterior.laser_samples[None, :, k]
    return post


def to_inference_data(posterior, *, module=None):
    """The samples as ArviZ data (an ``InferenceData`` with ArviZ 0.x, a ``DataTree`` with
    ArviZ >= 1.0 or ``arviz_base``).

    Posterior group: the 8 paper parameters (one chain of S draws), the points as
    ``points`` (draw, point, axis) in mm, each inferred noise level and, with the
    misaligned model, ``tilt_x, tilt_y`` (rad) and ``offset_x, offset_y`` (mm).

    Parameters
    ----------
    posterior : Posterior
    module : module, optional
        The ArviZ module whose ``from_dict`` builds the data (default ``arviz``).

    Returns
    -------
    arviz.InferenceData or xarray.DataTree

    Raises
    ------
    ImportError
        ArviZ is not installed (``pip install 'bayescal[arviz]'``).
    """
    if module is None:
        try:
            import arviz as module
        except ImportError:
            raise MissingDependencyError(
                "to_inference_data needs arviz (pip install 'bayescal[arviz]')") \
                from None
    post = posterior_dict(posterior)
    kw = {"dims": {"points": ["point", "axis"]}, "coords": {"axis": ["x", "y", "z"]}}
    if "posterior" in inspect.signature(module.from_dict).parameters:     # ArviZ 0.x
        return module.from_dict(posterior=post, **kw)
    return module.from_dict({"posterior": post}, **kw)
