"""Design values of a calibration: ``--nominal`` (whole or in part), the image size, and the
focal scale the data imply. The rule lives in the library
(:func:`bayescal.fit.start.design_values`, which the library also applies without an image
size when no prior is given); this module reads the options and says what was derived.

The paper's sensor (:meth:`~bayescal.SensorParams.paper`) has an 800x600 image. For any
other image size the design values that ``--nominal`` does not give are derived:

* ``u0, v0``: the image centre, with a prior sd of ``max(10, min(W, H) / 40)`` px (10 px
  for the paper's sensor, 26 px for 1280x1024: a lens is centred to a few percent of the
  sensor, not to 10 px);
* ``alpha_u, alpha_v``: the focal scale that puts the laser points where the pixels are,
  from the nominal ``xi, h, beta``: for each point with approximate coordinates, or on the
  rough floor plan's walls, the unit-scale projection radius ``rho / (xi r - z)`` (eq. (1)),
  and the scale is the median ratio of the pixels' distance from the centre to it (the
  paper's signs: ``alpha_u > 0 > alpha_v``). Without points or plan, the paper's 55 px
  scaled by ``min(W, H) / 600``;
* ``xi, phi, h, beta``: the paper's.

Imports only :mod:`bayescal.errors` at module level (``--help`` stays instant).
"""

from __future__ import annotations

import numpy as np

from ..errors import UsageError

__all__ = ["PAPER_IMAGE_SIZE", "read_nominal", "image_size_setting", "design_values",
           "centre_sd", "note_flagged", "note_design"]

#: the paper's image, width x height in px: its design values are the paper's sensor
PAPER_IMAGE_SIZE = (800, 600)


def read_nominal(path):
    """The design values ``--nominal`` gives: ``{name: value}``, any subset of the eight.

    Raises
    ------
    UsageError
        Not a JSON object, an unknown name, a value that is not a finite number, or
        values no sensor has (e.g. ``h <= 0``).
    """
    from ..io.data import read_json
    from ..sensor.parameters import PARAM_NAMES, SensorParams

    if path is None:
        return {}
    raw = read_json(path)
    raw = raw.get("params", raw) if isinstance(raw, dict) else raw
    if not isinstance(raw, dict):
        raise UsageError(f"--nominal {path}: expected a JSON object of design values, e.g. "
                         '{"u0": 640, "v0": 512}')
    unknown = [n for n in raw if n not in PARAM_NAMES]
    if unknown:
        raise UsageError(f"--nominal {path}: unknown parameter(s) {', '.join(unknown)}; "
                         f"expected some of {', '.join(PARAM_NAMES)} (the rest are derived)")
    out = {}
    for name, value in raw.items():
        try:
            v = float(value)
        except (TypeError, ValueError):
            v = float("nan")
        if not np.isfinite(v) or isinstance(value, bool):
            raise UsageError(f"--nominal {path}: {name} = {value!r}; expected a finite number")
        out[name] = v
    try:                                    # a valid sensor with the paper's values beside them
        paper = dict(zip(PARAM_NAMES, SensorParams.paper().to_array(), strict=True))
        SensorParams(**{**paper, **out})
    except (TypeError, ValueError) as exc:
        raise UsageError(f"--nominal {path}: {exc}") from None
    return out


def image_size_setting(option, data):
    """The image size: ``--image-size``, else the data file's ``# image_size:`` line, else
    the paper's 800x600. Returns ``((width, height), how)``."""
    if option is not None:
        return tuple(int(v) for v in option), "--image-size"
    size = None if data is None else data.image_size
    if size is not None:
        return tuple(size), f"{data.pixel_table.path} (image_size line)"
    return PAPER_IMAGE_SIZE, "default (the paper's sensor)"


def centre_sd(image_size):
    """Prior sd of the principal point (px) when it is the image centre, not a design value
    (:func:`bayescal.fit.start.centre_sd`)."""
    from ..fit.start import centre_sd as sd

    return sd(image_size)


def design_values(given, *, image_size, data=None, plan=None):
    """The nominal sensor: ``given`` design values, the rest derived from the image size
    and the data (:func:`bayescal.fit.start.design_values`, the library's rule with the
    image size known).

    Parameters
    ----------
    given : dict
        ``{name: value}`` from ``--nominal`` (any subset of the eight).
    image_size : (int, int)
        Width, height, px.
    data : LaserData, optional
        Pixels and approximate points (for the focal scale).
    plan : FloorPlan, optional
        The rough floor plan (for the focal scale without approximate points).

    Returns
    -------
    nominal : SensorParams
    derived : dict
        ``{name: how}`` of the values not given (empty for the paper's image size, whose
        defaults are the paper's sensor).
    """
    from ..errors import InvalidValueError
    from ..fit.start import design_values as library_design

    pixels = None if data is None else data.pixels
    points = None if data is None else data.approx_points
    try:
        return library_design(pixels, points, plan=plan, image_size=tuple(image_size),
                              given=given)
    except InvalidValueError as exc:
        raise UsageError(f"--nominal: {str(exc).removeprefix('design values: ')}") from None


def note_flagged(table, n_kept, what):
    """Say which rows ``bayescal extract`` flagged and the job leaves out."""
    lines = table.dropped
    if lines:
        unit = "lines" if table.kind == "csv" else "rows"
        shown = ", ".join(map(str, lines[:20])) + (" ..." if len(lines) > 20 else "")
        print(f"{table.path}: {len(lines)} of {len(lines) + n_kept} points flagged by "
              f"extract (flagged = 1) left out of the {what}: {unit} {shown}")


def note_design(size, derived, nominal):
    """Say which design values came from the image size or the data, not ``--nominal``."""
    if derived:
        vals = ", ".join(f"{n} = {getattr(nominal, n):.6g} ({how})" for n, how in derived.items())
        print(f"image {size[0][0]}x{size[0][1]} ({size[1]}): design values {vals}; give "
              "--nominal to set them")
