"""The station's device configuration (``configs/station.toml``): pydantic models and a loader.

Each device section says how to reach the instrument (``kind`` picks the transport) and builds
its driver with ``build()`` (robot drivers: ``drivers.robot``); connections are made by the
driver's ``open()``, never here. Unknown keys are refused, so a misspelt key is an error rather
than a silent default.
:func:`load_station_config` turns every problem into one ``InputError`` line naming the file,
the key and what is wrong.
"""

from __future__ import annotations

import sys
from pathlib import Path
from typing import Annotated, Literal

import serial
from pydantic import BaseModel, ConfigDict, Field, ValidationError
from pymodbus.client import ModbusSerialClient, ModbusTcpClient

from drivers.base import Backoff, Driver
from drivers.dial import DIAL_DIALECTS, DialIndicator
from drivers.drawstring import ENCODINGS, AsciiDrawstring, ModbusDrawstring, RegisterMap
from drivers.robot import JOINT_ENCODINGS, JointRegisterMap, ModbusJointSource, RtdeJointSource
from station.errors import InputError

if sys.version_info >= (3, 11):
    import tomllib
else:  # pragma: no cover
    import tomli as tomllib


class _Section(BaseModel):
    model_config = ConfigDict(extra="forbid", frozen=True)


class Registers(_Section):
    """Modbus layout of the length: defaults are holding register 0, INT32 micrometres, high
    word first, scale 1 (``length_mm = raw * unit_per_count * scale``)."""

    address: int = Field(0, ge=0, le=65535)
    encoding: Literal[tuple(ENCODINGS)] = "int32_um"  # type: ignore[valid-type]
    word_order: Literal["big", "little"] = "big"
    scale: float = 1.0
    table: Literal["holding", "input"] = "holding"

    def register_map(self, device_id: int) -> RegisterMap:
        return RegisterMap(device_id=device_id, **self.model_dump())


class SerialLine(_Section):
    """A serial port: path (``/dev/ttyUSB0``, or a simulated ``/tmp/station-sim/<name>`` link),
    line speed (baud) and the reply timeout (s)."""

    port: str
    baudrate: int = Field(9600, gt=0)
    timeout_s: float = Field(0.2, gt=0)

    def serial_port(self) -> serial.Serial:
        """The unopened pyserial port (the driver opens it)."""
        return serial.serial_for_url(
            self.port,
            do_not_open=True,
            baudrate=self.baudrate,
            timeout=self.timeout_s,
            exclusive=True,
        )


class DrawstringModbusTcp(_Section):
    kind: Literal["modbus_tcp"]
    host: str = "127.0.0.1"
    port: int = Field(5020, gt=0, le=65535)
    device_id: int = Field(1, ge=0, le=255)
    timeout_s: float = Field(0.3, gt=0)
    registers: Registers = Registers()

    def build(self) -> Driver:
        client = ModbusTcpClient(self.host, port=self.port, timeout=self.timeout_s, retries=0)
        return ModbusDrawstring(client, self.registers.register_map(self.device_id))


class DrawstringModbusRtu(SerialLine):
    kind: Literal["modbus_rtu"]
    baudrate: int = Field(115200, gt=0)
    device_id: int = Field(1, ge=0, le=255)
    timeout_s: float = Field(0.3, gt=0)
    registers: Registers = Registers()

    def build(self) -> Driver:
        client = ModbusSerialClient(self.port, baudrate=self.baudrate, timeout=self.timeout_s, retries=0)
        return ModbusDrawstring(client, self.registers.register_map(self.device_id))


class DrawstringAscii(SerialLine):
    kind: Literal["ascii"]

    def build(self) -> Driver:
        return AsciiDrawstring(self.serial_port())


Drawstring = Annotated[
    DrawstringModbusTcp | DrawstringModbusRtu | DrawstringAscii, Field(discriminator="kind")
]


class Dial(SerialLine):
    """Dial indicator on a serial line; ``dialect`` is ``sylvac`` (default) or ``mitutoyo``."""

    dialect: Literal[DIAL_DIALECTS] = "sylvac"  # type: ignore[valid-type]

    def build(self) -> Driver:
        return DialIndicator(self.serial_port(), self.dialect)


class RobotRtde(_Section):
    """A UR controller's RTDE interface (port 30004 is fixed by the protocol)."""

    kind: Literal["rtde"]
    host: str = "127.0.0.1"
    frequency_hz: float = Field(500.0, gt=0, le=500)

    def build(self) -> Driver:
        return RtdeJointSource(self.host, self.frequency_hz)


class RobotModbusTcp(_Section):
    """A controller publishing its six joints in Modbus registers (e.g. the HSR JR680): from
    ``address`` on, joint 1 first, ``encoding`` with ``word_order``, times ``scale``."""

    kind: Literal["modbus_tcp"]
    host: str = "127.0.0.1"
    port: int = Field(502, gt=0, le=65535)
    device_id: int = Field(1, ge=0, le=255)
    address: int = Field(0, ge=0, le=65535)
    encoding: Literal[tuple(JOINT_ENCODINGS)] = "int32_mdeg"  # type: ignore[valid-type]
    word_order: Literal["big", "little"] = "big"
    scale: float = 1.0
    table: Literal["holding", "input"] = "holding"
    timeout_s: float = Field(0.3, gt=0)

    def build(self) -> Driver:
        client = ModbusTcpClient(self.host, port=self.port, timeout=self.timeout_s, retries=0)
        layout = self.model_dump(include={"device_id", "address", "encoding", "word_order", "scale", "table"})
        return ModbusJointSource(client, JointRegisterMap(**layout))


Robot = Annotated[RobotRtde | RobotModbusTcp, Field(discriminator="kind")]


class Reconnect(_Section):
    """Retries after a transient failure: ``attempts`` in all, waits growing from ``initial_s``
    by ``factor`` up to ``max_s`` (s)."""

    attempts: int = Field(4, ge=1)
    initial_s: float = Field(0.05, ge=0)
    factor: float = Field(2.0, ge=1)
    max_s: float = Field(1.0, ge=0)

    def backoff(self) -> Backoff:
        return Backoff(**self.model_dump())


class Sim(_Section):
    """The simulated cell that ``station sim serve`` runs: world seed, robot program motion."""

    seed: int = 0
    speed_deg_s: float = Field(30.0, gt=0)
    accel_deg_s2: float = Field(60.0, gt=0)
    dwell_s: float = Field(3.0, ge=0)
    targets_per_line: int = Field(70, ge=2)  # the cell's plan: targets along each gauge line


class Session(_Section):
    """``station sample``: what is calibrated (robot model and setup files, relative to this config
    or to the shipped ``configs/``) and the capture rule. Times are simulated seconds (divided by
    ``time_scale`` at the station), speeds as the controller reports them."""

    robot_model: str = "robots/hsr_jr680.toml"
    setup: str = "setups/sim.toml"
    settle_speed_deg_s: float = Field(0.05, gt=0)  # every |qd| below this ...
    settle_s: float = Field(0.5, gt=0)  # ... for this long, robot mode RUNNING: settled
    readings: int = Field(5, ge=2)  # K readings of every device per capture
    window_s: float = Field(1.5, gt=0)  # all K rounds inside this synchronisation window
    still_deg: float = Field(0.005, gt=0)  # joint span during a capture: else "robot moved"
    jump_mm: float = Field(0.15, gt=0)  # drawstring span during a capture: else "sensor jumped"
    dial_range_mm: tuple[float, float] = (-2.0, 2.0)  # dial gate (in range to capture)
    dial_stable_mm: float = Field(0.02, gt=0)  # dial span during a capture (noise 0.002 mm)
    length_range_mm: tuple[float, float] = (50.0, 5000.0)  # drawstring outside: slack or jump
    match_deg: float = Field(2.0, gt=0)  # a settle this far (max |dq|) from every target is ignored
    target_timeout_s: float = Field(120.0, gt=0)  # no capture for this long: the session ends
    unreachable_s: float = Field(30.0, gt=0)  # real s a device may stay silent while suspended


class StationConfig(_Section):
    """``configs/station.toml``: one section per device, plus the shared ``time_scale``."""

    time_scale: float = Field(1.0, gt=0)
    session: Session = Session()
    robot: Robot
    drawstring: Drawstring
    dial: Dial | None = None
    reconnect: Reconnect = Reconnect()
    sim: Sim = Sim()

    def devices(self) -> dict[str, BaseModel]:
        """The configured device sections by name, robot first."""
        found = {"robot": self.robot, "drawstring": self.drawstring, "dial": self.dial}
        return {name: section for name, section in found.items() if section is not None}


def _key(loc: tuple) -> str:
    """``drawstring.registers.address`` from a pydantic error location (union tags dropped)."""
    tags = {"rtde", "modbus_tcp", "modbus_rtu", "ascii", "function-after", "function-wrap"}
    return ".".join(str(part) for part in loc if part not in tags) or "(top level)"


def load_station_config(path: str | Path) -> StationConfig:
    """Read and validate a station config; any problem is an ``InputError`` naming file and key."""
    path = Path(path)
    try:
        raw = tomllib.loads(path.read_text())
    except OSError as exc:
        raise InputError(f"{path}: cannot read: {exc.strerror or exc}") from exc
    except tomllib.TOMLDecodeError as exc:
        raise InputError(f"{path}: not valid TOML: {exc}") from exc
    try:
        return StationConfig.model_validate(raw)
    except ValidationError as exc:
        err = exc.errors()[0]
        raise InputError(f"{path}: {_key(err['loc'])}: {err['msg']}") from exc
