"""Which laser model do the data prefer? :func:`compare_models` ranks fits of the same data.

The criterion is the Laplace estimate of each fit's log evidence
(``result.extras["log_evidence"]``, computed by the least squares; a posterior uses its
MAP's): the collapsed log likelihood (every laser point integrated out) and the log prior
at the MAP, plus the Gaussian volume ``(d/2) log 2 pi + log det(cov)/2`` of its d
geometric unknowns (with a floor plan, the walls' too: they are integrated like the
sensor). The misaligned model's four extra unknowns cost it an Occam factor
of roughly ``log(prior sd / posterior sd)`` each (about 6 nats on an aligned sensor in a
2500 mm room); a tilt that moves the pixels pays that back many times over. Plain
leave-one-out does not apply here (each laser point has its own latent position, so a
left-out point carries no information about the others); the evidence needs no
refitting. Why this criterion and how it behaves: ``docs/model.md``, "Which model".
"""

from __future__ import annotations

import dataclasses

import numpy as np

from ..errors import InvalidValueError

__all__ = ["compare_models", "ModelComparison", "DECISIVE"]

#: a difference of log evidence above this (nats, a Bayes factor of ~20) is decisive
DECISIVE = 3.0


@dataclasses.dataclass
class ModelComparison:
    """The ranking of :func:`compare_models`.

    Attributes
    ----------
    rows : list of dict
        One per result, in the order given: ``model`` (``"aligned"`` or
        ``"misaligned"``), ``method``, ``log_evidence`` (nats), ``delta`` (nats below
        the best, 0 for the best) and ``weight`` (posterior model probability under
        equal prior odds).
    preferred : int
        Index of the preferred result (largest log evidence).
    results : list
        The results compared.
    decisive : bool
        The best beats the runner-up by more than :data:`DECISIVE` nats.
    """

    rows: list
    preferred: int
    results: list
    decisive: bool

    @property
    def preferred_result(self):
        """The preferred result object."""
        return self.results[self.preferred]

    @property
    def preferred_model(self):
        """``"aligned"`` or ``"misaligned"``: the preferred result's laser model."""
        return self.rows[self.preferred]["model"]

    def __str__(self):
        lines = [f"{'':2s}{'model':<12s}{'method':<14s}{'log evidence':>14s}{'delta':>9s}"
                 f"{'weight':>9s}"]
        for k, r in enumerate(self.rows):
            mark = "* " if k == self.preferred else "  "
            lines.append(f"{mark}{r['model']:<12s}{r['method']:<14s}{r['log_evidence']:14.2f}"
                         f"{r['delta']:9.2f}{r['weight']:9.3f}")
        lines.append(f"preferred: {self.preferred_model}"
                     + ("" if self.decisive else f" (not decisive: within {DECISIVE:g} nats)"))
        return "\n".join(lines)


def _log_evidence(result, k):
    res = getattr(result, "map_result", None) or result      # a posterior: its MAP's
    ev = getattr(res, "extras", {}).get("log_evidence")
    if ev is None or not np.isfinite(ev):
        raise InvalidValueError(
            f"results[{k}] has no log evidence (a {getattr(res, 'method', '?')} "
            "result or a file saved before it existed); compare simultaneous "
            "fits on approximate points or a floor plan")
    return float(ev)


def compare_models(results):
    """Rank fits of the same data by their Laplace log evidence.

    Parameters
    ----------
    results : sequence of CalibrationResult or Posterior
        At least two fits of the same data (e.g. ``model="aligned"`` and
        ``model="misaligned"``), by :func:`~bayescal.calibrate_simultaneous` or
        :func:`~bayescal.sample_posterior` on approximate points.

    Returns
    -------
    ModelComparison
        ``rows`` (model, method, log evidence, delta, weight), ``preferred`` (index),
        ``preferred_model``, ``preferred_result``, ``decisive``; ``str()`` is a table.

    Raises
    ------
    ValueError
        Fewer than two results, a result without a log evidence, or results of
        different data (pixels differ).

    Examples
    --------
    >>> import numpy as np
    >>> import bayescal as bc
    >>> ds = bc.simulate_room(range_mm=2500, n_points=200, sigma_px=0.2, approx_error=0.03,
    ...                       approx_model="fig9", tilt=(np.radians(1.0), 0.0), rng=0)
    >>> fits = [bc.calibrate_simultaneous(ds.pixels, ds.approx_points, sigma_px=0.2,
    ...                                   sigma_scene=ds.sigma_scene, model=m)
    ...         for m in ("aligned", "misaligned")]
    >>> bc.compare_models(fits).preferred_model
    'misaligned'
    """
    results = list(results)
    if len(results) < 2:
        raise InvalidValueError(f"compare_models needs at least two results, got {len(results)}")
    ev = np.array([_log_evidence(r, k) for k, r in enumerate(results)])
    px = [getattr(getattr(r, "map_result", None) or r, "extras", {}).get("pixels")
          for r in results]
    if all(p is not None for p in px) and any(
            np.shape(p) != np.shape(px[0]) or not np.allclose(p, px[0]) for p in px[1:]):
        raise InvalidValueError("compare_models compares fits of the same data; the results' "
                                "pixels differ")
    best = int(np.argmax(ev))
    w = np.exp(ev - ev[best])
    w /= w.sum()
    rows = [{"model": getattr(r, "model", "aligned"),
             "method": "bayes" if hasattr(r, "param_samples") else r.method,
             "log_evidence": float(e), "delta": float(ev[best] - e), "weight": float(wk)}
            for r, e, wk in zip(results, ev, w, strict=True)]
    runner_up = np.sort(ev)[-2]
    return ModelComparison(rows=rows, preferred=best, results=results,
                           decisive=bool(ev[best] - runner_up > DECISIVE))
