"""The posterior's file: one ``.npz`` archive without pickles (see
:mod:`bayescal.results.posterior`): :func:`save_posterior` writes it atomically,
:func:`read_posterior` reads back the keyword arguments that rebuild the same object."""

from __future__ import annotations

import json
import os
import pathlib

import numpy as np
from scipy import stats

from ..errors import InvalidValueError, MissingFileError, OutputExistsError
from ..likelihood.priors import Prior
from ..scene.floorplan import FloorPlan
from ..stats.chains import ChainDiagnostics

__all__ = ["save_posterior", "read_posterior", "FORMAT_VERSION", "ARRAYS"]

FORMAT_VERSION = 1
#: the arrays every posterior file holds, under the attribute's name
ARRAYS = ("param_samples", "point_samples", "noise_samples", "pixels", "approx_points",
          "tau", "ess", "laplace_cov8", "laplace_cov7", "map_params", "map_points",
          "map_point_covariance")


def _prior_record(prior):
    """``{name: [scipy distribution name, args, kwds]}`` of the eight and the pose's priors;
    with a camera prior, its ``"camera": [mean, cov]`` in place of the five it replaces."""
    skip = () if prior.camera is None else ("xi", "alpha_u", "alpha_v", "u0", "v0")
    out = {name: [d.dist.name, [float(a) for a in d.args],
                  {k: float(v) for k, v in d.kwds.items()}]
           for name, d in {**prior.dists, **prior.pose_dists}.items() if name not in skip}
    if prior.camera is not None:
        out["camera"] = [prior.camera[0].tolist(), prior.camera[1].tolist()]
    return out


def _read_prior(record):
    """The prior saved by :func:`_prior_record`: a dict, or a Prior with its camera."""
    camera = record.pop("camera", None)
    dists = {n: getattr(stats, d)(*args, **kwds) for n, (d, args, kwds) in record.items()}
    if camera is None:
        return dists
    return Prior(dists, camera=(np.asarray(camera[0]), np.asarray(camera[1])))


def save_posterior(post, path, *, overwrite=False):
    """Write ``post`` to ``path`` (``.npz``), atomically; see :meth:`Posterior.save`."""
    path = pathlib.Path(path)
    if path.suffix != ".npz":
        raise InvalidValueError(f"path must end in .npz, got {str(path)!r}")
    if path.exists() and not overwrite:
        raise OutputExistsError(f"{path} exists; pass overwrite=True to replace it")
    prior = _prior_record(post.prior)
    meta = {"format": "bayescal-posterior", "version": FORMAT_VERSION,
            "noise_names": list(post.noise_names), "sigma_px": post.sigma_px,
            "prior": prior, "n_steps": post.n_steps, "burn": post.burn,
            "n_walkers": post.n_walkers, "converged": post.converged,
            "acceptance": post.acceptance, "imh_acceptance": post.imh_acceptance,
            "offset_sd": post.offset_sd,
            "diagnostics": None if post.diagnostics is None else post.diagnostics.to_dict()}
    arrays = {k: getattr(post, k) for k in ARRAYS}
    if post.sigma_scene is not None:
        arrays["sigma_scene"] = np.asarray(post.sigma_scene, float)
    for name in ("wall_samples", "outlier_prob"):        # optional arrays
        if getattr(post, name) is not None:
            arrays[name] = getattr(post, name)
    if post.plan is not None:
        arrays.update({"plan_" + k: v for k, v in post.plan.to_arrays().items()})
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_name(path.name + ".tmp")       # atomic: never a half-written file
    try:
        with open(tmp, "wb") as f:
            np.savez_compressed(f, meta_json=np.array(json.dumps(meta)), **arrays)
        os.replace(tmp, path)
    finally:
        tmp.unlink(missing_ok=True)
    return path


def read_posterior(path):
    """The keyword arguments of the ``Posterior`` saved in ``path`` (a dict); see
    :func:`bayescal.load_posterior`."""
    path = pathlib.Path(path)
    if not path.exists():
        raise MissingFileError(f"no posterior file at {path}")
    with np.load(path, allow_pickle=False) as f:
        if "meta_json" not in f:
            raise InvalidValueError(f"{path} is not a bayescal posterior file (no meta_json)")
        meta = json.loads(str(f["meta_json"]))
        if meta.get("format") != "bayescal-posterior":
            raise InvalidValueError(f"{path} is not a bayescal posterior file")
        if meta["version"] > FORMAT_VERSION:
            raise InvalidValueError(f"{path} has format version {meta['version']}; this bayescal "
                                    f"reads up to {FORMAT_VERSION}")
        arrays = {k: f[k] for k in ARRAYS}
        sigma_scene = f["sigma_scene"] if "sigma_scene" in f else None
        wall_samples = f["wall_samples"] if "wall_samples" in f else None
        outlier_prob = f["outlier_prob"] if "outlier_prob" in f else None
        plan_arrays = {k[5:]: f[k] for k in f.files if k.startswith("plan_")}
    prior = _read_prior(meta["prior"])
    return dict(
        param_samples=arrays["param_samples"], point_samples=arrays["point_samples"],
        noise_samples=arrays["noise_samples"], noise_names=meta["noise_names"],
        pixels=arrays["pixels"], approx_points=arrays["approx_points"],
        sigma_px=meta["sigma_px"], sigma_scene=sigma_scene, prior=prior, tau=arrays["tau"],
        ess=arrays["ess"], n_steps=meta["n_steps"], burn=meta["burn"],
        n_walkers=meta["n_walkers"], converged=meta["converged"],
        acceptance=meta["acceptance"], imh_acceptance=meta["imh_acceptance"],
        laplace_cov8=arrays["laplace_cov8"], laplace_cov7=arrays["laplace_cov7"],
        map_params=arrays["map_params"], map_points=arrays["map_points"],
        map_point_covariance=arrays["map_point_covariance"],
        diagnostics=None if meta.get("diagnostics") is None else
        ChainDiagnostics.from_dict(meta["diagnostics"]), wall_samples=wall_samples,
        plan=_load_plan(plan_arrays), outlier_prob=outlier_prob,
        offset_sd=meta.get("offset_sd", 0.0))



def _load_plan(arrays):
    """The FloorPlan saved with a floor-plan posterior, or None."""
    return FloorPlan.from_arrays(arrays) if arrays else None
