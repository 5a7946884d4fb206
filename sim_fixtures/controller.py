"""The simulated robot as a controller with its own joint convention presents it (a robot file's
``[controller]``: ``q_model = joint_sign * reading + joint_offset_deg``).

The simulated truth walks the model's joints; only what crosses the wire is the controller's: the
joints and speeds every joint server publishes (:class:`ControllerView`), and the corrected targets a
station writes to its target channel, which the program takes as the model's (:class:`ModelInbox`).
Both are picklable: a spawned RTDE server gets its own copy.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass
from typing import Any

import numpy as np

from calib.conventions import controller_joints, model_joints


@dataclass(frozen=True)
class ControllerView:
    """``robot`` (anything whose ``state(t_s)`` has ``q_deg`` and ``qd_deg_s``, the model's) with
    its joints [deg] and speeds [deg/s] in the convention ``sign`` (6,), ``offset_deg`` (6,) [deg]."""

    robot: Any
    sign: tuple[float, ...]
    offset_deg: tuple[float, ...]

    def state(self, t_s: float):
        now = self.robot.state(t_s)
        return dataclasses.replace(
            now,
            q_deg=controller_joints(now.q_deg, self.sign, self.offset_deg),
            qd_deg_s=np.asarray(self.sign, float) * np.asarray(now.qd_deg_s, float),
        )


@dataclass(frozen=True)
class ModelInbox:
    """A target channel's ``inbox(target, q_deg)`` fed with the controller's joints [deg]: hands the
    model's on (the convention as :class:`ControllerView`'s)."""

    inbox: Any
    sign: tuple[float, ...]
    offset_deg: tuple[float, ...]

    def __call__(self, target: int, q_deg) -> None:
        self.inbox(target, model_joints(q_deg, self.sign, self.offset_deg))


def presented(robot, inbox, sign=None, offset_deg=None):
    """``robot`` and ``inbox`` as a controller of convention ``sign``, ``offset_deg`` presents them
    (None or the identity: as they are)."""
    sign = tuple(float(v) for v in (sign if sign is not None else [1] * 6))
    offset = tuple(float(v) for v in (offset_deg if offset_deg is not None else [0.0] * 6))
    if all(v == 1 for v in sign) and not any(offset):
        return robot, inbox
    return ControllerView(robot, sign, offset), None if inbox is None else ModelInbox(inbox, sign, offset)
