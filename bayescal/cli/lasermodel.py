"""The laser model of a calibration: ``--model aligned|misaligned|auto``, and the priors.

Job side (:mod:`bayescal.cli.jobs`): :func:`nominal_and_prior` reads ``--nominal`` and
``--prior`` (the eight parameters and the laser pose's four), :func:`model_setting`
checks ``--model`` against the method and the scene: the misaligned model is fitted
from approximate points or a floor plan (``--walls``) with ``--method simultaneous`` or
``bayes``, and by the sequential method's stage 2. ``auto`` (which compares the Laplace
evidence of least-squares fits on approximate points or a floor plan) falls back to
``aligned`` with a note on the sequential path.

Run side (:mod:`bayescal.cli.runs`): :class:`ModelChoice` records what was fitted and,
for ``auto``, fits both models by least squares and ranks them with
:func:`bayescal.compare_models` (Laplace evidence; ``docs/model.md``): the preferred model
when the difference is decisive, else the misaligned one (it contains the aligned model,
so its intervals hold either way).
"""

from __future__ import annotations

import dataclasses

from ..errors import Failure, UsageError
from ..sensor.pose import POSE_NAMES

__all__ = ["nominal_and_prior", "model_setting", "ModelChoice", "FITTED_MODELS", "camera_setting",
           "read_camera", "camera_nominal",
           "CAMERA_FILE"]

#: the models a fit can have (``auto`` picks one of them)
FITTED_MODELS = ("aligned", "misaligned")


def nominal_and_prior(given, prior_specs, *, image_size=(800, 600), data=None, plan=None,
                      with_derived=False):
    """The nominal sensor (``--nominal``, in part or whole, the rest derived) and the
    priors (``--prior``), checked.

    Parameters
    ----------
    given : dict, path or None
        ``{name: value}`` of ``--nominal`` (:func:`bayescal.cli.design.read_nominal`), or
        the ``--nominal`` file itself.
    prior_specs : list of (str, distribution) or None
        ``--prior`` values.
    image_size : (int, int)
        px; another than the paper's 800x600 derives the design values not given
        (:func:`bayescal.cli.design.design_values`).
    data, plan : LaserData, FloorPlan, optional
        What the focal scale is derived from.
    with_derived : bool, optional
        Also return ``derived``.

    Returns
    -------
    nominal : SensorParams
    prior : dict or None
        ``{name: frozen distribution}``: the defaults centred on ``nominal`` (a principal
        point at the image centre gets the sd of :func:`~bayescal.cli.design.centre_sd`)
        with the overrides (pose names included); None when the nominal is the paper's
        sensor and no ``--prior`` was given.
    derived : dict
        ``{name: how}`` of the design values derived, not given (``with_derived`` only).
    """
    from scipy import stats

    from ..likelihood.priors import default_prior
    from .design import centre_sd, design_values, read_nominal

    if not isinstance(given, dict):
        given = read_nominal(given)
    nominal, derived = design_values(given, image_size=image_size, data=data, plan=plan)
    overrides = dict(prior_specs or [])
    if not given and not derived and not overrides:
        return (nominal, None, derived) if with_derived else (nominal, None)
    prior = default_prior(nominal)
    for name in ("u0", "v0"):
        if derived.get(name) == "image centre":
            prior[name] = stats.norm(getattr(nominal, name), centre_sd(image_size))
    prior.update(overrides)
    return (nominal, prior, derived) if with_derived else (nominal, prior)


def model_setting(model, *, method, plan, prior_specs):
    """The laser model a calibration fits, checked against the method and the scene.

    Parameters
    ----------
    model : {"aligned", "misaligned", "auto"}
        ``--model``.
    method : str
        ``--method``.
    plan : FloorPlan or None
        ``--walls``.
    prior_specs : list of (str, distribution) or None
        ``--prior`` values.

    Returns
    -------
    model : {"aligned", "misaligned", "auto"}
        What the run fits (``auto`` on a path that has only the aligned model
        becomes ``aligned``).
    note : str or None
        Why ``auto`` fell back to ``aligned``.

    Raises
    ------
    UsageError
        An unknown model, or a laser-pose prior where the pose is not fitted.
    """
    from .options import LASER_MODELS

    if model not in LASER_MODELS:
        raise UsageError(f"--model {model!r}; expected one of {', '.join(LASER_MODELS)}")
    note = None
    if method == "sequential" and model == "auto":
        model, note = "aligned", ("--model auto compares least-squares fits on approximate "
                                  "points by their evidence, which the sequential method has "
                                  "not; fitted the aligned model (ask for --model misaligned)")
    pose = [name for name, _ in prior_specs or [] if name in POSE_NAMES]
    if pose and model == "aligned":
        raise UsageError(f"--prior {pose[0]}=...: a prior of the laser pose is used only when "
                         "the pose is fitted; expected --model misaligned or auto (with "
                         "--method simultaneous or bayes)")
    return model, note


@dataclasses.dataclass
class ModelChoice:
    """What a calibration run fitted: the model asked for, the one used and why.

    Attributes
    ----------
    requested : {"aligned", "misaligned", "auto"}
        The job's model (after the fallback of :func:`model_setting`).
    model : {"aligned", "misaligned"} or None
        The model fitted (None until :meth:`resolve` ran).
    note : str or None
        Why ``auto`` fell back, why one of its fits was left out, or that the evidence
        did not decide (then ``auto`` uses the misaligned model: it contains the aligned
        one, so its intervals hold whichever is true).
    comparison : ModelComparison or None
        ``auto``: :func:`bayescal.compare_models` of the two least-squares fits.
    fits : dict
        ``auto``: ``{model: CalibrationResult}`` of the converged fits.
    """

    requested: str
    model: str | None = None
    note: str | None = None
    comparison: object = None
    fits: dict = dataclasses.field(default_factory=dict)

    def resolve(self, job, least_squares):
        """Fix :attr:`model`; for ``auto`` fit both models and compare them.

        Parameters
        ----------
        job : CalibrateJob
        least_squares : callable
            ``least_squares(job) -> CalibrationResult`` (may raise ConvergenceError).
        """
        if self.requested != "auto":
            self.model = self.requested
            return self
        import bayescal as bc

        from ..checks.compare import DECISIVE
        from ..results.calibration import ConvergenceError

        failed = []
        for m in FITTED_MODELS:
            try:
                self.fits[m] = least_squares(dataclasses.replace(job, model=m))
            except ConvergenceError:
                failed.append(m)
            except (ValueError, ArithmeticError) as exc:
                raise Failure(f"--model auto: the least squares of the {m} model failed on "
                              f"these data ({exc}); nothing was written") from None
        if len(self.fits) == 2:
            c = self.comparison = bc.compare_models([self.fits[m] for m in FITTED_MODELS])
            self.model = c.preferred_model if c.decisive else "misaligned"
            if not c.decisive:
                self.note = (f"--model auto: the evidence does not decide (within {DECISIVE:g} "
                             "nats); used the misaligned model, which contains the aligned "
                             "one, so that its intervals hold either way")
            return self
        self.model = next(iter(self.fits), "aligned")
        self.note = (f"--model auto: the least squares of the {' and '.join(failed)} model "
                     f"did not converge; no comparison, used the {self.model} model")
        return self

    def record(self):
        """Plain data for ``run.json``: ``requested``, ``fitted``, ``note``, ``comparison``."""
        rec = {"requested": self.requested, "fitted": self.model, "note": self.note,
               "comparison": None}
        if self.comparison is not None:
            c = self.comparison
            rec["comparison"] = {"rows": [dict(r) for r in c.rows],
                                 "preferred": c.preferred_model, "decisive": c.decisive,
                                 "table": str(c)}
        return rec

    def text(self):
        """Lines for the run's summary: the choice, the note and the comparison table."""
        lines = []
        if self.requested == "auto" and self.comparison is not None:
            lines.append(f"laser model: auto chose {self.model} (Laplace log evidence of the "
                         "least-squares fits, nats):")
            lines.append(str(self.comparison))
        if self.note:
            lines.append(self.note)
        return "\n".join(lines)


#: the file ``bayescal calibrate-camera`` writes into its output folder
CAMERA_FILE = "camera.json"


def camera_setting(path, nominal, prior_specs):
    """The camera of ``calibrate --camera`` (its ``camera.json`` or the folder holding it).

    Its intrinsics become the nominal camera (``phi``, ``h``, ``beta`` stay those of
    ``--nominal`` or the paper's) and, with their covariance, the camera's prior; its
    image size must be that of the data and ``--image-size``.

    Parameters
    ----------
    path : pathlib.Path
        ``--camera``.
    nominal : SensorParams
        From :func:`nominal_and_prior`.
    prior_specs : list of (str, distribution) or None
        ``--prior`` values: none of ``xi, alpha_u, alpha_v, u0, v0`` (the camera gives them).

    Returns
    -------
    camera : CameraResult
    nominal : SensorParams
    prior : dict
        The default priors of ``phi``, ``h``, ``beta`` (and the pose's) centred on
        ``nominal``, with the overrides; the camera's prior replaces the other five.
    image_size : tuple of int or None

    Raises
    ------
    UsageError
        No camera file there, a file that is not a camera result, or a ``--prior`` of
        one of the five (exit 2, nothing written).
    """
    camera, size = read_camera(path)
    nominal, prior = camera_nominal(camera, path, nominal, prior_specs)
    return camera, nominal, prior, size


def read_camera(path):
    """The camera result of ``--camera`` and its image size (or None: not recorded, or only
    guessed from the extent of corners without one).

    Raises
    ------
    UsageError
        No camera file there, or a file that is not a camera result.
    """
    import pathlib

    from ..results.camera import load_camera
    from ..sensor.parameters import camera_moments

    p = pathlib.Path(path)
    p = p / CAMERA_FILE if p.is_dir() else p
    if not p.is_file():
        raise UsageError(f"--camera {path}: no camera file (expected the {CAMERA_FILE} that "
                         "'bayescal calibrate-camera' writes, or its folder)")
    try:
        camera = load_camera(p)
        camera_moments(camera)
    except (TypeError, ValueError, KeyError) as exc:
        raise UsageError(f"--camera {p}: not a usable camera calibration ({exc})") from None
    size = getattr(camera, "image_size", None)
    if camera.info.get("image_size_from") == "corners":    # a guess from the corners' extent
        size = None
    return camera, None if size is None else tuple(int(s) for s in size)


def camera_nominal(camera, path, nominal, prior_specs):
    """The nominal sensor with ``camera``'s intrinsics and the priors left to the laser
    stage (see :func:`camera_setting`)."""
    import numpy as np

    from ..likelihood.priors import default_prior
    from ..sensor.parameters import CAMERA_PARAM_NAMES, SensorParams, camera_moments

    mean, _ = camera_moments(camera)
    nominal = SensorParams.from_identifiable(np.r_[mean, nominal.h, nominal.beta], nominal.phi)
    clash = [name for name, _ in prior_specs or [] if name in CAMERA_PARAM_NAMES]
    if clash:
        raise UsageError(f"--prior {clash[0]}=...: --camera {path} gives the prior of xi, "
                         "alpha_u, alpha_v, u0 and v0; leave them out")
    prior = {n: d for n, d in default_prior(nominal).items() if n not in CAMERA_PARAM_NAMES}
    prior.update(dict(prior_specs or []))
    return nominal, prior
