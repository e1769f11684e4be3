"""Point clouds out: reconstructed laser points with their covariances as PLY or NPZ.

A binary little-endian PLY (the format Open3D, MeshLab, CloudCompare and ROS tools read)
with one vertex per point: ``x y z`` (mm, frame C), the six entries of its 3x3 covariance
``cov_xx cov_xy cov_xz cov_yy cov_yz cov_zz`` (mm^2), and where known the pixel ``u v``
(px) and ``outlier_prob``. Every property is a float64; points that missed the cone are
written as NaN. About 40 lines of our own rather than a dependency: the header is plain
text and the body one structured numpy array (plyfile, the usual library, is GPL).
Files are written atomically and never replace an existing file unless asked.
"""

from __future__ import annotations

import os
import pathlib

import numpy as np

from ..errors import InvalidValueError, OutputExistsError

__all__ = ["write_ply", "write_npz", "cloud_fields", "COVARIANCE_FIELDS"]

#: the covariance entries, in the order of the PLY's properties
COVARIANCE_FIELDS = ("cov_xx", "cov_xy", "cov_xz", "cov_yy", "cov_yz", "cov_zz")
_UPPER = ((0, 0), (0, 1), (0, 2), (1, 1), (1, 2), (2, 2))


def cloud_fields(points, covariance=None, *, pixels=None, outlier_prob=None):
    """The per-point fields of a point cloud, ``{name: (M,) float64}`` in file order.

    Parameters
    ----------
    points : array_like, shape (M, 3)
        mm.
    covariance : array_like, shape (M, 3, 3), optional
        mm^2.
    pixels : array_like, shape (M, 2), optional
        px.
    outlier_prob : array_like, shape (M,), optional

    Returns
    -------
    dict
    """
    pts = np.asarray(points, dtype=float)
    if pts.ndim != 2 or pts.shape[1] != 3:
        raise InvalidValueError(f"points must have shape (M, 3), got {pts.shape}")
    m = len(pts)
    out = {"x": pts[:, 0], "y": pts[:, 1], "z": pts[:, 2]}
    if covariance is not None:
        cov = np.asarray(covariance, dtype=float)
        if cov.shape != (m, 3, 3):
            raise InvalidValueError(f"covariance must have shape (M, 3, 3) = {(m, 3, 3)}, "
                                    f"got {cov.shape}")
        out.update({n: cov[:, i, j] for n, (i, j) in zip(COVARIANCE_FIELDS, _UPPER,
                                                          strict=True)})
    if pixels is not None:
        pix = np.asarray(pixels, dtype=float)
        if pix.shape != (m, 2):
            raise InvalidValueError(f"pixels must have shape (M, 2) = {(m, 2)}, got {pix.shape}")
        out.update(u=pix[:, 0], v=pix[:, 1])
    if outlier_prob is not None:
        op = np.asarray(outlier_prob, dtype=float)
        if op.shape != (m,):
            raise InvalidValueError(f"outlier_prob must have shape (M,) = {(m,)}, got {op.shape}")
        out["outlier_prob"] = op
    return out


def _atomic_write(path, write, overwrite):
    path = pathlib.Path(path)
    if path.exists() and not overwrite:
        raise OutputExistsError(f"{path} exists; pass overwrite=True to replace it")
    tmp = path.with_name(path.name + ".tmp")
    try:
        with open(tmp, "wb") as f:
            write(f)
        os.replace(tmp, path)
    finally:
        tmp.unlink(missing_ok=True)
    return path


def write_ply(path, points, covariance=None, *, pixels=None, outlier_prob=None,
              overwrite=False):
    """Write a binary little-endian PLY point cloud (see the module docstring).

    Parameters
    ----------
    path : str or pathlib.Path
    points, covariance, pixels, outlier_prob
        As in :func:`cloud_fields`.
    overwrite : bool, optional
        Replace an existing file (default: refuse).

    Returns
    -------
    pathlib.Path
    """
    fields = cloud_fields(points, covariance, pixels=pixels, outlier_prob=outlier_prob)
    body = np.empty(len(fields["x"]), dtype=[(n, "<f8") for n in fields])
    for n, v in fields.items():
        body[n] = v
    header = ["ply", "format binary_little_endian 1.0",
              "comment bayescal point cloud: x y z mm in frame C, cov_* mm^2, u v px",
              f"element vertex {len(body)}"]
    header += [f"property double {n}" for n in fields] + ["end_header"]

    def write(f):
        f.write(("\n".join(header) + "\n").encode("ascii"))
        f.write(body.tobytes())

    return _atomic_write(path, write, overwrite)


def write_npz(path, points, covariance=None, *, pixels=None, outlier_prob=None,
              overwrite=False):
    """Write the same fields as :func:`write_ply` to a ``.npz`` (arrays ``points`` (M, 3),
    ``covariance`` (M, 3, 3), ``pixels`` (M, 2), ``outlier_prob`` (M,) where given)."""
    cloud_fields(points, covariance, pixels=pixels, outlier_prob=outlier_prob)   # checks
    arrays = {k: np.asarray(v, float) for k, v in (("points", points),
                                                   ("covariance", covariance),
                                                   ("pixels", pixels),
                                                   ("outlier_prob", outlier_prob))
              if v is not None}
    return _atomic_write(path, lambda f: np.savez_compressed(f, **arrays), overwrite)
