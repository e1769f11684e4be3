"""A targeted model check: the signature of a laser cone tilted against the camera axis.

A tilted cone puts the laser points above the paper's cone on one side of the room and
below it on the other. Fitted with the aligned model, the principal point absorbs the part
of that error which is a first harmonic of the azimuth in the image (u0 and v0 then move by
tens of their sds: ``docs/model.md``), and what is left shows in each point's misfit as a
*second* harmonic around the ring: large on two opposite sides, small between. This
statistic is the fraction of the per-point misfit (sum of squared standardized residuals,
from the predictive check) that ``cos 2 azimuth`` and ``sin 2 azimuth`` explain, with its
p-value from permutations of the points over the azimuths. It runs inside
:func:`bayescal.checks.model.model_check` (registered in its ``STATISTICS``).

Measured (least squares, 300 points, 2500 mm, 0.2 px, z unknown, pixel noise inferred,
20 sensors each): tilted 1 degree, 20 of 20 flagged (p = 0.001); 0.5 degree, 19 of 20;
aligned, 2 of 20. With the noise given, the global chi-square of the check catches most
tilted sensors first and this statistic alone flags fewer (``studies/misalignment.py``,
30 sensors each: 2, 21, 18 and 24 of 30 at 0.25, 0.5, 1 and 2 degrees, while the whole
check fails 20/30 at 0.25 degree and 30/30 from 0.5 degree on). On aligned sensors
per-point misfits are not quite exchangeable around a room of unequal walls, so the
false-alarm rate is ~10 %, not the nominal 1 % (``tests/checks/test_misalignment.py``).
A lateral offset of the apex (5 mm) is not seen,
and errors shared by the points of a wall (approximate points read off a rough plan) make
the same structure: the message names both causes.
"""

from __future__ import annotations

import numpy as np

__all__ = ["harmonic_statistic", "N_PERMUTATIONS", "MIN_POINTS"]

#: permutations of the p-value (resolution 1 / N_PERMUTATIONS)
N_PERMUTATIONS = 1000
#: fewest checked points for the statistic to be computed
MIN_POINTS = 20


def _explained(y, X):
    b, *_ = np.linalg.lstsq(X, y, rcond=None)
    return float(np.sum((X @ b) ** 2) / np.sum(y * y))


def harmonic_statistic(result, check, *, rng=0):
    """The second-harmonic statistic of a predictive check (see the module docstring).

    Parameters
    ----------
    result : CalibrationResult or Posterior
        Its ``model`` chooses the message (a misaligned fit has the tilt free already);
        the statistic itself reads the check.
    check : dict
        :func:`~bayescal.checks.model.predictive_check` output (``point_chi2``,
        ``point_rows``, ``azimuth``).
    rng : int or numpy.random.Generator, optional
        For the permutations (default 0: the same p-value every call).

    Returns
    -------
    dict or None
        ``name`` (``"ring_harmonic"``), ``p_value``, ``observed`` (the fraction explained),
        ``expected`` (its mean under permutation), ``message``; None with fewer than
        ``MIN_POINTS`` checked points.
    """
    fitted_pose = getattr(result, "model", "aligned") == "misaligned"
    used = np.asarray(check["point_rows"]) > 0
    if used.sum() < MIN_POINTS:
        return None
    az = np.asarray(check["azimuth"], float)[used]
    y = np.asarray(check["point_chi2"], float)[used]
    y = y - y.mean()
    X = np.column_stack([np.cos(2 * az), np.sin(2 * az)])
    observed = _explained(y, X)
    gen = np.random.default_rng(rng)
    perm = np.array([_explained(gen.permutation(y), X) for _ in range(N_PERMUTATIONS)])
    p = float((1 + np.sum(perm >= observed)) / (1 + N_PERMUTATIONS))
    return {"name": "ring_harmonic", "p_value": p, "observed": observed,
            "expected": float(perm.mean()),
            "message": (f"the misfit varies around the ring as cos 2 azimuth (it explains "
                        f"{observed:.0%} of the per-point misfit, {perm.mean():.0%} by "
                        f"chance; p = {p:.2g}): " + (_AFTER_POSE if fitted_pose
                                                     else _ALIGNED_HINT))}


#: what the signature means in an aligned fit, and what to do
_ALIGNED_HINT = ("the signature of a laser cone tilted against the camera axis, which the "
                 "aligned model hides in u0, v0 and their sds (docs/model.md): fit with "
                 "model=\"misaligned\" (command line: --model misaligned, or auto) and "
                 "compare the two with bc.compare_models; or of errors shared by a wall's "
                 "points (give a floor plan)")
#: ... and in a fit that has the pose free already
_AFTER_POSE = ("with the cone's tilt already fitted, errors shared by a wall's points (give "
               "a floor plan) or a mirror or lens the model does not describe")
