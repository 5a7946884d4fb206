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
    """Factors from internal units (rad, mm) to display units (deg, mm).

    Parameters
    ----------
    names : sequence of str, length k
        Parameter names; a ``*_deg`` name is an angle.

    Returns
    -------
    ndarray, shape (k,)
        ``180 / pi`` for an angle, 1 otherwise.
    """
    return np.array([np.degrees(1.0) if n.endswith("_deg") else 1.0 for n in names])


def display_unit(name: str) -> tuple[float, str]:
    """``display_factor`` of one parameter and its display unit, by its name's suffix."""
    unit = "deg" if name.endswith("_deg") else "urad/(N m)" if name.endswith("_urad_per_Nm") else "mm"
    return float(display_factor([name])[0]), unit


def dh_from_degrees(table_deg: np.ndarray) -> np.ndarray:
    """A table in display units to internal units.

    Parameters
    ----------
    table_deg : ndarray, shape (6, 4)
        Columns theta [deg], d [mm], a [mm], alpha [deg] (the robot file's ``DH_KEYS``).

    Returns
    -------
    ndarray, shape (6, 4)
        Columns theta [rad], d [mm], a [mm], alpha [rad].
    """
    return table_deg * display_factor(DH_NAMES).reshape(6, 4) ** -1


def dh_to_degrees(dh: np.ndarray) -> np.ndarray:
    """A table in internal units to display units (the inverse of :func:`dh_from_degrees`).

    Parameters
    ----------
    dh : ndarray, shape (6, 4)
        Columns theta [rad], d [mm], a [mm], alpha [rad].

    Returns
    -------
    ndarray, shape (6, 4)
        Columns theta [deg], d [mm], a [mm], alpha [deg].
    """
    return dh * display_factor(DH_NAMES).reshape(6, 4)
