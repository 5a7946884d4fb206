"""Drawstring drivers: byte-exact Modbus RTU and ASCII frames on a pty, then behaviour and faults
against the simulated sensor through the real pymodbus clients (TCP and RTU) and pyserial."""

import threading

import numpy as np
import pytest
import serial
from pymodbus.client import ModbusSerialClient, ModbusTcpClient

from drivers.ascii import DIALECTS
from drivers.base import (
    Backoff,
    CrcError,
    DeviceReplyError,
    DeviceTimeout,
    DeviceUnreachable,
    GarbledReply,
    call_with_reconnect,
)
from drivers.drawstring import AsciiDrawstring, ModbusDrawstring, RegisterMap
from sim_fixtures.modbus_device import ModbusDevice
from sim_fixtures.serial_device import SerialAsciiDevice
from sim_fixtures.world import Noise
from tests.system.serial_script import ScriptedSerial

TIMEOUT_S = 0.3
H = bytes.fromhex
DEFAULT_MAP = RegisterMap()


def rtu_driver(link, registers=DEFAULT_MAP):
    client = ModbusSerialClient(str(link), baudrate=115200, timeout=TIMEOUT_S, retries=0)
    return ModbusDrawstring(client, registers)


# Frames as a Modbus manual writes them: id, function, data, CRC-16 (low byte first).
@pytest.mark.parametrize(
    "registers, request_frame, reply, length_mm",
    [
        # read 2 holding registers at 0 from device 1: 0x0001E240 um = 123.456 mm
        (RegisterMap(), H("01 03 00 00 00 02 c4 0b"), H("01 03 04 00 01 e2 40 e2 a3"), 123.456),
        # a negative INT32: 0xFFFFF63C = -2500 um
        (RegisterMap(), H("01 03 00 00 00 02 c4 0b"), H("01 03 04 ff ff f6 3c bd a6"), -2.5),
        # FLOAT32 mm, low word first, device 5, register 100: 0x449A5000 = 1234.5
        (
            RegisterMap(address=100, encoding="float32_mm", word_order="little", device_id=5),
            H("05 03 00 64 00 02 84 50"),
            H("05 03 04 50 00 44 9a 1d 98"),
            1234.5,
        ),
        # same INT32 with a scale of 2 (e.g. a 2:1 cable pulley)
        (RegisterMap(scale=2.0), H("01 03 00 00 00 02 c4 0b"), H("01 03 04 00 01 e2 40 e2 a3"), 246.912),
    ],
)
def test_rtu_frames_byte_exact(tmp_path, registers, request_frame, reply, length_mm):
    with ScriptedSerial(tmp_path / "ds", [(request_frame, reply)]) as dev:
        with rtu_driver(tmp_path / "ds", registers) as drawstring:
            reading = drawstring.read()
    assert dev.received == [request_frame]
    assert reading.values["length_mm"] == pytest.approx(length_mm, abs=1e-9)
    assert reading.units == {"length_mm": "mm"}


def test_rtu_exception_frame_is_a_device_error(tmp_path):
    regs = RegisterMap(address=100, device_id=5)
    script = [(H("05 03 00 64 00 02 84 50"), H("05 83 02 81 30"))]  # exception 2: bad address
    with ScriptedSerial(tmp_path / "ds", script), rtu_driver(tmp_path / "ds", regs) as ds:
        with pytest.raises(DeviceReplyError, match="drawstring: Modbus exception code 2") as info:
            ds.read()
    assert info.value.code == "2"


def test_rtu_bad_crc_raises_crc_error(tmp_path):
    script = [(H("01 03 00 00 00 02 c4 0b"), H("01 03 04 00 01 e2 40 e2 a4"))]  # CRC a3 -> a4
    with ScriptedSerial(tmp_path / "ds", script), rtu_driver(tmp_path / "ds") as ds:
        with pytest.raises(CrcError, match="drawstring: bad CRC in reply 01 03 04 00 01 e2 40"):
            ds.read()


def test_rtu_silence_is_a_timeout(tmp_path):
    with ScriptedSerial(tmp_path / "ds", [(H("01 03 00 00 00 02 c4 0b"), b"")]):
        with rtu_driver(tmp_path / "ds") as ds, pytest.raises(DeviceTimeout, match="0.3 s"):
            ds.read()


def test_ascii_frames_byte_exact(tmp_path):
    script = [(b"M\r\n", b"L+01234.567\r\n"), (b"M\r\n", b"E3\r\n")]
    port = serial.serial_for_url(str(tmp_path / "ds"), do_not_open=True, timeout=TIMEOUT_S)
    with ScriptedSerial(tmp_path / "ds", script) as dev, AsciiDrawstring(port) as ds:
        assert ds.read().values == {"length_mm": 1234.567}
        with pytest.raises(DeviceReplyError, match="drawstring: device error 'E3'"):
            ds.read()
    assert dev.received == [b"M\r\n", b"M\r\n"]


# ---- against the simulated sensor ----------------------------------------------------------

TRUE_MM = 1234.5


@pytest.fixture(params=["tcp", "rtu"])
def sim_modbus(request, tmp_path):
    """Simulated drawstring at a true 1234.5 mm, sigma 20 um, INT32 um at register 10, id 3."""
    regs = RegisterMap(address=10, device_id=3)
    noise = Noise().drawstring(np.random.default_rng(11))
    transport = {"tcp": ("127.0.0.1", 0)} if request.param == "tcp" else {"rtu_link": tmp_path / "ds-rtu"}
    with ModbusDevice(regs, lambda: noise.measure(TRUE_MM), **transport) as dev:
        if request.param == "tcp":
            client = ModbusTcpClient("127.0.0.1", port=dev.address["port"], timeout=TIMEOUT_S, retries=0)
        else:
            client = ModbusSerialClient(dev.address["port"], baudrate=115200, timeout=TIMEOUT_S, retries=0)
        yield dev, ModbusDrawstring(client, regs)


def test_reads_the_simulated_sensor_with_its_noise(sim_modbus):
    dev, ds = sim_modbus
    with ds:
        values = np.array([ds.read().values["length_mm"] for _ in range(100)])
    assert dev.requests == 100
    assert abs(values.mean() - TRUE_MM) < 0.01  # 5 sigma of the mean of 100
    assert 0.012 < values.std() < 0.03
    assert np.allclose(values * 1000, np.round(values * 1000), atol=1e-6)  # 1 um steps


@pytest.mark.parametrize(
    "fault, error, match",
    [
        ("error", DeviceReplyError, "Modbus exception code 4"),
        ("garbled", GarbledReply, "unparseable reply"),
        ("silence", DeviceTimeout, "no reply from"),
        ("unplug", DeviceUnreachable, "link lost"),
    ],
)
def test_simulated_faults_give_named_errors_then_reconnect(sim_modbus, fault, error, match):
    dev, ds = sim_modbus
    with ds:
        dev.faults.inject(fault)
        with pytest.raises(error, match=f"^drawstring: {match}"):
            ds.read()
        if fault == "unplug" and dev.cable:
            threading.Timer(0.1, dev.cable.replug).start()
        reading = call_with_reconnect(ds, ds.read, Backoff(attempts=6, initial_s=0.05))
    assert abs(reading.values["length_mm"] - TRUE_MM) < 0.2


def test_simulated_crc_corruption_on_the_rtu_line(tmp_path):
    regs = RegisterMap()
    with ModbusDevice(regs, lambda: 500.0, rtu_link=tmp_path / "ds") as dev:
        with rtu_driver(tmp_path / "ds", regs) as ds:
            dev.faults.inject("crc")
            with pytest.raises(CrcError, match="^drawstring: bad CRC in reply 01 03 04"):
                ds.read()
            assert ds.read().values == {"length_mm": 500.0}


def test_tcp_sensor_that_stays_away_is_unreachable():
    with ModbusDevice(RegisterMap(), lambda: 1.0, tcp=("127.0.0.1", 0)) as dev:
        port = dev.address["port"]
    ds = ModbusDrawstring(ModbusTcpClient("127.0.0.1", port=port, timeout=TIMEOUT_S, retries=0))
    with pytest.raises(DeviceUnreachable, match="^drawstring: unreachable after 3 attempts"):
        call_with_reconnect(ds, ds.open, Backoff(attempts=3, initial_s=0.01))


def test_ascii_drawstring_against_the_simulated_sensor(tmp_path):
    noise = Noise().drawstring(np.random.default_rng(3))
    link = tmp_path / "ds"
    with SerialAsciiDevice(link, DIALECTS["drawstring"], lambda: noise.measure(TRUE_MM)) as dev:
        port = serial.serial_for_url(str(link), do_not_open=True, timeout=TIMEOUT_S)
        with AsciiDrawstring(port) as ds:
            values = [ds.read().values["length_mm"] for _ in range(50)]
            dev.faults.inject("garbled")
            with pytest.raises(GarbledReply, match="^drawstring: "):
                ds.read()
    assert abs(np.mean(values) - TRUE_MM) < 0.015 and np.std(values) > 0.005
