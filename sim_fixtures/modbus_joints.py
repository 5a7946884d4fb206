"""A simulated controller that publishes its six joints in Modbus TCP registers.

It is the simulated Modbus drawstring server (:class:`sim_fixtures.modbus_device.ModbusDevice`:
transport, start/stop, fault plan) with a different payload: on every read request the current
joints of the robot source are written into the registers in the
:class:`drivers.robot.JointRegisterMap` layout (e.g. INT32 millidegrees: 1 mdeg resolution).
"""

from __future__ import annotations

import time
from collections.abc import Callable

from drivers.robot import JointRegisterMap
from sim_fixtures.modbus_device import ModbusDevice
from sim_fixtures.serial_device import FaultPlan


def robot_joints(robot, start_monotonic: float | None = None) -> Callable[[], list[float]]:
    """``measure()`` for the server: the robot source's joints (deg) now, its program having
    started at ``start_monotonic`` (``time.monotonic()`` value; default: now)."""
    start = time.monotonic() if start_monotonic is None else start_monotonic
    return lambda: list(robot.state(time.monotonic() - start).q_deg)


class ModbusJointServer(ModbusDevice):
    """Serves ``measure()`` (six joints, deg) at ``registers`` on ``tcp=(host, port)`` (port 0
    picks a free one; see :attr:`address`). ``faults`` as for the drawstring server."""

    def __init__(
        self,
        registers: JointRegisterMap,
        measure: Callable[[], list[float]],
        *,
        tcp: tuple[str, int],
        faults: FaultPlan | None = None,
    ):
        super().__init__(registers, measure, tcp=tcp, faults=faults)

    def _encode(self, value) -> list[int]:
        """Registers for the current joints (deg)."""
        return self.registers.encode_deg(value)
