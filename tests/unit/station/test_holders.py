"""A device refused because another process holds its serial port names that process (issue 20,
item 3), instead of asking whether `station sim serve` runs."""

import subprocess
import sys

from drivers.base import DeviceUnreachable
from station.config import UNREACHABLE_HINT, StationConfig, unreachable_hint
from tests.hostile_inputs import absent_devices

HOLD = """
import fcntl, sys
port = open(sys.argv[1], "a")
fcntl.flock(port, fcntl.LOCK_EX)  # as pyserial's exclusive open does
print("held", flush=True)
sys.stdin.read()
"""


def test_the_hint_names_the_process_holding_the_dial_port(tmp_path):
    port = tmp_path / "dial"
    port.write_text("")
    cfg = StationConfig.model_validate({**absent_devices(), "dial": {"port": str(port)}})
    locked = DeviceUnreachable("dial", f"cannot open {port}: Could not exclusively lock port {port}")
    assert unreachable_hint(cfg, locked) == f"{port} is held by another process"  # none found
    holder = subprocess.Popen(
        [sys.executable, "-c", HOLD, str(port)], stdin=subprocess.PIPE, stdout=subprocess.PIPE, text=True
    )
    try:
        assert holder.stdout.readline() == "held\n"
        hint = unreachable_hint(cfg, locked)
    finally:
        holder.communicate("", timeout=10)
    assert hint.startswith(f"{port} is held by PID {holder.pid} ({sys.executable} -c import fcntl, sys")
    drawstring = DeviceUnreachable("drawstring", "unreachable after 2 attempts (connection refused)")
    assert unreachable_hint(cfg, drawstring) == UNREACHABLE_HINT
