"""Gauge-block lines: fitting and a minimal (4-parameter) parametrisation.

A line is stored as a reference ``(point, direction, e1, e2)``, an orthonormal frame fixed at the
start of a calibration (the line fitted to the nominal TCPs), and four small unknowns
``(c1, c2, b1, b2)`` in mm and mm/mm:

    point(c)     = point + c1 e1 + c2 e2
    direction(b) ~ direction + b1 e1 + b2 e2      (not normalised)

The residual of a position ``p`` is its offset from the line, measured in the plane through ``p``
perpendicular to the reference direction::

    r_k = e_k . (p - point) - c_k - (direction . (p - point)) b_k,   k = 1, 2

This is exact for any line not perpendicular to the reference, linear in the four unknowns, and
equals the perpendicular distance to within a factor ``1 / sqrt(1 + b1^2 + b2^2)`` (a few ppm for the
mrad tilts a calibration moves a line by).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

N_LINE_PARAMS = 4


@dataclass(frozen=True)
class LineReference:
    """Fixed frame of one line: a point [mm], unit direction, and two unit normals ``e1, e2``."""

    point: np.ndarray
    direction: np.ndarray
    e1: np.ndarray
    e2: np.ndarray

    @classmethod
    def from_point_direction(cls, point, direction, normal=None) -> LineReference:
        """``e1`` along ``normal`` (e.g. the dial's axis) made perpendicular to the line, if given."""
        u = np.asarray(direction, float)
        u = u / np.linalg.norm(u)
        e1 = None if normal is None else np.asarray(normal, float) - (np.asarray(normal, float) @ u) * u
        if e1 is None or np.linalg.norm(e1) < 1e-6:
            e1 = np.cross(u, np.eye(3)[np.argmin(np.abs(u))])
        e1 = e1 / np.linalg.norm(e1)
        return cls(np.asarray(point, float), u, e1, np.cross(u, e1))

    def line(self, params: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """The line ``(point [mm], unit direction)`` for the unknowns ``params = (c1, c2, b1, b2)``."""
        c1, c2, b1, b2 = params
        u = self.direction + b1 * self.e1 + b2 * self.e2
        point = self.point + c1 * self.e1 + c2 * self.e2
        return point, u / np.linalg.norm(u)


def fit_line(points: np.ndarray, normal=None) -> LineReference:
    """Least-squares line through ``points`` (N, 3) [mm], N >= 2, centred on their mean; ``e1``
    along ``normal`` where given."""
    centre = points.mean(axis=0)
    _, _, vt = np.linalg.svd(points - centre, full_matrices=False)
    return LineReference.from_point_direction(centre, vt[0], normal)


def line_residual(
    ref: LineReference, params: np.ndarray, p: np.ndarray
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Offsets of positions ``p`` (N, 3) from the line, their derivatives by ``p`` and by ``params``.

    Returns ``r`` (N, 2) [mm], ``dr_dp`` (N, 2, 3) and ``dr_dparams`` (N, 2, 4).
    """
    c1, c2, b1, b2 = params
    rel = p - ref.point
    along = rel @ ref.direction
    r = np.stack([rel @ ref.e1 - c1 - along * b1, rel @ ref.e2 - c2 - along * b2], axis=1)
    dr_dp = np.stack([ref.e1 - b1 * ref.direction, ref.e2 - b2 * ref.direction])
    dr_dp = np.broadcast_to(dr_dp, (p.shape[0], 2, 3))
    dr_dparams = np.zeros((p.shape[0], 2, 4))
    dr_dparams[:, 0, 0] = -1.0
    dr_dparams[:, 1, 1] = -1.0
    dr_dparams[:, 0, 2] = -along
    dr_dparams[:, 1, 3] = -along
    return r, dr_dp, dr_dparams
