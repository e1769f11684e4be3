"""Reports a person can open: a JSON summary, PNG plots, Markdown and self-contained HTML.

The report is built from plain data (a summary dict as stored in
``summary.json``, the laser pixels, the estimated points and their 3x3
covariances, optionally a :class:`~bayescal.Posterior` and the truth of a
simulation), so that ``bayescal report`` can rebuild it from a finished run.

Contents: the parameter table (mean or estimate, sd, 90 % interval and the
"prior-dominated" flag: the data do not determine the parameter, its prior
does), convergence diagnostics, the corner plot (posterior only), pixel
residuals in the image, and the reconstruction (top view) with 95 %
uncertainty ellipses.
"""

from __future__ import annotations

import base64
import html
import pathlib

import numpy as np

from .camera import project
from .laser import triangulate_theta
from .parameters import IDENTIFIABLE_NAMES, PARAM_NAMES, SensorParams
from .posterior import PRIOR_DOMINATED_RATIO

__all__ = [
    "result_summary",
    "posterior_summary",
    "linear_reconstruction",
    "plot_pixel_residuals",
    "plot_reconstruction_ellipses",
    "write_report",
]

_Z90 = 1.6448536269514722          # normal 95th percentile: 90 % central interval
_CHI2_2_95 = 5.991464547107979      # chi-square(2) 95 % quantile: 2-D 95 % ellipse


def _non_identifiable(report):
    names = set()
    for nd in getattr(report, "null_directions", []) or []:
        names.update(nd.get("components", {}))
    return [n for n in PARAM_NAMES if n in names]


def result_summary(result, *, prior=None):
    """JSON-ready summary of a :class:`~bayescal.CalibrationResult`.

    Parameters
    ----------
    result : CalibrationResult
    prior : dict, optional
        ``{name: frozen distribution}`` the calibration used (the eight
        names, e.g. from :func:`~bayescal.priors.default_prior`); adds
        ``prior_sd`` and ``sd_ratio`` (sd / prior sd) to each row.

    Returns
    -------
    dict
        ``method``, ``converged``, ``message``, ``params`` and ``sd`` (dicts by
        name), ``covariance`` (8x8), ``covariance_identifiable`` (7x7),
        residual statistics, ``identifiability`` (text) and ``rows``: one
        dict per parameter with ``name, mean, sd, q05, q95, prior_dominated``
        (normal 90 % interval). ``prior_dominated`` marks parameters in a
        near-null direction of the data (set by the prior or held fixed)
        and, with ``prior``, those whose sd exceeds the posterior module's
        ``PRIOR_DOMINATED_RATIO`` times the prior sd (the rule of
        :meth:`Posterior.summary`).
    """
    values = result.params.to_array()
    sd = result.std
    flagged = _non_identifiable(result.identifiability)
    ratio_limit = PRIOR_DOMINATED_RATIO
    rows = []
    for name, v, s in zip(PARAM_NAMES, values, sd, strict=True):
        row = {"name": name, "mean": v, "sd": s, "q05": v - _Z90 * s, "q95": v + _Z90 * s,
               "prior_dominated": name in flagged}
        if prior is not None and name in prior:
            psd = float(prior[name].std())
            row["prior_sd"] = psd
            row["sd_ratio"] = s / psd if psd > 0 else float("nan")
            row["prior_dominated"] = bool(row["prior_dominated"] or row["sd_ratio"] > ratio_limit)
        rows.append(row)
    return {
        "method": result.method,
        "converged": bool(result.converged),
        "message": str(result.message),
        "nfev": int(result.nfev),
        "params": result.params.as_dict(),
        "sd": dict(zip(PARAM_NAMES, sd, strict=True)),
        "covariance": result.covariance,
        "covariance_identifiable": result.covariance_identifiable,
        "residual_rms": dict(result.residual_rms),
        "sigma_px_estimated": result.sigma_px_estimated,
        "n_residuals": int(result.n_residuals),
        "n_unknowns": int(result.n_unknowns),
        "identifiability": str(result.identifiability),
        "rows": rows,
    }


def posterior_summary(posterior):
    """JSON-ready summary of a :class:`~bayescal.Posterior`.

    Returns
    -------
    dict
        ``method = "bayes"``, ``converged``, ``rows`` (:meth:`Posterior.summary`),
        ``params`` (posterior means), ``sd``, ``covariance`` (8x8),
        ``covariance_identifiable`` (7x7), ``laplace_covariance`` (8x8),
        ``tau``, ``n_samples``, ``text`` (:meth:`Posterior.summary_text`),
        ``laplace_comparison`` (when the posterior provides it).
    """
    rows = posterior.summary()
    cov = posterior.covariance()
    return {
        "method": "bayes",
        "converged": bool(posterior.converged),
        "params": posterior.params_mean.as_dict(),
        "sd": dict(zip(PARAM_NAMES, np.sqrt(np.diag(cov)), strict=True)),
        "covariance": cov,
        "covariance_identifiable": posterior.covariance(identifiable=True),
        "laplace_covariance": posterior.laplace_covariance(),
        "tau": np.asarray(posterior.tau),
        "n_samples": int(np.shape(posterior.param_samples)[0]),
        "text": posterior.summary_text(),
        "rows": rows,
        "laplace_comparison": posterior.laplace_comparison(),
    }


def linear_reconstruction(params, cov_identifiable, pixels, sigma_px):
    """Triangulate pixels and propagate parameter and pixel uncertainty to first order.

    ``cov = J_theta C_theta J_theta^T + sigma_px^2 J_px J_px^T`` with the
    analytic Jacobians of :func:`~bayescal.laser.triangulate_theta`.

    Parameters
    ----------
    params : SensorParams
    cov_identifiable : ndarray, shape (7, 7)
        Covariance of ``(xi, gamma_u, gamma_v, u0, v0, h, beta)``; NaN entries
        (not estimated) are treated as 0.
    pixels : ndarray, shape (M, 2)
        px.
    sigma_px : float
        Pixel noise of the new pixels, px (0 for the parameter part only).

    Returns
    -------
    mean : ndarray, shape (M, 3)
        Triangulated points, mm (NaN where the ray misses the cone).
    cov : ndarray, shape (M, 3, 3)
        mm^2.
    """
    theta = params.to_identifiable()
    pts, _, dpix, dth = triangulate_theta(theta, np.asarray(pixels, float), jacobian=True)
    C = np.nan_to_num(np.asarray(cov_identifiable, float))
    cov = dth @ C @ np.swapaxes(dth, -1, -2) + sigma_px**2 * dpix @ np.swapaxes(dpix, -1, -2)
    return pts, cov


# -- figures ----------------------------------------------------------------

def plot_pixel_residuals(pixels, predicted, *, sigma_px=None):
    """Residuals ``pixels - predicted`` in the image and their distribution.

    Left: :func:`~bayescal.plotting.plot_residuals` with the arrows magnified so
    that the largest is 15 % of the ring's radius; right: histogram of the
    residuals (divided by ``sigma_px`` when given, with N(0, 1) drawn; the
    residuals of a fit are smaller than the noise by about
    ``sqrt(1 - n_unknowns / n_residuals)``).

    Parameters
    ----------
    pixels, predicted : ndarray, shape (N, 2)
        Observed and model pixels, px.
    sigma_px : float, optional

    Returns
    -------
    matplotlib.figure.Figure
    """
    import matplotlib.pyplot as plt

    from .plotting import plot_residuals

    res = pixels - predicted
    fig, (a1, a2) = plt.subplots(1, 2, figsize=(11, 4.5))
    norm = np.nanmax(np.hypot(res[:, 0], res[:, 1]))
    spread = max(np.nanmax(np.abs(pixels - np.nanmean(pixels, axis=0))), 1.0)
    plot_residuals(pixels, predicted, scale=0.15 * spread / norm if norm > 0 else 1.0, ax=a1)
    flat = res[np.isfinite(res).all(axis=1)].ravel()
    if sigma_px:
        flat = flat / sigma_px
        a2.set_xlabel("residual / sigma_px")
        x = np.linspace(-4, 4, 200)
        a2.plot(x, np.exp(-x**2 / 2) / np.sqrt(2 * np.pi), "k-", label="N(0, 1)")
    else:
        a2.set_xlabel("residual (px)")
    a2.hist(flat, bins=30, density=True, color="tab:red", alpha=0.6, label="u and v residuals")
    a2.legend(fontsize="small")
    a2.set_title(f"largest residual {norm:.3g} px")
    fig.tight_layout()
    return fig


def plot_reconstruction_ellipses(points, cov, *, approx_points=None, truth=None, walls=None):
    """Top view with 95 % uncertainty ellipses, and the sd of every point by azimuth.

    Left: :func:`~bayescal.plotting.plot_reconstruction` with ellipses holding
    95 % in 2-D (``n_sigma = sqrt(chi2_2(0.95)) = 2.45``), approximate points in
    grey; right: per-point sd of x, y, z (and the error when ``truth`` is given).

    Parameters
    ----------
    points : ndarray, shape (N, 3)
        mm, frame C.
    cov : ndarray, shape (N, 3, 3)
        mm^2.
    approx_points, truth : ndarray, shape (N, 3), optional
    walls : ndarray, shape (W, 2, 2), optional

    Returns
    -------
    matplotlib.figure.Figure
    """
    import matplotlib.pyplot as plt

    from .plotting import plot_reconstruction

    fig, (a1, a2) = plt.subplots(1, 2, figsize=(12, 5.5))
    if approx_points is not None:
        a1.scatter(approx_points[:, 0], approx_points[:, 1], s=3, c="0.65",
                   label="approximate points")
    ok = np.isfinite(points).all(axis=1) & np.isfinite(cov).all(axis=(1, 2))
    plot_reconstruction(points[ok], cov[ok], truth=None if truth is None else truth[ok],
                        walls=walls, n_sigma=np.sqrt(_CHI2_2_95), ax=a1)
    a1.set_title("top view, 95 % ellipses in (x, y)")
    az = np.degrees(np.arctan2(points[:, 1], points[:, 0]))
    sd = np.sqrt(np.maximum(np.diagonal(cov, axis1=1, axis2=2), 0))
    for j, name in enumerate("xyz"):
        a2.plot(az[ok], sd[ok, j], ".", ms=3, label=f"sd {name}")
    if truth is not None:
        err = np.linalg.norm(points - truth, axis=1)
        a2.plot(az[ok], err[ok], "k.", ms=2, label="|estimate - truth|")
    a2.set_yscale("log")
    a2.set_xlabel("azimuth (deg)")
    a2.set_ylabel("mm")
    a2.set_title("per-point uncertainty")
    a2.legend(fontsize="small")
    fig.tight_layout()
    return fig


def _plot_corner(posterior, truth_params):
    from . import plotting

    if hasattr(plotting, "plot_corner"):
        truth = None if truth_params is None else SensorParams(**truth_params)
        return plotting.plot_corner(posterior, truth=truth)
    import corner

    truths = None if truth_params is None else [truth_params[n] for n in PARAM_NAMES]
    return corner.corner(np.asarray(posterior.param_samples), labels=list(PARAM_NAMES),
                         truths=truths, show_titles=True, title_fmt=".3g")


def _figures(out, summary, *, pixels, points, recon, approx_points, posterior, truth,
             image_size, walls):
    from .plotting import plot_image, savefig

    params = SensorParams(**summary["params"])
    figs = {}
    figs["image"] = savefig(plot_image(pixels, params=params, image_size=image_size),
                            out / "image.png")
    sigma_px = summary.get("sigma_px") or summary.get("sigma_px_estimated")
    if points is not None and summary["method"] != "sequential":
        pred = project(params, points)
        figs["residuals"] = savefig(plot_pixel_residuals(pixels, pred, sigma_px=sigma_px),
                                    out / "residuals.png")
    if recon is not None:
        tp = None if truth is None else np.asarray(truth.get("points"), float)
        figs["reconstruction"] = savefig(
            plot_reconstruction_ellipses(*recon, approx_points=approx_points,
                                         truth=tp, walls=walls), out / "reconstruction.png")
    if posterior is not None:
        tpar = None if truth is None else truth.get("params")
        figs["corner"] = savefig(_plot_corner(posterior, tpar), out / "corner.png")
    return figs


# -- text ------------------------------------------------------------------

def _num(v, fmt=".5g"):
    try:
        v = float(v)
    except (TypeError, ValueError):
        return str(v)
    return "nan" if not np.isfinite(v) else format(v, fmt)


def _table(summary, truth):
    cols = ["name", "mean", "sd", "q05", "q95"]
    rows0 = summary["rows"]
    extra = [c for c in ("tau", "ess", "sd_ratio") if c in rows0[0]]
    cols += extra + ["prior_dominated"]
    head = ["parameter", "estimate/mean", "sd", "5 %", "95 %"] + extra + ["prior-dominated"]
    if truth is not None:
        head.append("truth")
    body, flags = [], []
    for r in rows0:
        flags.append(bool(r.get("prior_dominated")))
        cells = [r["name"]] + [_num(r.get(c)) for c in cols[1:-1]]
        cells.append("**yes**" if r.get("prior_dominated") else "no")
        if truth is not None:
            cells.append(_num(truth["params"][r["name"]]))
        body.append(cells)
    return head, body, flags


def _accuracy(summary, points, truth):
    if truth is None or points is None or truth.get("points") is None:
        return None
    tp = np.asarray(truth["points"], float)
    if tp.shape != points.shape:
        return None
    from .metrics import reconstruction_errors

    err = reconstruction_errors(points, tp)
    return {"mean_error_mm": float(np.nanmean(err)), "median_error_mm": float(np.nanmedian(err)),
            "max_error_mm": float(np.nanmax(err))}


def _lines_intro(summary):
    m = summary["method"]
    status = "converged" if summary.get("converged") else "**NOT CONVERGED**"
    out = [f"Method: **{m}**; status: {status}."]
    if summary.get("message"):
        out.append(f"Solver message: {summary['message']}.")
    if summary.get("inputs"):
        out.append("Inputs: " + ", ".join(f"`{v}`" for v in summary["inputs"].values() if v) + ".")
    if summary.get("sigma_px") is not None:
        out.append(f"Pixel noise used: {_num(summary['sigma_px'])} px.")
    if summary.get("sigma_px_estimated") is not None:
        out.append(f"Pixel noise estimated from the residuals: "
                   f"{_num(summary['sigma_px_estimated'])} px.")
    if summary.get("sigma_scene"):
        out.append(f"Scene uncertainty: {summary['sigma_scene']}.")
    return out


def _note():
    return ("*Prior-dominated*: the data do not determine the parameter, its prior does (or "
            "it was held fixed). Either its sd exceeds "
            f"{PRIOR_DOMINATED_RATIO:g} x its prior sd (column sd_ratio, when a prior was used), "
            "or "
            "it lies on the exact phi/alpha ridge: phi, alpha_u and alpha_v enter the model "
            "only through gamma_u = alpha_u (xi + phi) and gamma_v = alpha_v (xi + phi). The "
            "seven identifiable combinations are " + ", ".join(IDENTIFIABLE_NAMES) + ".")


def _markdown(summary, head, body, figs, acc, title):
    md = [f"# {title}", ""] + _lines_intro(summary) + [""]
    md += ["## Parameters", "", "| " + " | ".join(head) + " |",
           "|" + "---|" * len(head)]
    md += ["| " + " | ".join(c) + " |" for c in body]
    md += ["", _note(), ""]
    if acc:
        md += ["## Accuracy against the simulation truth", "",
               f"Mean 3D error {acc['mean_error_mm']:.1f} mm, median "
               f"{acc['median_error_mm']:.1f} mm, max {acc['max_error_mm']:.1f} mm.", ""]
    diag = summary.get("text") or summary.get("identifiability")
    if diag:
        md += ["## Diagnostics", "", "```", str(diag), "```", ""]
    caps = {"corner": "Posterior of the eight parameters (corner plot)",
            "residuals": "Pixel residuals in the image",
            "reconstruction": "Reconstruction with 95 % uncertainty ellipses",
            "image": "Laser pixels in the image"}
    md += ["## Figures", ""]
    for k in ("corner", "residuals", "reconstruction", "image"):
        if k in figs:
            md += [f"### {caps[k]}", "", f"![{caps[k]}]({figs[k].name})", ""]
    return "\n".join(md)


def _md_inline_to_html(text):
    text = html.escape(text)
    parts = text.split("**")
    text = "".join(f"<b>{p}</b>" if i % 2 else p for i, p in enumerate(parts))
    parts = text.split("`")
    return "".join(f"<code>{p}</code>" if i % 2 else p for i, p in enumerate(parts))


def _html(summary, head, body, flags, figs, acc, title):
    h = ["<!DOCTYPE html>", "<html><head><meta charset='utf-8'>",
         f"<title>{html.escape(title)}</title>",
         "<style>body{font-family:sans-serif;max-width:1100px;margin:auto;padding:1em}"
         "table{border-collapse:collapse}td,th{border:1px solid #bbb;padding:3px 8px;"
         "text-align:right}td:first-child{text-align:left}tr.flag{background:#fff3cd}"
         "img{max-width:100%}pre{background:#f4f4f4;padding:.5em}</style></head><body>",
         f"<h1>{html.escape(title)}</h1>"]
    h += [f"<p>{_md_inline_to_html(line)}</p>" for line in _lines_intro(summary)]
    h += ["<h2>Parameters</h2><table><tr>"
          + "".join(f"<th>{html.escape(c)}</th>" for c in head) + "</tr>"]
    for cells, flag in zip(body, flags, strict=True):
        cls = " class='flag'" if flag else ""
        h.append(f"<tr{cls}>" + "".join(f"<td>{_md_inline_to_html(c)}</td>" for c in cells)
                 + "</tr>")
    h += ["</table>", f"<p>{_md_inline_to_html(_note())}</p>"]
    if acc:
        h.append(f"<h2>Accuracy against the simulation truth</h2><p>Mean 3D error "
                 f"{acc['mean_error_mm']:.1f} mm, median {acc['median_error_mm']:.1f} mm, "
                 f"max {acc['max_error_mm']:.1f} mm.</p>")
    diag = summary.get("text") or summary.get("identifiability")
    if diag:
        h.append(f"<h2>Diagnostics</h2><pre>{html.escape(str(diag))}</pre>")
    h.append("<h2>Figures</h2>")
    for k in ("corner", "residuals", "reconstruction", "image"):
        if k in figs:
            data = base64.b64encode(figs[k].read_bytes()).decode("ascii")
            h.append(f"<h3>{html.escape(k)}</h3><img alt='{k}' src='data:image/png;base64,"
                     f"{data}'>")
    h.append("</body></html>")
    return "\n".join(h)


def write_report(out, summary, *, pixels, points=None, recon=None, approx_points=None,
                 posterior=None, truth=None, walls=None, image_size=(800, 600), title=None):
    """Write figures, ``report.md`` and a self-contained ``report.html`` into ``out``.

    Parameters
    ----------
    out : str or pathlib.Path
        Existing folder.
    summary : dict
        From :func:`result_summary` or :func:`posterior_summary` (may carry
        ``inputs``, ``sigma_px``, ``sigma_scene`` for the introduction).
    pixels : ndarray, shape (N, 2)
        Laser pixels, px.
    points : ndarray, shape (N, 3), optional
        Estimated points, mm, whose projections give the pixel residuals.
    recon : (ndarray (N, 3), ndarray (N, 3, 3)), optional
        Reconstructed points (mm) and their covariances (mm^2): the ellipse
        plot and, with ``truth``, the mean 3D error. Default: no ellipse plot,
        error of ``points``.
    approx_points : ndarray, shape (N, 3), optional
    posterior : Posterior, optional
        Adds the corner plot.
    truth : dict, optional
        ``{"params": {name: value}, "points": (N, 3)}`` of a simulation.
    walls : ndarray, shape (W, 2, 2), optional
    image_size : (int, int)
    title : str, optional

    Returns
    -------
    dict of str to pathlib.Path
        Every file written (figures, ``markdown``, ``html``).
    """
    out = pathlib.Path(out)
    title = title or f"bayescal calibration report ({summary['method']})"
    figs = _figures(out, summary, pixels=pixels, points=points, recon=recon,
                    approx_points=approx_points, posterior=posterior, truth=truth,
                    image_size=image_size, walls=walls)
    head, body, flags = _table(summary, truth)
    acc = _accuracy(summary, recon[0] if recon is not None else points, truth)
    if acc:
        summary["accuracy"] = acc
    md = out / "report.md"
    md.write_text(_markdown(summary, head, body, figs, acc, title), encoding="utf-8")
    ht = out / "report.html"
    ht.write_text(_html(summary, head, body, flags, figs, acc, title), encoding="utf-8")
    return {**figs, "markdown": md, "html": ht}
