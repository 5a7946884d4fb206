"""A robot driver in the model's joints: a controller's joint convention applied on read, inverted on
write (contract: a robot file's ``[controller]``, ``q_model = joint_sign * reading + joint_offset_deg``).

:class:`ModelJoints` wraps any joint source: ``read()`` gives ``q_deg`` in the model's joints and
``qd_deg_s`` (where a reading carries it) with the signs applied (offsets do not move); its target
channel takes the model's joints and writes the controller's. Everything else (open, close, fields,
``no_channel``, ``clock_may_stand_still``, any other attribute) is the wrapped driver's.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Sequence

import numpy as np

from calib.conventions import controller_joints, model_joints
from drivers.base import Driver, Reading, TargetChannel


class ModelJoints(Driver):
    """``driver`` (a joint source) read and written in the model's joints under the convention
    ``sign`` (6,) of +-1 and ``offset_deg`` (6,) [deg]."""

    def __init__(self, driver: Driver, sign: Sequence[float], offset_deg: Sequence[float]):
        self.driver = driver
        self.sign, self.offset_deg = np.asarray(sign, float), np.asarray(offset_deg, float)
        self.name, self.fields = driver.name, driver.fields

    def __getattr__(self, name: str):
        if name == "driver":  # not set yet (a copy being made): no wrapped driver to ask
            raise AttributeError(name)
        return getattr(self.driver, name)

    @property
    def no_channel(self) -> str | None:  # type: ignore[override]
        return self.driver.no_channel

    @property
    def clock_may_stand_still(self) -> bool:  # type: ignore[override]
        return self.driver.clock_may_stand_still

    def open(self) -> None:
        self.driver.open()

    def close(self) -> None:
        self.driver.close()

    def read(self) -> Reading:
        """The wrapped driver's reading with ``q_deg`` [deg] and ``qd_deg_s`` [deg/s] the model's."""
        reading = self.driver.read()
        values = dict(reading.values)
        values["q_deg"] = _floats(model_joints(values["q_deg"], self.sign, self.offset_deg))
        if "qd_deg_s" in values:
            values["qd_deg_s"] = _floats(self.sign * np.asarray(values["qd_deg_s"], float))
        return dataclasses.replace(reading, values=values)

    def target_channel(self) -> ControllerTargets | None:
        inner = self.driver.target_channel()
        return None if inner is None else ControllerTargets(inner, self.sign, self.offset_deg)


@dataclasses.dataclass(frozen=True)
class ControllerTargets:
    """A target channel that takes the model's joints [deg] and writes the controller's to
    ``channel`` (``sign``, ``offset_deg``: the convention, as :class:`ModelJoints`)."""

    channel: TargetChannel
    sign: np.ndarray
    offset_deg: np.ndarray

    @property
    def where(self) -> str:
        return self.channel.where

    def write(self, target: int, q_deg: Sequence[float]) -> None:
        """Target ``target``'s model joints ``q_deg`` (6,) [deg], written as the controller's."""
        self.channel.write(target, _floats(controller_joints(q_deg, self.sign, self.offset_deg)))


def in_model_joints(driver: Driver, convention) -> Driver:
    """``driver`` in the model's joints under ``convention`` (a robot file's ``[controller]``:
    ``joint_sign``, ``joint_offset_deg``; None or the identity: ``driver`` itself)."""
    if convention is None:
        return driver
    sign, offset = np.asarray(convention.joint_sign, float), np.asarray(convention.joint_offset_deg, float)
    return driver if np.all(sign == 1) and not np.any(offset) else ModelJoints(driver, sign, offset)


def _floats(values) -> tuple[float, ...]:
    return tuple(float(v) for v in values)
