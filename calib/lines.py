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
    """Fixed frame of one line (module docstring).

    Attributes
    ----------
    point : ndarray, shape (3,)
        A point on the line [mm].
    direction : ndarray, shape (3,)
        Unit direction.
    e1, e2 : ndarray, shape (3,)
        Unit normals, ``(direction, e1, e2)`` right-handed and orthonormal.
    """

    point: np.ndarray
    direction: np.ndarray
    e1: np.ndarray
    e2: np.ndarray

    @classmethod
    def from_point_direction(cls, point, direction, normal=None) -> LineReference:
        """The frame of a line, ``e1`` along ``normal`` made perpendicular to it.

        Parameters
        ----------
        point : array_like, shape (3,)
            A point on the line [mm].
        direction : array_like, shape (3,)
            Its direction (any length).
        normal : array_like, shape (3,), optional
            Wanted ``e1`` (e.g. the dial's axis); absent or along the line: any perpendicular.

        Returns
        -------
        LineReference
        """
        u = np.asarray(direction, float)
        u = u / np.linalg.norm(u)
        e1 = None if normal is None else np.asarray(normal, float) - (np.asarray(normal, float) @ u) * u
        if e1 is None or np.linalg.norm(e1) < 1e-6:
            e1 = np.cross(u, np.eye(3)[np.argmin(np.abs(u))])
        e1 = e1 / np.linalg.norm(e1)
        return cls(np.asarray(point, float), u, e1, np.cross(u, e1))

    def line(self, params: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """The line for the unknowns ``params``.

        Parameters
        ----------
        params : ndarray, shape (4,)
            ``(c1, c2, b1, b2)`` [mm, mm, mm/mm, mm/mm].

        Returns
        -------
        point : ndarray, shape (3,)
            ``point + c1 e1 + c2 e2`` [mm].
        direction : ndarray, shape (3,)
            ``direction + b1 e1 + b2 e2``, normalised.
        """
        c1, c2, b1, b2 = params
        u = self.direction + b1 * self.e1 + b2 * self.e2
        point = self.point + c1 * self.e1 + c2 * self.e2
        return point, u / np.linalg.norm(u)


def fit_line(points: np.ndarray, normal=None) -> LineReference:
    """Least-squares line through points, centred on their mean.

    Parameters
    ----------
    points : ndarray, shape (N, 3), N >= 2
        Points [mm].
    normal : array_like, shape (3,), optional
        Wanted ``e1`` of the frame (``LineReference.from_point_direction``).

    Returns
    -------
    LineReference
        Through the mean, along the first principal direction.
    """
    centre = points.mean(axis=0)
    _, _, vt = np.linalg.svd(points - centre, full_matrices=False)
    return LineReference.from_point_direction(centre, vt[0], normal)


def line_residual(
    ref: LineReference, params: np.ndarray, p: np.ndarray
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Offsets of positions from a line and their derivatives (module docstring's ``r_k``).

    Parameters
    ----------
    ref : LineReference
        The line's fixed frame.
    params : ndarray, shape (4,)
        Its unknowns ``(c1, c2, b1, b2)``.
    p : ndarray, shape (N, 3)
        Positions [mm].

    Returns
    -------
    r : ndarray, shape (N, 2)
        Offsets along ``e1``, ``e2`` [mm].
    dr_dp : ndarray, shape (N, 2, 3)
        Their derivatives by ``p`` [mm/mm].
    dr_dparams : ndarray, shape (N, 2, 4)
        Their derivatives by ``params`` [mm/mm, mm per mm/mm].
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
