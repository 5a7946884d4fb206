"""The RTDE wire format (protocol version 2), as the controller side writes and reads it.

Every package is ``uint16 size | uint8 type | payload``, big-endian, where ``size`` counts the
3-byte header too (UR's RTDE guide, "Protocol"; the same layout as ``ur_rtde``'s ``RTDE::sendAll``
and UR's Python client ``serialize.ControlHeader``: ``>HB``). The package types are ASCII letters.

Controller replies to the client's requests:

======  ===============================  =====================================================
type    client sends                     controller answers
======  ===============================  =====================================================
``V``   ``uint16 protocol_version``      ``uint8 accepted`` (1 / 0)
``v``   nothing                          ``uint32 major, minor, bugfix, build``
``O``   ``double frequency_hz`` + names  ``uint8 recipe_id`` + comma-separated type names
        (comma-separated, ASCII)         (``NOT_FOUND`` for a name the controller lacks)
``I``   names (comma-separated, ASCII)   ``uint8 recipe_id`` (0: refused) + the type names
                                         (``NOT_FOUND``; ``IN_USE``: another client writes it)
``S``   nothing                          ``uint8 accepted``
``P``   nothing                          ``uint8 accepted``
``U``   (either way: outputs from the     ``uint8 recipe_id`` + the recipe's values packed in
        controller, inputs from a client)
                                         order: DOUBLE ``d``, INT32 ``i``, UINT32 ``I``,
                                         UINT64 ``Q``, VECTOR6D ``6d``, VECTOR3D ``3d``,
                                         VECTOR6INT32 ``6i``, VECTOR6UINT32 ``6I``
``M``   either way                       ``uint8 len, message, uint8 len, source, uint8 level``
======  ===============================  =====================================================

This module only packs and parses bytes; the server that uses it is
:mod:`sim_fixtures.rtde_server`.
"""

from __future__ import annotations

import struct
from collections.abc import Mapping, Sequence
from dataclasses import dataclass

HEADER = struct.Struct(">HB")
HEADER_SIZE = HEADER.size  # 3 bytes

REQUEST_PROTOCOL_VERSION = ord("V")
GET_URCONTROL_VERSION = ord("v")
TEXT_MESSAGE = ord("M")
DATA_PACKAGE = ord("U")
SETUP_OUTPUTS = ord("O")
SETUP_INPUTS = ord("I")
START = ord("S")
PAUSE = ord("P")

PROTOCOL_VERSION = 2
NOT_FOUND = "NOT_FOUND"
IN_USE = "IN_USE"

#: struct format of each RTDE data type (without the byte-order prefix).
TYPE_FORMATS: dict[str, str] = {
    "DOUBLE": "d",
    "INT32": "i",
    "UINT32": "I",
    "UINT64": "Q",
    "UINT8": "B",
    "BOOL": "?",
    "VECTOR3D": "3d",
    "VECTOR6D": "6d",
    "VECTOR6INT32": "6i",
    "VECTOR6UINT32": "6I",
}

#: Output fields this controller offers and their RTDE types (UR's RTDE guide, "Controller
#: outputs"). It covers ur_rtde's RTDEReceiveInterface default recipe; anything else is NOT_FOUND.
OUTPUT_TYPES: dict[str, str] = {
    "timestamp": "DOUBLE",
    "target_q": "VECTOR6D",
    "target_qd": "VECTOR6D",
    "target_qdd": "VECTOR6D",
    "target_current": "VECTOR6D",
    "target_moment": "VECTOR6D",
    "actual_q": "VECTOR6D",
    "actual_qd": "VECTOR6D",
    "actual_current": "VECTOR6D",
    "joint_control_output": "VECTOR6D",
    "actual_TCP_pose": "VECTOR6D",
    "actual_TCP_speed": "VECTOR6D",
    "actual_TCP_force": "VECTOR6D",
    "target_TCP_pose": "VECTOR6D",
    "target_TCP_speed": "VECTOR6D",
    "actual_digital_input_bits": "UINT64",
    "joint_temperatures": "VECTOR6D",
    "actual_execution_time": "DOUBLE",
    "robot_mode": "INT32",
    "joint_mode": "VECTOR6INT32",
    "safety_mode": "INT32",
    "actual_tool_accelerometer": "VECTOR3D",
    "speed_scaling": "DOUBLE",
    "target_speed_fraction": "DOUBLE",
    "actual_momentum": "DOUBLE",
    "actual_main_voltage": "DOUBLE",
    "actual_robot_voltage": "DOUBLE",
    "actual_robot_current": "DOUBLE",
    "actual_joint_voltage": "VECTOR6D",
    "actual_digital_output_bits": "UINT64",
    "runtime_state": "UINT32",
    "robot_status_bits": "UINT32",
    "safety_status_bits": "UINT32",
    "standard_analog_input0": "DOUBLE",
    "standard_analog_input1": "DOUBLE",
    "standard_analog_output0": "DOUBLE",
    "standard_analog_output1": "DOUBLE",
    "output_bit_registers0_to_31": "UINT32",
    "output_bit_registers32_to_63": "UINT32",
    **{f"output_int_register_{i}": "INT32" for i in range(48)},
    **{f"output_double_register_{i}": "DOUBLE" for i in range(48)},
}


#: Input fields a client may write and their RTDE types (UR's RTDE guide, "Controller inputs"):
#: what ur_rtde's RTDEIOInterface sets up, and the general purpose registers.
INPUT_TYPES: dict[str, str] = {
    "standard_digital_output_mask": "UINT8",
    "standard_digital_output": "UINT8",
    "configurable_digital_output_mask": "UINT8",
    "configurable_digital_output": "UINT8",
    "tool_digital_output_mask": "UINT8",
    "tool_digital_output": "UINT8",
    "speed_slider_mask": "UINT32",
    "speed_slider_fraction": "DOUBLE",
    "standard_analog_output_mask": "UINT8",
    "standard_analog_output_type": "UINT8",
    "standard_analog_output_0": "DOUBLE",
    "standard_analog_output_1": "DOUBLE",
    "input_bit_registers0_to_31": "UINT32",
    "input_bit_registers32_to_63": "UINT32",
    **{f"input_int_register_{i}": "INT32" for i in range(48)},
    **{f"input_double_register_{i}": "DOUBLE" for i in range(48)},
}


class WireError(ValueError):
    """Bytes that are not a well-formed RTDE package."""


@dataclass(frozen=True)
class Package:
    """One package: its type letter's code and its payload (header stripped)."""

    kind: int
    payload: bytes


def pack(kind: int, payload: bytes = b"") -> bytes:
    """Header + payload; the size field counts the header."""
    size = HEADER_SIZE + len(payload)
    if size > 0xFFFF:
        raise WireError(f"package of {size} bytes exceeds the 16-bit size field")
    return HEADER.pack(size, kind) + payload


def split(buffer: bytes) -> tuple[list[Package], bytes]:
    """Whole packages at the front of ``buffer`` and the incomplete rest."""
    packages = []
    offset = 0
    while len(buffer) - offset >= HEADER_SIZE:
        size, kind = HEADER.unpack_from(buffer, offset)
        if size < HEADER_SIZE:
            raise WireError(f"package size {size} is smaller than its {HEADER_SIZE}-byte header")
        if len(buffer) - offset < size:
            break
        packages.append(Package(kind, bytes(buffer[offset + HEADER_SIZE : offset + size])))
        offset += size
    return packages, bytes(buffer[offset:])


def parse_protocol_request(payload: bytes) -> int:
    """The protocol version a ``V`` request asks for (``uint16``)."""
    if len(payload) != 2:
        raise WireError(f"V request carries {len(payload)} bytes, expected 2 (uint16 version)")
    return struct.unpack(">H", payload)[0]


def parse_setup_outputs(payload: bytes) -> tuple[float, list[str]]:
    """Frequency (Hz) and variable names of an ``O`` request (v2: ``double`` then names).

    ur_rtde ends the name list with a comma; empty names are dropped.
    """
    if len(payload) < 8:
        raise WireError(f"O request carries {len(payload)} bytes, expected a double frequency")
    (frequency,) = struct.unpack_from(">d", payload)
    names = [n for n in payload[8:].decode("ascii").split(",") if n]
    return frequency, names


def bool_reply(kind: int, accepted: bool) -> bytes:
    """Answer to ``V``, ``S`` or ``P``: one ``uint8`` success flag."""
    return pack(kind, struct.pack(">B", int(accepted)))


def version_reply(major: int, minor: int, bugfix: int, build: int) -> bytes:
    """Answer to ``v``: four ``uint32``."""
    return pack(GET_URCONTROL_VERSION, struct.pack(">IIII", major, minor, bugfix, build))


def output_types(names: Sequence[str]) -> list[str]:
    """RTDE type of each name, ``NOT_FOUND`` for names this controller does not offer."""
    return [OUTPUT_TYPES.get(n, NOT_FOUND) for n in names]


def parse_setup_inputs(payload: bytes) -> list[str]:
    """Variable names of an ``I`` request (comma-separated; empty names dropped)."""
    return [n for n in payload.decode("ascii", errors="replace").split(",") if n]


def input_types(names: Sequence[str]) -> list[str]:
    """RTDE type of each input name, ``NOT_FOUND`` for names this controller does not take."""
    return [INPUT_TYPES.get(n, NOT_FOUND) for n in names]


def setup_inputs_reply(recipe_id: int, types: Sequence[str]) -> bytes:
    """Answer to ``I``: the recipe id (0: refused) and the types, comma-separated."""
    return pack(SETUP_INPUTS, struct.pack(">B", recipe_id) + ",".join(types).encode("ascii"))


def setup_outputs_reply(recipe_id: int, types: Sequence[str]) -> bytes:
    """Answer to ``O``: the recipe id and the types, comma-separated."""
    return pack(SETUP_OUTPUTS, struct.pack(">B", recipe_id) + ",".join(types).encode("ascii"))


def data_format(types: Sequence[str]) -> struct.Struct:
    """Packing of a ``U`` payload for a recipe: ``uint8`` recipe id, then each value."""
    try:
        return struct.Struct(">B" + "".join(TYPE_FORMATS[t] for t in types))
    except KeyError as exc:
        raise WireError(f"no data format for RTDE type {exc.args[0]}") from None


def item_count(rtde_type: str) -> int:
    """How many numbers a value of this type holds: 6, 3 or 1."""
    if rtde_type.startswith("VECTOR"):
        return 6 if rtde_type.startswith("VECTOR6") else 3
    return 1


def flatten(types: Sequence[str], values: Sequence[object]) -> list:
    """Values in wire order, vectors expanded (their length checked against the type)."""
    flat = []
    for t, v in zip(types, values, strict=True):
        if t.startswith("VECTOR"):
            n = item_count(t)
            if len(v) != n:
                raise WireError(f"{t} needs {n} values, got {len(v)}")
            flat.extend(v)
        else:
            flat.append(v)
    return flat


def data_package(recipe_id: int, fmt: struct.Struct, types: Sequence[str], values: Sequence[object]) -> bytes:
    """A ``U`` package of one recipe (``fmt`` from :func:`data_format` on ``types``)."""
    return pack(DATA_PACKAGE, fmt.pack(recipe_id, *flatten(types, values)))


def text_message(message: str, source: str, level: int) -> bytes:
    """An ``M`` package (v2 layout); levels 0 exception, 1 error, 2 warning, 3 info."""
    m, s = message.encode("utf-8"), source.encode("utf-8")
    return pack(TEXT_MESSAGE, struct.pack(f">B{len(m)}sB{len(s)}sB", len(m), m, len(s), s, level))


def unpack_data(payload: bytes, fmt: struct.Struct, types: Sequence[str]) -> tuple[int, dict]:
    """Recipe id and values (by position) of a ``U`` payload; the inverse of :func:`data_package`.

    Returns the recipe id and a dict position -> value (tuples for vectors).
    """
    flat = fmt.unpack(payload)
    values, i = {}, 1
    for k, t in enumerate(types):
        n = item_count(t)
        values[k] = tuple(flat[i : i + n]) if t.startswith("VECTOR") else flat[i]
        i += n
    return flat[0], values


def zero_value(rtde_type: str) -> object:
    """The value a field this simulator does not model carries: zeros of the right shape."""
    return (0,) * item_count(rtde_type) if rtde_type.startswith("VECTOR") else 0


def values_for(names: Sequence[str], types: Sequence[str], modelled: Mapping[str, object]) -> list:
    """Values of a recipe: modelled ones by name, zeros for the rest."""
    return [modelled.get(n, zero_value(t)) for n, t in zip(names, types, strict=True)]
