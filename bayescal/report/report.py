"""The calibration report: built from a result object, rendered to Markdown and HTML.

:func:`write_report` takes a :class:`~bayescal.CalibrationResult` or a
:class:`~bayescal.Posterior` (the shared vocabulary: ``params``, ``points``,
``covariance()``, ``point_covariance()``, ``summary()``), the run record
(``run.json``, :mod:`bayescal.io.runinfo`), the laser data and optionally the truth
of a simulation. It draws the figures (:mod:`bayescal.plotting`) and builds one
:class:`~bayescal.report.document.Document`, written as ``report.md`` and a
self-contained ``report.html``.

Contents: the parameter table (estimate or mean, sd, 90 % interval, the
"prior-dominated" flag: the data do not determine the parameter, its prior
does), with the misaligned laser model the laser pose (tilt in degrees, offset in
mm) and, after ``--model auto``, the log-evidence table of both models, warnings
(noise estimate far from the noise used, unconverged runs, a failed predictive
check), the accuracy against the truth, the model check
and the input lines flagged as outliers (:mod:`bayescal.checks.model`),
diagnostics, and the figures (the plan view for a floor-plan run).
"""

from __future__ import annotations

import pathlib

import numpy as np

from ..io.paramtable import pose_rows
from ..results.calibration import linear_reconstruction
from ..sensor.parameters import IDENTIFIABLE_NAMES, SensorParams
from ..stats.identifiability import PRIOR_DOMINATED_RATIO, RIDGE_NAMES
from .document import Document, write_document

__all__ = ["write_report", "parameter_rows", "accuracy", "linear_reconstruction",
           "report_figures"]


def _is_posterior(result):
    return hasattr(result, "param_samples")


def parameter_rows(result, *, prior=None):
    """One dict per parameter (``name, mean, sd, q05, q95, prior_dominated`` and more)."""
    if _is_posterior(result):
        return result.summary_rows()
    return result.summary_rows(prior=prior, ratio_limit=PRIOR_DOMINATED_RATIO)


def accuracy(points, truth):
    """Mean, median and max 3D error (mm) of ``points`` against ``truth["points"]``, or None."""
    if truth is None or points is None or truth.get("points") is None:
        return None
    tp = np.asarray(truth["points"], float)
    if tp.shape != np.shape(points):
        return None
    from ..results.metrics import reconstruction_errors

    err = reconstruction_errors(points, tp)
    return {"mean_error_mm": float(np.nanmean(err)), "median_error_mm": float(np.nanmedian(err)),
            "max_error_mm": float(np.nanmax(err))}


def _num(v, fmt=".5g"):
    try:
        v = float(v)
    except (TypeError, ValueError):
        return str(v)
    return "nan" if not np.isfinite(v) else format(v, fmt)


def _table(rows, truth):
    extra = [c for c in ("tau", "ess", "sd_ratio") if c in rows[0]]
    head = ["parameter", "estimate/mean", "sd", "5 %", "95 %"] + extra + ["prior-dominated"]
    if truth is not None:
        head.append("truth")
    body = []
    for r in rows:
        cells = [r["name"]] + [_num(r.get(c)) for c in ["mean", "sd", "q05", "q95"] + extra]
        cells.append("**yes**" if r.get("prior_dominated") else "no")
        if truth is not None:
            cells.append(_num(truth["params"][r["name"]]))
        body.append(cells)
    return head, body, [bool(r.get("prior_dominated")) for r in rows]


def _true_pose(truth):
    """The simulation's laser pose (tilt_x, tilt_y rad, offset_x, offset_y mm), or None."""
    from ..sensor.pose import POSE_NAMES, LaserPose

    laser = None if truth is None else truth.get("laser")
    if not isinstance(laser, dict) or any(n not in laser for n in POSE_NAMES):
        return None
    return LaserPose(*(float(laser[n]) for n in POSE_NAMES))


def _pose_section(doc, result, truth):
    """The laser pose of a misaligned fit: tilt in degrees, offset in mm, 90 % intervals."""
    rows = pose_rows(result)
    if not rows:
        return
    true = _true_pose(truth)
    doc.heading("Laser pose")
    head = ["pose", "estimate/mean", "sd", "5 %", "95 %"] + (["truth"] if true else [])
    body = []
    for k, r in enumerate(rows):
        f = np.degrees(1.0) if r["unit"] == "rad" else 1.0
        unit = "deg" if r["unit"] == "rad" else r["unit"]
        cells = [f"{r['name']} ({unit})"] + [_num(f * r[c], ".4g")
                                             for c in ("mean", "sd", "q05", "q95")]
        if true:
            cells.append(_num(f * true.to_array()[k], ".4g"))
        body.append(cells)
    doc.table(head, body)
    doc.paragraph("The laser cone's tilt about x and y and the offset of its apex from the "
                  "camera axis (docs/conventions.md); the misaligned model fits them with "
                  "the sensor parameters (rad and mm in params.csv and the result file).")


def _model_section(doc, info):
    """Which laser model was fitted and, after --model auto, the log-evidence table."""
    rec = info.get("laser_model")
    if not rec:
        return
    cmp = rec.get("comparison")
    if (rec.get("requested") == "auto" and cmp) or rec.get("note"):
        doc.heading("Laser model")
    if rec.get("requested") == "auto" and cmp:
        doc.paragraph(f"`--model auto` fitted both laser models by least squares and chose "
                      f"**{rec.get('fitted')}**, the larger Laplace log evidence"
                      + ("" if cmp.get("decisive") else " (not decisive: within 3 nats)") + ".")
        doc.table(["model", "method", "log evidence (nats)", "delta", "weight"],
                  [[("**" + r["model"] + "**") if r["model"] == cmp["preferred"] else r["model"],
                    r["method"], _num(r["log_evidence"], ".2f"), _num(r["delta"], ".2f"),
                    _num(r["weight"], ".3f")] for r in cmp["rows"]])
    if rec.get("note"):
        doc.paragraph(rec["note"] + ".")


def _sigma_used(result, info):
    if _is_posterior(result):
        return None
    return info.get("sigma_px") or result.extras.get("sigma_px") or result.sigma_px_estimated


def _residual_figure(result, info, pixels):
    from ..checks.residuals import least_squares_residuals, posterior_residuals
    from ..plotting import plot_pixel_residuals

    if _is_posterior(result):
        z = posterior_residuals(result, n_draws=100)
        return plot_pixel_residuals(pixels, z, title="Pixel residuals under 100 posterior draws "
                                    "(each point through its own draw)")
    if result.method == "sequential":
        return _sequential_figure(result)
    if result.points is None:
        return None
    spx = _sigma_used(result, info)
    ssc = result.extras.get("sigma_scene")
    raw, z = least_squares_residuals(result, pixels, spx, ssc)
    if result.extras.get("walls") is not None:
        how = "across each point's track on its wall (its azimuth absorbs the other), / sd"
    elif ssc is not None:
        how = "each divided by its sd after the fit, sigma_px sqrt(1 - leverage)"
    else:
        how = f"divided by {spx:.3g} px x sqrt(1 - {result.n_unknowns}/{result.n_residuals})"
    return plot_pixel_residuals(pixels, z, raw=raw, title=f"Least-squares pixel residuals, {how}")


def _sequential_figure(result):
    """Both stages' standardized residuals, or None for a failed run or an old file."""
    from ..fit.sequential import sequential_residuals
    from ..plotting import plot_sequential_residuals

    try:
        return plot_sequential_residuals(sequential_residuals(result))
    except (TypeError, ValueError):
        return None


def _check_figures(out, result, info, *, recon, truth, check):
    """The plan view (plan runs) and the predictive-check plot: ``{key: (caption, path)}``."""
    from ..io.planfile import plan_from_record
    from ..plotting import savefig
    from ..plotting.checks import plot_predictive_check
    from ..plotting.plan import plan_figure

    figs = {}
    plan = plan_from_record(info.get("plan"))
    if plan is not None:
        figs["plan"] = ("Floor plan: the plan as given (dashed), the estimated walls with draws "
                        "of their uncertainty, the points with their ellipses",
                        savefig(plan_figure(result, plan, recon=recon, truth=truth),
                                out / "plan.png"))
    if check is not None:
        fig = plot_predictive_check(check, azimuth=check["azimuth"],
                                    outlier_prob=getattr(result, "outlier_prob", None))
        figs["predictive"] = ("Posterior predictive check: each point's sum of squared "
                              "standardized residuals against its 99.9 % model bound",
                              savefig(fig, out / "predictive.png"))
    return figs


def report_figures(out, result, info, *, data, recon, truth, check=None):
    """Draw the report's figures into ``out``; returns ``{key: (caption, path)}``."""
    from ..plotting import plot_corner, plot_image, plot_reconstruction_ellipses, savefig

    out = pathlib.Path(out)
    size = tuple(info.get("image_size") or (800, 600))
    figs = {} if data is None else {"image": ("Laser pixels in the image", savefig(
        plot_image(data.pixels, params=result.params, image_size=size), out / "image.png"))}
    fig = _residual_figure(result, info, None if data is None else data.pixels)
    if fig is not None:
        what = ("Standardized residuals of both stages"
                if getattr(result, "method", None) == "sequential"
                else "Standardized pixel residuals")
        figs["residuals"] = (what, savefig(fig, out / "residuals.png"))
    if recon is not None:
        tp = (None if truth is None or truth.get("points") is None   # a truth of params only
              else np.asarray(truth["points"], float))
        walls = None if truth is None or truth.get("walls") is None else np.asarray(
            truth["walls"], float)
        figs["reconstruction"] = ("Reconstruction with 95 % uncertainty", savefig(
            plot_reconstruction_ellipses(*recon, approx_points=data.approx_points, truth=tp,
                                         walls=walls), out / "reconstruction.png"))
    if _is_posterior(result):
        tpar = None if truth is None else SensorParams(**truth["params"])
        pose = getattr(result, "model", "aligned") == "misaligned"
        what = ("the seven identifiable parameters and the laser pose" if pose
                else "the eight parameters")
        figs["corner"] = (f"Posterior of {what} (corner plot)", savefig(
            plot_corner(result, truth=tpar, identifiable=pose, laser_truth=_true_pose(truth)),
            out / "corner.png"))
    figs.update(_check_figures(out, result, info, recon=recon, truth=truth, check=check))
    return figs


def _warnings(result, info, data):
    from ..checks.datafile import runs_lines_text
    from ..checks.fit import off_plan_text
    from ..checks.residuals import noise_warnings

    runs = (getattr(result, "extras", None) or {}).get("off_plan_runs") or ()
    where = None if data is None else (lambda rows: runs_lines_text(data, rows))
    text = off_plan_text(runs, where=where)    # a block of points off the floor plan
    off = [f"{text}."] if text else []
    if _is_posterior(result):
        out = [] if result.converged else [
            "The sampler did not converge (chains shorter than 50 autocorrelation times): the "
            "means, sds and intervals below are not reliable."]
        return out + off
    used = info.get("sigma_px") or (data.sigma_px if data is not None else None)
    return noise_warnings(result, used) + off


def _intro(doc, result, info):
    status = "converged" if result.converged else "**NOT CONVERGED**"
    doc.paragraph(f"Method: **{info.get('method', getattr(result, 'method', 'bayes'))}**; "
                  f"laser model: **{getattr(result, 'model', 'aligned')}**; status: {status}.")
    if not _is_posterior(result) and result.message:
        doc.paragraph(f"Solver message: {str(result.message).rstrip('.')}.")
    ins = [v for v in (info.get("inputs") or {}).values() if v]
    if ins:
        doc.paragraph("Inputs: " + ", ".join(f"`{v}`" for v in ins) + ".")
    if info.get("sigma_px") is not None:
        how = info.get("sigma_px_how", "given")
        doc.paragraph(f"Pixel covariance scale used: {_num(info['sigma_px'])} ({how})."
                      if "covariances" in how else
                      f"Pixel noise used: {_num(info['sigma_px'])} px ({how}).")
    if not _is_posterior(result) and result.sigma_px_estimated is not None:
        what = result.noise_label()[len("estimated "):]
        doc.paragraph(f"{what.capitalize()} estimated from the residuals: "
                      f"{result.noise_text()}.")
    if info.get("sigma_scene"):
        doc.paragraph(f"Scene uncertainty: {info['sigma_scene']}.")


def _note(result):
    """The footnote of the parameter table: the rule of
    :func:`~bayescal.stats.identifiability.prior_dominated`, and the data's near-null
    directions where a least-squares result has them."""
    text = ("*Prior-dominated*: the priors, not the data, decide the parameter (or it was "
            f"held fixed): {', '.join(RIDGE_NAMES)} always (they enter the model only through "
            "gamma_u = alpha_u (xi + phi) and gamma_v = alpha_v (xi + phi)); any other when its "
            f"sd exceeds {PRIOR_DOMINATED_RATIO:g} x its prior sd (column sd_ratio); without a "
            "prior (the sequential method), any with a weight of 0.05 or more in a near-null "
            "direction of the data. The seven identifiable combinations are "
            + ", ".join(IDENTIFIABLE_NAMES) + ".")
    ident = None if _is_posterior(result) else getattr(result, "identifiability", None)
    null = getattr(ident, "null_directions", None) or []
    if null:
        dirs = "; ".join(
            f"{k} (s = {nd['singular_value']:.3g}): "
            + ", ".join(f"{w:+.3f} {n}" for n, w in nd["components"].items())
            for k, nd in enumerate(null, 1))
        text += (f" Near-null directions of the data (singular values below {ident.rtol:g} of "
                 "the largest, in columns scaled to unit norm): combinations the data alone "
                 f"leave open, which the priors close: {dirs}. With a prior, a parameter in "
                 "one is flagged only when its sd ratio shows that the priors decide it.")
    return text


def _checks_section(doc, check, flagged):
    doc.heading("Model check and outliers")
    if flagged:
        doc.paragraph(flagged + ".")
    else:
        doc.paragraph("No input line is flagged as an outlier (outlier_prob > 0.5 in "
                      "points.csv).")
    if check is None:
        return
    left = (f" ({check['excluded']} flagged outliers left out)" if check["excluded"] else "")
    verdict = check["message"]
    if not check["fits"]:
        doc.warning(f"Posterior predictive check: {verdict}{left}. The intervals below assume "
                    "the model; check the noise levels, the scene sds and the scene model "
                    "(errors shared by a wall call for --walls).")
    else:
        doc.paragraph(f"Posterior predictive check: {verdict}{left}.")
    doc.paragraph("p-values: " + ", ".join(f"{k} {v:.3g}" for k, v in
                                          check["p_values"].items()) + ".")


def build_document(result, info, *, rows, figs, acc, truth, warnings, title, check=None,
                   flagged=None, summary=None):
    """The report as a :class:`~bayescal.report.document.Document`."""
    doc = Document(title)
    _intro(doc, result, info)
    for w in warnings:
        doc.warning(w)
    doc.heading("Parameters")
    head, body, flags = _table(rows, truth)
    doc.table(head, body, flags=flags)
    doc.paragraph(_note(result))
    _pose_section(doc, result, truth)
    _model_section(doc, info)
    if acc:
        doc.heading("Accuracy against the simulation truth")
        doc.paragraph(f"Mean 3D error {acc['mean_error_mm']:.1f} mm, median "
                      f"{acc['median_error_mm']:.1f} mm, max {acc['max_error_mm']:.1f} mm.")
        if truth.get("accuracy_note"):          # how the truth's points were made
            doc.paragraph(str(truth["accuracy_note"]))
    if info.get("method") != "sequential":
        _checks_section(doc, check, flagged)
    doc.heading("Diagnostics")
    doc.preformatted(summary or result.summary())
    doc.heading("Figures")
    for key in ("plan", "corner", "predictive", "residuals", "reconstruction", "image"):
        if key in figs:
            doc.figure(*figs[key])
    for key in sorted(k for k in figs if k.startswith("extra")):
        doc.figure(*figs[key])
    return doc


def write_report(out, result, info, *, data, recon=None, truth=None, prior=None, title=None,
                 figures=()):
    """Write the figures, ``report.md`` and a self-contained ``report.html`` into ``out``.

    Parameters
    ----------
    out : str or pathlib.Path
        Existing folder.
    result : CalibrationResult or Posterior
    info : dict
        The run record (``method``, ``inputs``, ``sigma_px``, ``sigma_scene``,
        ``image_size``), see :func:`bayescal.io.runinfo.run_record`.
    data : LaserData or None
        The laser data the result was computed from (None: a sequential run without
        laser data, whose report has the parameters and the residuals of both stages).
    recon : (ndarray (N, 3), ndarray (N, 3, 3)), optional
        Reconstructed points (mm) and covariances (mm^2) for the ellipse plot
        and the accuracy (default: the result's points, if any).
    truth : dict, optional
        ``{"params": {name: value}, "points": (N, 3), "walls": ...}`` of a simulation.
    prior : dict, optional
        The priors of a least-squares run, for the sd_ratio column.
    title : str, optional
    figures : sequence of (str, pathlib.Path), optional
        More figures (caption, PNG file in ``out``), shown after the report's own.

    Returns
    -------
    files : dict of str to pathlib.Path
        Every file written (figures, ``markdown``, ``html``).
    accuracy : dict or None
        See :func:`accuracy`.
    """
    out = pathlib.Path(out)
    title = title or f"bayescal calibration report ({info.get('method', 'bayes')})"
    from ..checks.datafile import flagged_text, located_summary
    from ..checks.model import model_check

    check = None if getattr(result, "method", None) == "sequential" or result.points is None \
        or data is None else model_check(result, pixels=data.pixels,
                                         approx_points=data.approx_points, info=info)
    figs = report_figures(out, result, info, data=data, recon=recon, truth=truth, check=check)
    figs.update({f"extra{k}": (cap, pathlib.Path(p)) for k, (cap, p) in enumerate(figures)})
    acc = accuracy(recon[0] if recon is not None else result.points, truth)
    doc = build_document(result, info, rows=parameter_rows(result, prior=prior), figs=figs,
                         acc=acc, truth=truth, warnings=_warnings(result, info, data),
                         title=title, check=check,
                         flagged=None if data is None else flagged_text(
                             data, getattr(result, "outlier_prob", None)),
                         summary=located_summary(result, data))
    md, ht = write_document(doc, out, "report")
    files = {k: p for k, (_, p) in figs.items()}
    files.update(markdown=md, html=ht)
    return files, acc
