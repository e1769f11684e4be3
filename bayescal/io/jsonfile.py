"""JSON files: numpy-aware writing (non-finite numbers kept as strings) and located read errors."""

from __future__ import annotations

import json
import math
import pathlib

import numpy as np

from ..errors import InputError, InvalidValueError

__all__ = ["to_jsonable", "write_json", "read_json"]


def to_jsonable(obj, *, nonfinite="string"):
    """Convert numpy arrays/scalars (and paths) to plain JSON types, recursively.

    Parameters
    ----------
    obj : object
    nonfinite : {"string", "null"}
        NaN and infinities become ``"nan"``/``"inf"``/``"-inf"`` (default, lossless)
        or ``None``.
    """
    if nonfinite not in ("string", "null"):
        raise InvalidValueError(f"nonfinite must be 'string' or 'null', got {nonfinite!r}")
    if isinstance(obj, dict):
        return {str(k): to_jsonable(v, nonfinite=nonfinite) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [to_jsonable(v, nonfinite=nonfinite) for v in obj]
    if isinstance(obj, np.ndarray):
        return to_jsonable(obj.tolist(), nonfinite=nonfinite)
    if isinstance(obj, (np.bool_, bool)):
        return bool(obj)
    if isinstance(obj, (np.integer,)):
        return int(obj)
    if isinstance(obj, (float, np.floating)):
        v = float(obj)
        if math.isfinite(v):
            return v
        if nonfinite == "null":
            return None
        return "inf" if v > 0 else "-inf" if v < 0 else "nan"
    if isinstance(obj, pathlib.Path):
        return str(obj)
    return obj


def write_json(path, obj):
    """Write ``obj`` as indented JSON (numpy arrays as lists, non-finite floats as strings)."""
    path = pathlib.Path(path)
    path.write_text(json.dumps(to_jsonable(obj), indent=2) + "\n", encoding="utf-8")
    return path


def read_json(path):
    """Read a JSON file written by :func:`write_json` (``"inf"``/``"nan"`` strings stay strings)."""
    path = pathlib.Path(path)
    try:
        return json.loads(path.read_text(encoding="utf-8"))
    except FileNotFoundError:
        raise InputError(f"{path}: no such file", path=str(path)) from None
    except json.JSONDecodeError as exc:
        raise InputError(f"{path}, line {exc.lineno}: not valid JSON ({exc.msg})",
                         path=str(path), line=exc.lineno) from None
