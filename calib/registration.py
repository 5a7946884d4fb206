"""Registration of a calibrated model's base frame to the cell's, through the gauge lines.

A drawstring-and-lines calibration determines the robot's geometry up to a rigid motion of its base
frame together with the anchor and the lines (nothing it measures sees where the cell is): its
frame sits millimetres from the frame the setup's lines were measured in, and targets the setup
places are only reached once the two are registered. Each measured line is in both: as the fit
placed it (calibrated frame) and as the setup states it (cell frame, to its placement tolerance),
so the rigid motion that brings the fitted lines onto the stated ones registers the frames. Two
lines that are not parallel determine it; with one, the turn about it and the shift along it are
kept near none by a weak prior (``prior_mm``, ``prior_rad``).
"""

from __future__ import annotations

import numpy as np
from scipy.optimize import least_squares
from scipy.spatial.transform import Rotation


def register_lines(
    points_from: np.ndarray,
    directions_from: np.ndarray,
    points_to: np.ndarray,
    directions_to: np.ndarray,
    lengths_mm: np.ndarray,
    placement_mm: float = 0.5,
    prior_mm: float = 50.0,
    prior_rad: float = 0.05,
) -> tuple[np.ndarray, np.ndarray]:
    """The rigid motion ``(R, t)`` that best maps lines (K,) given by a point and a unit direction
    (K, 3) each in one frame onto the same lines in another: each line's point off its counterpart
    (across it) and its direction's turn (times half the line's length ``lengths_mm`` (K,), the
    shift at its ends), both in units of ``placement_mm``, plus the weak prior. Returns ``R``
    (3, 3) and ``t`` (3,) [mm] with ``x_to = R x_from + t``."""
    d_to = directions_to / np.linalg.norm(directions_to, axis=1, keepdims=True)
    across = np.eye(3) - d_to[:, :, None] * d_to[:, None, :]  # (K, 3, 3): off the line, not along it

    def residuals(v: np.ndarray) -> np.ndarray:
        rot = Rotation.from_rotvec(v[:3]).as_matrix()
        off = np.einsum("kij,kj->ki", across, points_from @ rot.T + v[3:] - points_to)
        turn = np.cross(directions_from @ rot.T, d_to) * (lengths_mm[:, None] / 2)
        lines = np.r_[off.ravel(), turn.ravel()] / placement_mm
        return np.r_[lines, v[:3] / prior_rad, v[3:] / prior_mm]

    v = least_squares(residuals, np.zeros(6), method="lm", xtol=1e-12).x
    return Rotation.from_rotvec(v[:3]).as_matrix(), v[3:]
