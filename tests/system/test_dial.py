"""Dial indicator driver: byte-exact dialect frames, then behaviour and faults against the
simulated indicator on a real pty, through pyserial."""

import threading

import numpy as np
import pytest
import serial

from drivers.ascii import DIALECTS
from drivers.base import (
    Backoff,
    DeviceReplyError,
    DeviceTimeout,
    DeviceUnreachable,
    GarbledReply,
    call_with_reconnect,
)
from drivers.dial import DialIndicator
from sim_fixtures.serial_device import SerialAsciiDevice
from sim_fixtures.world import Noise
from tests.system.serial_script import ScriptedSerial

TIMEOUT_S = 0.2


def dial_on(link, dialect="sylvac"):
    port = serial.serial_for_url(str(link), do_not_open=True, timeout=TIMEOUT_S, exclusive=True)
    return DialIndicator(port, dialect)


@pytest.mark.parametrize(
    "dialect, request_bytes, reply, value",
    [
        ("sylvac", b"?\r", b"+0012.345\r", 12.345),
        ("sylvac", b"?\r", b"-0000.007\r", -0.007),
        ("mitutoyo", b"R\r", b"01A+0000.123\r", 0.123),
        ("mitutoyo", b"R\r", b"01A-0003.210\r", -3.21),
    ],
)
def test_dialect_frames_byte_exact(tmp_path, dialect, request_bytes, reply, value):
    with ScriptedSerial(tmp_path / "dial", [(request_bytes, reply)]) as dev:
        with dial_on(tmp_path / "dial", dialect) as dial:
            reading = dial.read()
    assert dev.received == [request_bytes]
    assert reading.values == {"dial_mm": pytest.approx(value, abs=1e-12)}
    assert reading.units == {"dial_mm": "mm"} and reading.device == "dial"


@pytest.mark.parametrize(
    "dialect, reply, error, match",
    [
        ("sylvac", b"ERR3\r", DeviceReplyError, r"dial: device error 'ERR3'"),
        ("mitutoyo", b"913\r", DeviceReplyError, r"dial: device error '913'"),
        ("sylvac", b"+12.3\r", GarbledReply, r"dial: unparseable reply b'\+12.3'"),
        ("mitutoyo", b"+0000.123\r", GarbledReply, r"dial: unparseable reply"),  # no header
        ("sylvac", b"+0012.3", DeviceTimeout, r"dial: incomplete reply b'\+0012.3' within 0.2 s"),
        ("sylvac", b"", DeviceTimeout, r"dial: no reply within 0.2 s"),
    ],
)
def test_dialect_error_frames_raise_named_errors(tmp_path, dialect, reply, error, match):
    request_bytes = DIALECTS[dialect].request
    with ScriptedSerial(tmp_path / "dial", [(request_bytes, reply)]):
        with dial_on(tmp_path / "dial", dialect) as dial, pytest.raises(error, match=match):
            dial.read()


def test_error_code_is_kept(tmp_path):
    with ScriptedSerial(tmp_path / "dial", [(b"?\r", b"ERR3\r")]):
        with dial_on(tmp_path / "dial") as dial, pytest.raises(DeviceReplyError) as info:
            dial.read()
    assert info.value.code == "3"


def test_unknown_dialect_is_refused(tmp_path):
    with pytest.raises(ValueError, match="dial dialect must be one of"):
        dial_on(tmp_path / "dial", "keyence")


@pytest.fixture(params=["sylvac", "mitutoyo"])
def sim_dial(request, tmp_path):
    """The simulated indicator at a true 0.5 mm, sigma 2 um, 1 um resolution, range +-12.5 mm."""
    noise = Noise().dial(np.random.default_rng(7))
    link = tmp_path / "dial"
    with SerialAsciiDevice(
        link, DIALECTS[request.param], lambda: noise.measure(0.5), range_mm=(-12.5, 12.5)
    ) as dev:
        yield dev, dial_on(link, request.param)


def test_reads_the_simulated_indicator_with_its_noise(sim_dial):
    dev, dial = sim_dial
    with dial:
        values = np.array([dial.read().values["dial_mm"] for _ in range(200)])
    assert dev.requests == 200
    assert abs(values.mean() - 0.5) < 0.001  # 4 sigma of the mean of 200
    assert 0.0012 < values.std() < 0.0030
    assert np.allclose(values, np.round(values, 3))  # 1 um resolution on the wire


def test_simulated_faults_give_named_errors_then_recover(sim_dial):
    dev, dial = sim_dial
    with dial:
        for fault, error in [
            ("error", DeviceReplyError),
            ("garbled", GarbledReply),
            ("silence", DeviceTimeout),
            ("unplug", DeviceUnreachable),
        ]:
            dev.faults.inject(fault)
            with pytest.raises(error, match="^dial: "):
                dial.read()
        dev.replug()
        dial.open()
        assert abs(dial.read().values["dial_mm"] - 0.5) < 0.02


def test_out_of_travel_reads_err3(tmp_path):
    with SerialAsciiDevice(tmp_path / "dial", DIALECTS["sylvac"], lambda: 13.0, (-12.5, 12.5)):
        with dial_on(tmp_path / "dial") as dial, pytest.raises(DeviceReplyError, match="ERR3"):
            dial.read()


def test_reconnect_rides_through_an_unplug(sim_dial):
    dev, dial = sim_dial
    dev.faults.inject("unplug")
    replug = threading.Timer(0.15, dev.replug)
    with dial:
        replug.start()
        reading = call_with_reconnect(dial, dial.read, Backoff(attempts=6, initial_s=0.05))
    replug.join()
    assert abs(reading.values["dial_mm"] - 0.5) < 0.02


def test_reconnect_gives_up_when_the_indicator_stays_away(sim_dial):
    dev, dial = sim_dial
    dev.faults.inject("unplug")
    with dial, pytest.raises(DeviceUnreachable, match=r"^dial: unreachable after 3 attempts"):
        call_with_reconnect(dial, dial.read, Backoff(attempts=3, initial_s=0.01))
