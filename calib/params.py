"""Names and display units of the 24 D-H parameters (joint-major, as ``dh.ravel()``)."""

from __future__ import annotations

import numpy as np

from calib.kinematics import DH_COLUMNS, N_JOINTS

_UNIT = {"theta": "deg", "d": "mm", "a": "mm", "alpha": "deg"}

DH_KEYS = tuple(f"{col}_{_UNIT[col]}" for col in DH_COLUMNS)
"""A joint's keys in the robot file (contract), in column order: theta_deg, d_mm, a_mm, alpha_deg."""

DH_NAMES = tuple(f"J{j + 1}.{key}" for j in range(N_JOINTS) for key in DH_KEYS)
"""Parameter names as the report writes them: ``J1.theta_deg``, ``J1.d_mm``, ..."""


def display_factor(names) -> np.ndarray:
    """Factor from internal units (rad, mm) to display units (deg, mm) for each name."""
    return np.array([np.degrees(1.0) if n.endswith("_deg") else 1.0 for n in names])


def dh_from_degrees(table_deg: np.ndarray) -> np.ndarray:
    """(6, 4) table in display units [theta deg, d mm, a mm, alpha deg] to internal (rad, mm)."""
    return table_deg * display_factor(DH_NAMES).reshape(6, 4) ** -1


def dh_to_degrees(dh: np.ndarray) -> np.ndarray:
    """(6, 4) internal table to display units (deg, mm)."""
    return dh * display_factor(DH_NAMES).reshape(6, 4)
