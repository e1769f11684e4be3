"""The report of a camera calibration from board views: Markdown and self-contained HTML.

:func:`write_camera_report` reads a :class:`~bayescal.CameraResult` (and, if run, the
cross-validation between halves of the views) and writes ``camera_report.md`` and
``camera_report.html``: the intrinsics with their standard errors, the noise model,
intrinsics the views do not determine (sd at least the value) flagged, one row per view
(corners, rms, inferred noise, neighbour correlation; a view whose rms is over 3x the
median is flagged), the cross-validation chi-square, and the
figures it is given.
"""

from __future__ import annotations

import numpy as np

from .document import Document, write_document

__all__ = ["camera_document", "write_camera_report", "REPORT_STEM"]

#: file stem of the report (``camera_report.md``, ``camera_report.html``)
REPORT_STEM = "camera_report"


def _intrinsics_rows(result):
    sd, bad = result.std(), result.unidentified()
    rows = [[n, f"{v:.6g}", f"{sd[n]:.3g}", "-" if n == "xi" else "px",
             "**no** (sd >= value)" if n in bad else "yes"]
            for n, v in result.intrinsics.items()]
    return rows, [n in bad for n in result.intrinsics]


def _view_rows(result):
    mc = result.model_check()
    rows = [[v["name"], str(v["n"]), f"{v['rms']:.3f}", f"{v['sigma']:.3f}",
             f"{v['lag1']:+.2f}"] for v in mc["views"]]
    flags = [v["name"] in mc["suspect"] for v in mc["views"]]
    return mc, rows, flags


def _crossval(doc, cv):
    doc.heading("Cross-validation")
    chi2 = np.asarray(cv["chi2"], float)
    doc.paragraph(
        "The views split into two disjoint halves, each half calibrated alone; both project "
        "the same directions (image radii 150-300 px about the centre) and their difference "
        "is compared with its predicted covariance (the sum of the two). With honest "
        f"covariances the chi-square per direction is 2 on average. Here: mean "
        f"**{chi2.mean():.2f}** over {len(chi2)} split(s) (range {chi2.min():.2f}-"
        f"{chi2.max():.2f}); mean shift between the halves "
        f"{np.mean(cv['mean_shift']):.2f} px.")
    rows = [[" ".join(map(str, a)) + " / " + " ".join(map(str, b)), f"{c:.2f}", f"{s:.2f}"]
            for (a, b), c, s in zip(cv["splits"], chi2, cv["mean_shift"], strict=True)]
    doc.table(["views (half A / half B)", "chi-square per direction", "mean shift (px)"], rows)


def camera_document(result, *, crossval=None, figures=(), title=None, inputs=()):
    """The report as a :class:`~bayescal.report.document.Document`.

    Parameters
    ----------
    result : CameraResult
    crossval : dict, optional
        :func:`~bayescal.validation.camera_cv.halves_chi2`'s output (``chi2``,
        ``mean_shift``, ``splits``).
    figures : sequence of (str, pathlib.Path)
        Caption and PNG file (beside the report) of each figure.
    title : str, optional
    inputs : sequence of str
        Where the views came from (file names), listed in the report.
    """
    doc = Document(title or "Camera calibration")
    size = "unknown" if result.image_size is None else "x".join(map(str, result.image_size))
    doc.paragraph(f"{len(result.view_names)} views, every one used; image {size} px; "
                  f"method {result.method}; noise model `{result.noise}`"
                  + (f"; inputs: {', '.join(inputs)}" if inputs else "") + ".")
    doc.heading("Intrinsics (eq. (1))")
    rows, bad = _intrinsics_rows(result)
    if any(bad):
        doc.warning(f"The views do not determine {', '.join(result.unidentified())} (an sd at "
                    "least the value): check the board size (all its inner corners) and the "
                    "square, and use views spread over the image.")
    doc.table(["name", "value", "sd", "unit", "identified"], rows, flags=bad)
    if result.noise == "view-systematic":
        doc.paragraph(f"Per-view systematic field: rms {result.tau:.3f} px.")
    doc.heading("Views")
    mc, rows, flags = _view_rows(result)
    doc.paragraph(f"Residual rms {mc['rms']:.3f} px per coordinate; equal noise in every view "
                  f"p = {mc['bartlett_p']:.2g} (Bartlett). lag-1: correlation of "
                  "neighbouring corners' residuals along the board's rows.")
    if mc["suspect"]:
        doc.warning(f"View(s) {', '.join(mc['suspect'])}: rms over 3x the median; check the "
                    "corner detection in those images.")
    doc.table(["view", "corners", "rms (px)", "noise sd (px)", "lag-1"], rows, flags=flags)
    if crossval is not None:
        _crossval(doc, crossval)
    for caption, path in figures:
        doc.figure(caption, path)
    doc.heading("Summary")
    doc.preformatted(result.summary())
    return doc


def write_camera_report(folder, result, *, crossval=None, figures=(), title=None, inputs=()):
    """Write ``camera_report.md`` and ``camera_report.html`` into ``folder``.

    Parameters are those of :func:`camera_document`. Returns both paths.
    """
    doc = camera_document(result, crossval=crossval, figures=figures, title=title,
                          inputs=inputs)
    return write_document(doc, folder, REPORT_STEM)
