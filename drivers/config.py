"""Device sections of the station's configuration: pydantic models, one per transport.

Each device section says how to reach the instrument (``kind`` picks the transport) and builds
its driver with ``build()``; connections are made by the driver's ``open()``, never here. Unknown
keys are refused, so a misspelt key is an error rather than a silent default. The whole file
(sessions, the simulator) is ``station.config``'s.
"""

from __future__ import annotations

from typing import Annotated, Literal

import serial
from pydantic import AfterValidator, BaseModel, ConfigDict, Field
from pymodbus.client import ModbusSerialClient, ModbusTcpClient

from drivers.base import Backoff, Driver
from drivers.dial import DIAL_DIALECTS, DialIndicator
from drivers.drawstring import ENCODINGS, AsciiDrawstring, ModbusDrawstring, RegisterMap
from drivers.robot import JOINT_ENCODINGS, RTDE_PORT, JointRegisterMap, ModbusJointSource, RtdeJointSource


class Section(BaseModel):
    """A section of the station config: unknown keys, NaN and infinity are refused."""

    model_config = ConfigDict(extra="forbid", frozen=True, allow_inf_nan=False, defer_build=True)


Name = Annotated[str, Field(min_length=1, pattern=r"^[^\x00]*$")]
"""A host name or a path: not empty, no NUL character (which no system call accepts)."""
Timeout = Annotated[float, Field(gt=0, le=60)]  # s


def _scale(value: float) -> float:
    if not 1e-6 <= abs(value) <= 1e6:
        raise ValueError(f"{value:g}: the scale must lie within 1e-6 .. 1e6 (or the same negative)")
    return value


Scale = Annotated[float, AfterValidator(_scale)]
"""What a raw register value is multiplied by (after the encoding's unit)."""


class Registers(Section):
    """Modbus layout of the length: defaults are holding register 0, INT32 micrometres, high
    word first, scale 1 (``length_mm = raw * unit_per_count * scale``)."""

    address: int = Field(0, ge=0, le=65535)
    encoding: Literal[tuple(ENCODINGS)] = "int32_um"  # type: ignore[valid-type]
    word_order: Literal["big", "little"] = "big"
    scale: Scale = 1.0
    table: Literal["holding", "input"] = "holding"

    def register_map(self, device_id: int) -> RegisterMap:
        return RegisterMap(device_id=device_id, **self.model_dump())


class SerialLine(Section):
    """A serial port: path (``/dev/ttyUSB0``, or a simulated ``/tmp/station-sim/<name>`` link),
    line speed (baud) and the reply timeout (s)."""

    port: Name
    baudrate: int = Field(9600, gt=0, le=10_000_000)
    timeout_s: Timeout = 0.2

    def serial_port(self) -> serial.Serial:
        """The unopened pyserial port (the driver opens it)."""
        return serial.serial_for_url(
            self.port,
            do_not_open=True,
            baudrate=self.baudrate,
            timeout=self.timeout_s,
            exclusive=True,
        )


class DrawstringModbusTcp(Section):
    kind: Literal["modbus_tcp"]
    host: Name = "127.0.0.1"
    port: int = Field(5020, gt=0, le=65535)
    device_id: int = Field(1, ge=0, le=255)
    timeout_s: Timeout = 0.3
    registers: Registers = Registers()

    def build(self) -> Driver:
        client = ModbusTcpClient(self.host, port=self.port, timeout=self.timeout_s, retries=0)
        return ModbusDrawstring(client, self.registers.register_map(self.device_id))


class DrawstringModbusRtu(SerialLine):
    kind: Literal["modbus_rtu"]
    baudrate: int = Field(115200, gt=0, le=10_000_000)
    device_id: int = Field(1, ge=0, le=255)
    timeout_s: Timeout = 0.3
    registers: Registers = Registers()

    def build(self) -> Driver:
        client = ModbusSerialClient(self.port, baudrate=self.baudrate, timeout=self.timeout_s, retries=0)
        return ModbusDrawstring(client, self.registers.register_map(self.device_id))


class DrawstringAscii(SerialLine):
    kind: Literal["ascii"]

    def build(self) -> Driver:
        return AsciiDrawstring(self.serial_port())


DrawstringConfig = Annotated[
    DrawstringModbusTcp | DrawstringModbusRtu | DrawstringAscii, Field(discriminator="kind")
]


class DialConfig(SerialLine):
    """Dial indicator on a serial line; ``dialect`` is ``sylvac`` (default) or ``mitutoyo``."""

    dialect: Literal[DIAL_DIALECTS] = "sylvac"  # type: ignore[valid-type]

    def build(self) -> Driver:
        return DialIndicator(self.serial_port(), self.dialect)


class RobotRtde(Section):
    """A UR controller's RTDE interface (port 30004 is fixed by the protocol)."""

    kind: Literal["rtde"]
    host: Name = "127.0.0.1"
    frequency_hz: float = Field(500.0, ge=1, le=500)

    def build(self) -> Driver:
        return RtdeJointSource(self.host, self.frequency_hz)

    def endpoint(self) -> str:
        """Where the joints are read, as a simulator announces the robot it serves."""
        return f"rtde {self.host}:{RTDE_PORT}"


class RobotModbusTcp(Section):
    """A controller publishing its six joints in Modbus registers (e.g. the HSR JR680): from
    ``address`` on, joint 1 first, ``encoding`` with ``word_order``, times ``scale``."""

    kind: Literal["modbus_tcp"]
    host: Name = "127.0.0.1"
    port: int = Field(502, gt=0, le=65535)
    device_id: int = Field(1, ge=0, le=255)
    address: int = Field(0, ge=0, le=65535)
    encoding: Literal[tuple(JOINT_ENCODINGS)] = "int32_mdeg"  # type: ignore[valid-type]
    word_order: Literal["big", "little"] = "big"
    scale: Scale = 1.0
    table: Literal["holding", "input"] = "holding"
    timeout_s: Timeout = 0.3

    def build(self) -> Driver:
        client = ModbusTcpClient(self.host, port=self.port, timeout=self.timeout_s, retries=0)
        layout = self.model_dump(include={"device_id", "address", "encoding", "word_order", "scale", "table"})
        return ModbusJointSource(client, JointRegisterMap(**layout))

    def endpoint(self) -> str:
        """Where the joints are read, as a simulator announces the robot it serves."""
        return f"modbus-tcp {self.host}:{self.port}"


def _axis_template(text: str) -> str:
    if text and "{axis}" not in text:
        raise ValueError(f"{text!r}: write {{axis}} where the node id numbers the axis (1 .. 6)")
    return text


def _node_id(text: str) -> str:
    """``text`` (empty: none) if, ``{axis}`` read as 1 .. 6, asyncua parses it as node ids it can send."""
    for axis in range(1, 7) if text else ():
        _check_node_id(text.format(axis=axis))
    return text


def _check_node_id(text: str) -> None:
    from asyncua import ua  # here: only an OPC UA section pays for the import

    try:
        node = ua.NodeId.from_string(text)
    except ua.UaStringParsingError:
        raise ValueError(
            f"{text!r}: not an OPC UA node id (ns=<index>;i=<number>, ns=<index>;s=<name>, "
            "g=<guid> or b=<base64>)"
        ) from None
    if not 0 <= node.NamespaceIndex <= 0xFFFF:
        raise ValueError(f"{text!r}: namespace index {node.NamespaceIndex} is not within 0 .. 65535")
    if node.NodeIdType == ua.NodeIdType.Numeric and not 0 <= node.Identifier <= 0xFFFFFFFF:
        raise ValueError(f"{text!r}: numeric id {node.Identifier} is not within 0 .. 4294967295")


NodeTemplate = Annotated[
    str,
    Field(max_length=4096, pattern=r"^[^\x00{}]*(\{axis\}[^\x00{}]*)*$"),
    AfterValidator(_axis_template),
    AfterValidator(_node_id),
]
"""An OPC UA node id with ``{axis}`` for the axis number 1 .. 6, e.g.
``ns=2;s=DeviceSet/Robot/Axes/Axis{axis}/ParameterSet/ActualPosition``."""


AXIS_PARAMETERS = "ns=2;s=DeviceSet/Robot/Axes/Axis{axis}/ParameterSet"
"""Where ``station sim serve``'s OPC UA server puts each axis's parameters (the default node ids)."""


class RobotOpcUa(Section):
    """A controller's OPC UA server: the node ids of the axes' ``ActualPosition`` (the OPC UA
    Robotics companion specification's ``DeviceSet/<MotionDevice>/Axes/<Axis>/ParameterSet``) and
    ``ActualSpeed`` (empty: the change between reads), ``{axis}`` standing for 1 .. 6, in ``unit``
    (per second for speeds); the writable nodes a controller program reads corrected targets from
    (``target_node`` per axis, ``target_index_node``; either empty: no in-session correction);
    ``subscription_ms`` > 0: a sweep gets every sample the server publishes at that interval
    (a subscription) instead of polling (0)."""

    kind: Literal["opcua"]
    url: Annotated[str, Field(pattern=r"^opc\.tcp://[^\x00/]+(/[^\x00]*)?$")] = "opc.tcp://127.0.0.1:4840"
    position_node: Annotated[NodeTemplate, Field(min_length=1)] = f"{AXIS_PARAMETERS}/ActualPosition"
    speed_node: NodeTemplate = f"{AXIS_PARAMETERS}/ActualSpeed"
    unit: Literal["deg", "rad"] = "deg"
    timeout_s: Timeout = 1.0
    subscription_ms: float = Field(0.0, ge=0.0, le=10_000.0)
    target_node: NodeTemplate = f"{AXIS_PARAMETERS}/TargetPosition"
    target_index_node: Annotated[
        str, Field(max_length=4096, pattern=r"^[^\x00{}]*$"), AfterValidator(_node_id)
    ] = "ns=2;s=DeviceSet/Robot/TargetIndex"

    def nodes(self) -> tuple[list[str], list[str] | None]:
        """The six position node ids and the six speed node ids (None: no speed nodes)."""
        axes = range(1, 7)
        speeds = [self.speed_node.format(axis=i) for i in axes] if self.speed_node else None
        return [self.position_node.format(axis=i) for i in axes], speeds

    def build(self) -> Driver:
        from drivers.opcua import OpcUaJointSource

        targets = [self.target_node.format(axis=i) for i in range(1, 7)] if self.target_node else None
        return OpcUaJointSource(
            self.url,
            *self.nodes(),
            unit=self.unit,
            timeout_s=self.timeout_s,
            target_nodes=targets,
            target_index_node=self.target_index_node or None,
            subscription_ms=self.subscription_ms,
        )

    def endpoint(self) -> str:
        """Where the joints are read, as a simulator announces the robot it serves."""
        return f"opcua {self.url}"


class RobotRos(Section):
    """A ROS ``sensor_msgs/JointState`` topic through rosbridge (its WebSocket at ``host:port``),
    the six ``joint_names`` as the message names them, joint 1 first; ``target_topic``: where
    corrected targets are published for a measurement node (empty: no in-session correction)."""

    kind: Literal["ros"]
    host: Name = "127.0.0.1"
    port: int = Field(9090, gt=0, le=65535)
    topic: Annotated[str, Field(pattern=r"^/[A-Za-z0-9_/]*$")] = "/joint_states"
    target_topic: Annotated[str, Field(pattern=r"^(/[A-Za-z0-9_/]*)?$")] = "/station/target"
    joint_names: Annotated[list[Name], Field(min_length=6, max_length=6)] = [
        f"joint_{i}" for i in range(1, 7)
    ]
    timeout_s: Timeout = 2.0

    def build(self) -> Driver:
        from drivers.ros import RosJointSource

        return RosJointSource(
            self.host,
            self.port,
            self.topic,
            self.joint_names,
            timeout_s=self.timeout_s,
            target_topic=self.target_topic or None,
        )

    def endpoint(self) -> str:
        """Where the joints are read, as a simulator announces the robot it serves."""
        return f"ros ws://{self.host}:{self.port}{self.topic}"


RobotConfig = Annotated[RobotRtde | RobotModbusTcp | RobotOpcUa | RobotRos, Field(discriminator="kind")]


class Reconnect(Section):
    """Retries after a transient failure: ``attempts`` in all, waits growing from ``initial_s``
    by ``factor`` up to ``max_s`` (s)."""

    attempts: int = Field(4, ge=1, le=100)
    initial_s: float = Field(0.05, ge=0, le=60)
    factor: float = Field(2.0, ge=1, le=10)
    max_s: float = Field(1.0, ge=0, le=600)

    def backoff(self) -> Backoff:
        return Backoff(**self.model_dump())


def error_key(loc: tuple) -> str:
    """``drawstring.registers.address`` from a pydantic error location (union tags dropped)."""
    tags = {"rtde", "modbus_tcp", "modbus_rtu", "ascii", "opcua", "ros", "function-after", "function-wrap"}
    return ".".join(str(part) for part in loc if part not in tags) or "(top level)"
