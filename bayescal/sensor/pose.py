"""The pose of the laser cone in frame C: tilt and offset of a hand-assembled sensor.

The paper's model puts the cone's apex on the camera's axis, at ``(0, 0, -h)``, with its
axis along ``z``. A real sensor's cone is tilted by ``(tilt_x, tilt_y)`` and its apex offset
by ``(offset_x, offset_y)``:

* apex ``(offset_x, offset_y, -h)`` mm in frame C;
* axis ``R (0, 0, 1)`` with ``R = Ry(tilt_y) Rx(tilt_x)``: ``tilt_x`` rotates about ``x``
  (tipping the axis towards ``-y``), then ``tilt_y`` about ``y`` (towards ``+x``), rad;
* the lit generatrix at cone azimuth ``phi`` has direction
  ``R (sin beta cos phi, sin beta sin phi, cos beta)``.

All four zero is the paper's cone exactly (``docs/conventions.md``).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

__all__ = ["LaserPose", "rotation"]


def rotation(tilt_x, tilt_y):
    """``Ry(tilt_y) @ Rx(tilt_x)``, shape (3, 3)."""
    cx, sx, cy, sy = np.cos(tilt_x), np.sin(tilt_x), np.cos(tilt_y), np.sin(tilt_y)
    rx = np.array([[1.0, 0.0, 0.0], [0.0, cx, -sx], [0.0, sx, cx]])
    ry = np.array([[cy, 0.0, sy], [0.0, 1.0, 0.0], [-sy, 0.0, cy]])
    return ry @ rx


@dataclass(frozen=True)
class LaserPose:
    """Tilt and offset of the laser cone (see the module docstring for the convention).

    Parameters
    ----------
    tilt_x, tilt_y : float
        rad.
    offset_x, offset_y : float
        mm.
    h : float, optional
        Depth of the apex below the mirror focus, mm (needed for :attr:`apex`).

    Examples
    --------
    >>> import numpy as np
    >>> import bayescal as bc
    >>> pose = bc.LaserPose(tilt_x=0.0, tilt_y=np.radians(1.0), offset_x=5.0, h=200.0)
    >>> np.round(pose.axis, 4).tolist(), pose.apex.tolist()
    ([0.0175, 0.0, 0.9998], [5.0, 0.0, -200.0])
    """

    tilt_x: float = 0.0
    tilt_y: float = 0.0
    offset_x: float = 0.0
    offset_y: float = 0.0
    h: float | None = None

    def __post_init__(self):
        for name in ("tilt_x", "tilt_y", "offset_x", "offset_y"):
            v = getattr(self, name)
            if not np.isfinite(v):
                raise ValueError(f"{name} must be finite, got {v!r}")
        if max(abs(self.tilt_x), abs(self.tilt_y)) >= np.pi / 4:
            raise ValueError(f"tilts must be below 45 degrees, got ({self.tilt_x!r}, "
                             f"{self.tilt_y!r}) rad")

    @property
    def aligned(self):
        """True when all four are zero (the paper's cone)."""
        return self.tilt_x == self.tilt_y == self.offset_x == self.offset_y == 0.0

    @property
    def rotation(self):
        """``Ry(tilt_y) Rx(tilt_x)``, shape (3, 3)."""
        return rotation(self.tilt_x, self.tilt_y)

    @property
    def axis(self):
        """Unit axis of the cone in frame C, shape (3,)."""
        return self.rotation[:, 2].copy()

    @property
    def apex(self):
        """Apex of the cone in frame C, shape (3,) mm."""
        if self.h is None:
            raise ValueError("apex needs h: LaserPose(..., h=...)")
        return np.array([self.offset_x, self.offset_y, -float(self.h)])

    def generatrix(self, beta, phi):
        """Unit directions of the lit generatrices at cone azimuths ``phi``, shape (..., 3).

        Parameters
        ----------
        beta : float
            Half-angle of the cone from its axis, rad.
        phi : array_like, shape (...)
            Azimuths about the cone's axis, rad.
        """
        phi = np.asarray(phi, dtype=float)
        local = np.stack([np.sin(beta) * np.cos(phi), np.sin(beta) * np.sin(phi),
                          np.full(phi.shape, np.cos(beta))], axis=-1)
        return local @ self.rotation.T
