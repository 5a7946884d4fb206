"""The simulated RTU cable (``sim_fixtures.serial_device.LinkedPtyPair``): a replug that comes
before the pump thread has pulled the cable (a busy machine: the fault soak's timer fires first)
still leaves it plugged. It once stayed pulled for good, and a guard-tier fault soak's session
suspended on "drawstring not answering" until it was killed at 240 s."""

from __future__ import annotations

import serial

from sim_fixtures.serial_device import LinkedPtyPair


def test_a_replug_before_the_pump_has_pulled_the_cable_leaves_it_plugged(tmp_path):
    cable = LinkedPtyPair(tmp_path / ".dev", tmp_path / "drawstring")  # the pump not started
    try:
        cable.unplug()
        cable.replug()  # the pump has not run: the pull is still pending
        cable._pump()  # now it runs
        assert cable.b.plugged and (tmp_path / "drawstring").exists()
        with (
            serial.Serial(str(tmp_path / "drawstring"), timeout=1) as station,
            serial.Serial(cable.a.path, timeout=1) as device,
        ):  # and bytes pass
            station.write(b"ping")
            cable._pump()
            assert device.read(4) == b"ping"
    finally:
        cable.a.unplug()
        cable.b.unplug()
