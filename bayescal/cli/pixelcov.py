"""The command line's per-point pixel covariances (cov_uu, cov_uv, cov_vv columns): which
fits take them, the pixel-noise setting they make, and the floor plan's warning."""

from __future__ import annotations

import numpy as np

from ..errors import UsageError

__all__ = ["uses_pixel_cov", "pixel_cov_setting", "ring_corr_setting"]


def uses_pixel_cov(method, data, plan):
    """True when the job's fit takes the data file's per-point pixel covariances (least
    squares and posterior, approximate points or a floor plan; not the sequential method)."""
    return method in ("simultaneous", "bayes") and data is not None \
        and data.pixel_cov is not None


def pixel_cov_setting(value, data, method, plan, spx, spx_how):
    """The pixel-noise setting when the file has cov_uu, cov_uv, cov_vv columns."""
    import warnings

    if not uses_pixel_cov(method, data, plan):
        warnings.warn(f"{data.pixel_table.path}: ignoring the cov_uu, cov_uv, cov_vv columns "
                      "(used by --method simultaneous and bayes only)",
                      stacklevel=2)
        return spx, spx_how
    if plan is not None:
        _warn_loose_along(data)
    if value == "infer" and plan is not None:
        return None, "inferred: a scale on the file's per-point covariances (cov_uu, ...)"
    if value == "infer":
        raise UsageError("--sigma-px infer with the file's cov_uu, cov_uv, cov_vv columns: "
                         "inferring a scale on the covariances is not supported with "
                         "approximate points yet (it is with --walls); give --sigma-px SCALE "
                         "(1 = the covariances as they are)")
    scale = 1.0 if value is None else float(value)
    return scale, f"{scale:g} x the file's per-point covariances (cov_uu, cov_uv, cov_vv)"


def _warn_loose_along(data, limit_px=2.0):
    """Warn when --walls meets covariances looser than ``limit_px`` in some direction: most
    rows (an sd along the ring left at extract's default 5 px), or a few (points the
    extractor was unsure of, whatever ``--along-sd``)."""
    import warnings

    sd = np.sqrt(np.max(np.linalg.eigvalsh(data.pixel_cov), axis=-1))
    n_big = int(np.count_nonzero(sd > limit_px))
    if n_big == 0:
        return
    where = f"{data.pixel_table.path}: with --walls, pixel sds up to {np.max(sd):.3g} px"
    if n_big > len(sd) / 2:
        warnings.warn(f"{where} (along the ring) leave each point's azimuth to the ring's "
                      "shape; the least squares copes, the posterior may not converge "
                      "(docs/images.md): give sds along the ring of about 1 px "
                      "(bayescal extract --along-sd 1)", stacklevel=3)
    else:
        warnings.warn(f"{where} in {n_big} of {len(sd)} rows: points the extractor was unsure "
                      "of; they weigh little in the fit", stacklevel=3)


def ring_corr_setting(value, method, plan):
    """The ``--ring-corr DEG`` of a job: 0 when not given; refused unless the least squares
    runs on a floor plan (the only fit that takes it)."""
    if value is None or value == 0:
        return 0.0
    if plan is None or method != "simultaneous":
        raise UsageError("--ring-corr needs --walls and --method simultaneous (the least "
                         f"squares); got --method {method}"
                         + ("" if plan is not None else " without --walls"))
    return float(value)
