"""Checks on a finished fit: an inferred noise level that collapsed onto its bound.

:func:`check_noise_levels` refuses an inferred noise level that ended at its
prior bound (:class:`NoiseCollapseError`, naming the rows that drive it). See
``docs/robustness.md``.
"""

from __future__ import annotations

import numpy as np

from .rows import rows_text as _rows_text

__all__ = ["NoiseCollapseError", "check_noise_levels"]


class NoiseCollapseError(ValueError):
    """An inferred noise level ended at its prior bound.

    Attributes
    ----------
    name : str
        ``"sigma_px"`` or ``"kappa"``.
    value : float
    rows : ndarray of int
        Input rows (0-based) whose data pull the level towards the bound most.
    """

    def __init__(self, message, *, name, value, rows):
        super().__init__(message)
        self.name, self.value, self.rows = name, value, np.asarray(rows, dtype=int)


def check_noise_levels(lik, psi, q, *, factor=2.0, n_rows=5):
    """Refuse inferred noise levels that ended within ``factor`` of their prior bounds.

    Parameters
    ----------
    lik : bayescal.likelihood.points.LaserLikelihood
    psi : ndarray, shape (7 + n_extra,)
        Parameters and extra globals at the fit (``log sigma_px``, ``log kappa``...).
    q : ndarray, shape (N, 2)
        Scene coordinates at the fit.
    factor : float
        A level within this factor of a bound counts as at the bound.
    n_rows : int
        How many driving rows to name.

    Raises
    ------
    NoiseCollapseError
        Naming the level, its value, the bound and the rows whose collapsed
        likelihood gains most by moving the level further towards the bound.
    """
    from ..likelihood.points import NOISE_BOUNDS

    psi = np.asarray(psi, dtype=float)
    for k, name in enumerate(lik.extra_names):
        if name not in NOISE_BOUNDS:
            continue
        lo, hi = NOISE_BOUNDS[name]
        v = float(np.exp(psi[7 + k]))
        if lo * factor < v < hi / factor:
            continue
        toward = -1.0 if v <= lo * factor else 1.0
        step = np.zeros_like(psi)
        step[7 + k] = 0.1 * toward
        gain = (lik._laplace_points(psi + step, q, 2)[0]
                - lik._laplace_points(psi, q, 2)[0])
        gain = np.where(np.isfinite(gain), gain, -np.inf)
        rows = np.argsort(-gain)[:n_rows]
        what = "pixel noise sigma_px" if name == "sigma_px" else "scene noise kappa"
        side = "lower" if toward < 0 else "upper"
        raise NoiseCollapseError(
            f"the inferred {what} ended at {v:.3g}, at its {side} bound ({lo:g}-{hi:g}): "
            f"the data cannot determine it (e.g. the other noise level leaves no degrees of "
            f"freedom, or a few rows dominate). Rows driving it most (0-based): "
            f"{_rows_text(rows)}. Check those rows, or give {name} explicitly",
            name=name, value=v, rows=rows)
