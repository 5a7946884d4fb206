"""Unit mistakes a whole file makes recognisable, each refused with one line naming the likely
mistake: joints in radians where the contract wants degrees, a robot table's twists or joint limits
in radians, a setup's positions in metres. Each check looks at all of a file's values at once (one
small value is no evidence; all of them are), with the bounds stated in ``station.formats.base``."""

from __future__ import annotations

import numpy as np

from errors import InputError
from station.formats.base import MAX_TWIST_RAD, METRES_AS_MM, MIN_JOINT_RANGE_DEG, RADIANS_AS_DEG


def check_joints_in_degrees(path: str, q_deg: np.ndarray, what: str) -> None:
    """Bad input if every joint value of the file (``q1_deg .. q6_deg`` of all its ``what`` rows)
    lies within +-2 pi: radians in degrees columns (a real set moves its joints further)."""
    q = np.asarray(q_deg, float)
    if q.size and np.abs(q).max() <= RADIANS_AS_DEG and np.ptp(q, axis=0).max() > 0:
        raise InputError(
            f"{path}: every joint value of its {len(q)} {what} lies within +-6.28 (largest "
            f"{np.abs(q).max():.3g}): these look like radians, but q1_deg .. q6_deg are in degrees "
            "(multiply by 57.2958)"
        )


def check_robot_units(path: str, table_deg: np.ndarray, limits_deg: np.ndarray) -> None:
    """Bad input if the robot file's twists (``alpha_deg``) all lie within +-pi/2 and are not all
    zero, or a joint's limits span under ``MIN_JOINT_RANGE_DEG``: radians in degree fields."""
    alpha = np.asarray(table_deg, float)[:, 3]
    if np.abs(alpha).max() <= MAX_TWIST_RAD and np.abs(alpha).max() > 1e-3:
        values = ", ".join(f"{a:g}" for a in alpha)
        raise InputError(
            f"{path}: joints.*.alpha_deg are all within +-1.571 ({values}): these look like radians, "
            "but the D-H angles (alpha_deg, theta_deg) are in degrees"
        )
    span = np.diff(np.asarray(limits_deg, float), axis=1)[:, 0]
    if (span < MIN_JOINT_RANGE_DEG).any():
        j = int(np.argmin(span))
        lo, hi = limits_deg[j]
        raise InputError(
            f"{path}: joints.{j}: q_min_deg {lo:g} .. q_max_deg {hi:g} spans {span[j]:.3g} deg, under "
            f"{MIN_JOINT_RANGE_DEG:g}: these look like radians, but joint limits are in degrees"
        )


def check_positions_in_mm(path: str, points: dict[str, list[float]]) -> None:
    """Bad input if every stated gauge-line point (``points``: key -> [x, y, z]) lies within
    ``METRES_AS_MM`` of the base: metres where the setup wants mm."""
    if not points:
        return
    far = max(float(np.linalg.norm(p)) for p in points.values())
    if far < METRES_AS_MM:
        key, p = next(iter(points.items()))
        raise InputError(
            f"{path}: every gauge-line point lies within {METRES_AS_MM:g} mm of the robot's base ({key} = "
            f"{p}): these look like metres, but point_mm is in mm (multiply by 1000)"
        )
