"""Files that a command pairs must describe the same camera and the same scene.

A laser file states its image size (``# image_size: WxH``, written by ``simulate`` and
``extract``), a camera file (``camera.json``) and a run folder (``run.json``) record theirs,
an image has its own; ``--image-size`` states one too. Pixels of one camera triangulated
with another's calibration are nonsense without an error (rays that miss the cone, a ring
that does not stand out, azimuths squeezed to one side of the principal point), so every
pairing is checked here and a disagreement is bad input (exit 2) naming both sizes and
where each came from. The same goes for a ``--truth`` file and the data it is compared
with, and for the pixel noise of plain pixels (``u, v`` only) reconstructed with a run
that weighed its pixels by covariances.
"""

from __future__ import annotations

import pathlib

import numpy as np

from ..errors import UsageError

__all__ = ["agreed_image_size", "frame_image_size", "image_frame", "truth_for", "true_points",
           "plain_pixel_noise", "say_pixel_noise", "frame_noise", "quiet_median",
           "centred_geometry", "camera_hint",
           "FRAME_IMAGE_SUFFIXES",
           "IMAGE_TRUTH_NOTE"]

#: image files ``reconstruct`` runs through the laser extractor (the formats ``extract`` and
#: ``calibrate-camera`` read, PGM included)
FRAME_IMAGE_SUFFIXES = (".png", ".tif", ".tiff", ".jpg", ".jpeg", ".pgm", ".ppm", ".pnm",
                        ".bmp")

#: how a truth's points are made for pixels extracted from a simulation's image (its report)
IMAGE_TRUTH_NOTE = (
    "Truth of extracted pixels: they are not the simulated points, so each pixel's true laser "
    "point is the renderer's true centre line (linearly interpolated) at the pixel's azimuth "
    "under the true sensor; the error is the distance from the calibrated point to it (it "
    "includes the extraction error).")


def _wxh(size):
    return f"{int(size[0])}x{int(size[1])}"


def _file_line(table):
    return f"{table.path} (image_size line)"


def agreed_image_size(option, data=None, camera=None):
    """The image size of a calibration: ``--image-size``, the data file's line and the
    camera file's size must agree wherever they are given.

    Parameters
    ----------
    option : tuple of int or None
        ``--image-size``.
    data : LaserData, optional
    camera : tuple (path, size or None), optional
        ``--camera`` and the image size its file records.

    Returns
    -------
    ((int, int), str)
        The size and where it came from (the paper's 800x600 when nothing gives one).

    Raises
    ------
    UsageError
        Two of them disagree: both sizes named, with where each came from.
    """
    from .design import image_size_setting

    given = []
    if option is not None:
        given.append((tuple(int(v) for v in option), "--image-size"))
    if data is not None and data.image_size is not None:
        given.append((tuple(data.image_size), _file_line(data.pixel_table)))
    if camera is not None and camera[1] is not None:
        given.append((tuple(camera[1]), f"--camera {camera[0]}"))
    for size, how in given[1:]:
        if size != given[0][0]:
            raise UsageError(f"{how} is {_wxh(size)} px but {given[0][1]} is "
                             f"{_wxh(given[0][0])} px; expected one camera: pixels, camera "
                             "and --image-size must all be of the same image size")
    return given[0] if given else image_size_setting(None, None)


def _run_size(run, info):
    size = info.get("image_size")
    return None if not size else (tuple(int(v) for v in size), f"the run {run} ({run}/run.json)")


def frame_image_size(option, table, run, info):
    """The image size of a pixel file given to ``reconstruct``: ``--image-size`` and the
    file's line must agree with each other and with the run's calibration.

    Returns
    -------
    (int, int)

    Raises
    ------
    UsageError
        Two of them disagree (exit 2), naming both sizes.
    """
    given = []
    if option is not None:
        given.append((tuple(int(v) for v in option), "--image-size"))
    if table.meta.get("image_size") is not None:
        given.append((tuple(table.meta["image_size"]), _file_line(table)))
    ran = _run_size(run, info)
    for size, how in given[1:]:
        if size != given[0][0]:
            raise UsageError(f"{how} is {_wxh(size)} px but {given[0][1]} is "
                             f"{_wxh(given[0][0])} px; expected one camera")
    if given and ran is not None and given[0][0] != ran[0]:
        raise UsageError(f"{given[0][1]}: pixels of a {_wxh(given[0][0])} image, but "
                         f"{ran[1]} was calibrated on {_wxh(ran[0])} images; expected pixels "
                         "of the camera the run calibrated")
    if given:
        return given[0][0]
    return ran[0] if ran is not None else agreed_image_size(None)[0]


def image_frame(path, option, run, info, center):
    """A frame of laser pixels from an image file, once its size matches the run's (and
    ``--image-size``): ``(path, pixels (N, 2) px, covariance (N, 2, 2) px^2)``."""
    import imageio.v3 as iio

    from ..image.extract import laser_frame

    try:
        shape = iio.improps(path).shape
    except Exception as exc:  # noqa: BLE001 (imageio raises several types for a bad file)
        raise UsageError(f"{path}: cannot read the image ({exc})") from None
    size = (int(shape[1]), int(shape[0]))
    ran = _run_size(run, info)
    for other, how in ((None if option is None else tuple(option), "--image-size"),
                       (None if ran is None else ran[0], None if ran is None else ran[1])):
        if other is not None and tuple(other) != size:
            raise UsageError(f"{path} is a {_wxh(size)} image but {how} is {_wxh(other)} px; "
                             "expected an image of the camera the run calibrated")
    return laser_frame(pathlib.Path(path), center=center)


def truth_for(path, data):
    """``--truth`` for ``data``: the simulation's truth as it is when its points are the data's
    (same count; data with approximate points must have them). Pixels without approximate
    points that are not the simulation's (extracted from its image): with ``ring.csv``
    beside ``truth.json`` (the image's true centre line) each pixel's true point at its
    azimuth; without it the truth of the parameters alone. Both say so.

    Returns
    -------
    dict or None
    """
    from ..checks.datafile import load_truth

    if path is None:
        return None
    n = None if data is None else data.n_points
    if data is not None and data.approx_points is not None:     # a simulation's points
        return load_truth(path, n)
    truth = load_truth(path, None)
    pts = truth.get("points")
    if n is None or pts is None or len(pts) == n:
        return truth
    from ..sensor.parameters import SensorParams

    ring = pathlib.Path(path).with_name("ring.csv")
    if ring.is_file() and data.approx_points is None:
        from ..io.tables import read_table

        c = read_table(ring, required=("x", "y", "z", "azimuth"), optional=("u", "v")).columns
        ring_pts = np.column_stack([c["x"], c["y"], c["z"]])
        pts = true_points(SensorParams(**truth["params"]), data.pixels, c["azimuth"], ring_pts)
        print(f"--truth {path}: {len(truth['points'])} simulated points, {n} pixels in the data: "
              f"each pixel's true point is taken on the true centre line ({ring}) at its azimuth")
        return {**truth, "points": pts, "n_points": n, "accuracy_note": IMAGE_TRUTH_NOTE}
    print(f"--truth {path}: its {len(truth['points'])} points are not the data's {n} (pixels "
          f"not from this simulation's points{'' if ring.is_file() else ', and no ring.csv'}"
          "); compared: the parameters only")
    return {k: v for k, v in truth.items() if k not in ("points", "pixels_true")}


def true_points(params, pixels, azimuth, points):
    """The true laser point (N, 3), mm, at each pixel's azimuth under the true sensor
    ``params``, interpolated on a true centre line (``azimuth`` (K,) rad, ``points`` (K, 3)
    mm, e.g. the renderer's)."""
    from ..sensor.laser import pixel_azimuth

    az = pixel_azimuth(params, pixels)
    order = np.argsort(azimuth)
    a, p = np.asarray(azimuth)[order], np.asarray(points)[order]
    return np.stack([np.interp(az, a, p[:, j], period=2 * np.pi) for j in range(3)], axis=-1)


def plain_pixel_noise(result, info, run, sigma_px):
    """What pixels without covariances get from a run that weighed its pixels by
    covariances (its ``sigma_px`` then a scale on them, not a noise in px).

    ``--sigma-px`` is taken as given; otherwise the run's typical noise
    (:class:`~bayescal.results.pixelnoise.RingNoise`): a posterior's file does not keep the
    covariances, which are then read again from the run's data file.

    Returns
    -------
    RingNoise or None
        None when the run had no covariances or ``--sigma-px`` is given.

    Raises
    ------
    UsageError
        The covariances cannot be found (the data file gone): ``--sigma-px`` is named.
    """
    if sigma_px is not None or "covariances" not in str(info.get("sigma_px_how", "")):
        return None
    noise = result.ring_noise()
    if noise is None and hasattr(result, "param_samples"):
        from ..io.data import load_laser_data

        data = (info.get("inputs") or {}).get("data")
        try:
            cal = load_laser_data(data, need_points=False)
        except (OSError, ValueError, TypeError):
            cal = None
        if cal is not None and cal.pixel_cov is not None and len(cal.pixels) == len(
                result.pixels) and np.allclose(cal.pixels, result.pixels):
            result.pixel_cov = cal.pixel_cov
            noise = result.ring_noise()
    if noise is None:
        raise UsageError(f"{run}: the run weighed its pixels by per-pixel covariances (its "
                         "sigma_px is a scale on them) and its calibration pixels' covariances "
                         f"are not at hand ({(info.get('inputs') or {}).get('data')} is gone "
                         "or changed); give --sigma-px PX, the pixel noise of these pixels, "
                         "or pixel files with cov_uu, cov_uv, cov_vv")
    return noise


def say_pixel_noise(job):
    """Print the pixel noise given to a reconstruction's frames without covariances."""
    plain = [f[0].name for f in job.frames if f[2] is None]
    if not plain:
        return
    which = ", ".join(plain[:3]) + (" ..." if len(plain) > 3 else "")
    if job.plain_noise is not None:
        print(f"pixel noise of {which} (no cov_uu, cov_uv, cov_vv columns): "
              f"{job.plain_noise.describe()}; --sigma-px PX gives another")
    elif job.sigma_px is not None:
        print(f"pixel noise of {which}: --sigma-px {job.sigma_px:g} px")


def frame_noise(job, pixel_cov):
    """A frame's pixel covariances for the reconstructor: its own, or ``--sigma-px`` for a
    posterior run (a least-squares run's reconstructor was made with it), or None (the
    run's default: its pixel noise, or its :class:`RingNoise`)."""
    if pixel_cov is None and job.sigma_px is not None and hasattr(job.result, "param_samples"):
        return job.sigma_px ** 2 * np.eye(2)
    return pixel_cov


def quiet_median(values):
    """The median of the finite values, NaN without any (and without numpy's warning: the
    rows that missed the cone are reported on their own)."""
    v = np.asarray(values, float)
    v = v[np.isfinite(v)]
    return float(np.median(v)) if v.size else float("nan")


def centred_geometry(check, data, nominal, camera):
    """``check(data, center=principal point)``, its refusal with :func:`camera_hint`."""
    try:
        check(data, center=(nominal.u0, nominal.v0))
    except UsageError as exc:
        raise UsageError(f"{exc}{camera_hint(data, nominal, camera)}") from None


def camera_hint(data, nominal, camera):
    """When the principal point is a ``--camera``'s and the data file states no image size:
    what to add to a refusal of the pixels' geometry (pixels of another camera than that one
    give the same); else ``""``."""
    if camera is None or data is None or data.image_size is not None:
        return ""
    return (f" (the principal point ({nominal.u0:.1f}, {nominal.v0:.1f}) is --camera "
            f"{camera}'s: pixels of another camera or image size give this too; add the "
            "data's '# image_size: WxH' line to check)")
