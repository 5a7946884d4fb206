"""The live error: the drawstring reading against the length the current model predicts.

The model is the nominal robot table with the drawstring's anchor and offset refitted (least
squares, 4 unknowns) to every sample so far, so the live error of a sample shows what the
calibration will have to explain: the robot's geometric error, or a bad reading (a jump of
millimetres against a trend of tenths). Until 4 samples are in, the setup's rough values serve.
"""

from __future__ import annotations

import numpy as np
from scipy.optimize import least_squares

from calib.kinematics import tcp_position
from calib.params import dh_from_degrees
from station.formats.tables import RobotFile, SetupFile


class LiveFit:
    """Nominal TCPs of the samples (mm) and the refitted ``anchor_mm`` / ``length_offset_mm``."""

    def __init__(self, robot: RobotFile, setup: SetupFile):
        self.dh = dh_from_degrees(robot.table_deg())
        self.tool = np.asarray(robot.tool_mm, float)
        self.x = np.r_[setup.drawstring.anchor_mm, setup.drawstring.length_offset_mm]
        self.tcps: list[np.ndarray] = []
        self.lengths: list[float] = []

    def tcp_mm(self, q_deg) -> np.ndarray:
        """Nominal TCPs (N, 3), mm, of configurations (N, 6) in degrees."""
        return tcp_position(self.dh, np.radians(np.atleast_2d(q_deg)), self.tool)

    def predict_mm(self, tcp_mm) -> np.ndarray:
        return np.linalg.norm(np.atleast_2d(tcp_mm) - self.x[:3], axis=1) - self.x[3]

    def add(self, q_deg, length_mm: float) -> tuple[np.ndarray, float]:
        """The sample's nominal TCP (3,) and the model's length for it (before refitting on it)."""
        tcp = self.tcp_mm(q_deg)[0]
        model = float(self.predict_mm(tcp)[0])
        self.tcps.append(tcp)
        self.lengths.append(float(length_mm))
        if len(self.tcps) >= 4:
            p, y = np.array(self.tcps), np.array(self.lengths)
            self.x = least_squares(lambda x: np.linalg.norm(p - x[:3], axis=1) - x[3] - y, self.x).x
        return tcp, model


def line_segments(tcp_mm: np.ndarray, line_ids: np.ndarray) -> dict[int, np.ndarray]:
    """Each gauge line as a segment (2, 3): the principal axis of its TCPs, over their extent."""
    out = {}
    for lid in np.unique(line_ids):
        p = tcp_mm[line_ids == lid]
        centre = p.mean(axis=0)
        direction = np.linalg.svd(p - centre)[2][0] if len(p) > 1 else np.array([1.0, 0, 0])
        s = (p - centre) @ direction
        out[int(lid)] = centre + np.outer([s.min() - 20.0, s.max() + 20.0], direction)
    return out
