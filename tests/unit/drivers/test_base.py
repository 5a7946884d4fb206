"""The reconnect helper's schedule and which errors it retries (its use on real links is tested
against the simulated devices in test_drivers_dial / test_drivers_drawstring)."""

import pytest

from drivers.base import (
    MAX_JOINT_DEG,
    Backoff,
    CrcError,
    DeviceReplyError,
    DeviceTimeout,
    DeviceUnreachable,
    Driver,
    Field,
    Reading,
    call_with_reconnect,
)
from errors import DeviceError
from station.formats import base as formats


class Flaky(Driver):
    """Fails with the scripted errors in order, then reads; counts opens and closes."""

    name = "flaky"
    fields = {"x_mm": Field("mm")}

    def __init__(self, errors):
        self.errors = list(errors)
        self.opens = self.closes = 0

    def open(self):
        self.opens += 1

    def close(self):
        self.closes += 1

    def read(self):
        if self.errors:
            raise self.errors.pop(0)
        return Reading.now(self.name, {"x_mm": 1.5}, self.fields)


def test_backoff_delays_grow_and_saturate():
    assert list(Backoff(attempts=5, initial_s=0.1, factor=2, max_s=0.3).delays()) == [0.1, 0.2, 0.3, 0.3]
    with pytest.raises(ValueError, match="attempts"):
        Backoff(attempts=0)


def test_reconnect_retries_transient_errors_then_reads():
    waits = []
    dev = Flaky([DeviceTimeout("flaky", "no reply"), CrcError("flaky", "bad crc")])
    reading = call_with_reconnect(dev, dev.read, Backoff(attempts=3, initial_s=0.01), waits.append)
    assert reading.values == {"x_mm": 1.5} and reading.units == {"x_mm": "mm"}
    assert waits == [0.01, 0.02] and dev.opens == 2 and dev.closes == 2


def test_reconnect_gives_up_with_unreachable_naming_device_and_cause():
    dev = Flaky([DeviceTimeout("flaky", "no reply within 0.1 s")] * 3)
    with pytest.raises(DeviceUnreachable, match=r"flaky: unreachable after 3 attempts \(no reply"):
        call_with_reconnect(dev, dev.read, Backoff(attempts=3, initial_s=0), lambda s: None)


def test_device_error_code_is_not_retried():
    dev = Flaky([DeviceReplyError("flaky", "ERR3: out of range", code="3")])
    with pytest.raises(DeviceReplyError) as info:
        call_with_reconnect(dev, dev.read, Backoff(attempts=3), lambda s: None)
    assert info.value.code == "3" and dev.opens == 0
    assert isinstance(info.value, DeviceError)  # the CLI maps it to exit 1


def test_the_drivers_refuse_the_joint_readings_the_station_files_refuse():
    assert MAX_JOINT_DEG == formats.MAX_JOINT_DEG
