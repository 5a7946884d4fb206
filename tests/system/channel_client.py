"""A robot connection with its RTDE target channel open, as its own process, for
``tests/system/test_target_channels.py`` (ur_rtde aborting ends this process, not pytest's):

    python -m tests.system.channel_client HOST gone|frozen

It opens ``RtdeJointSource(HOST)``, reads, writes target 1 through the channel and prints
``open``; then waits for a line on stdin: the test has stopped the controller (``gone``) or frozen
it (``frozen``).

- ``gone``: reads until the link is lost, writes to the channel until that fails (at most 5
  tries), prints ``lost`` and waits for a line (the controller is back); then reads through
  ``call_with_reconnect`` and writes target 0 (``Q0``) through the channel the driver opens again.
- ``frozen``: reads until the stream is silent, then times ``close()``.

Its last line is a JSON object of what it saw; it closes the driver, drops everything and exits 0.
"""

from __future__ import annotations

import gc
import json
import sys
import time

from drivers.base import Backoff, DeviceTimeout, DeviceUnreachable, call_with_reconnect
from drivers.robot import RtdeJointSource

Q1 = [20.31, -39.87, -30.12, 5.21, -80.33, 10.47]
Q0 = [0.42, -50.11, -19.93, 0.17, -89.71, 0.25]


def read_until(source: RtdeJointSource, error: type[Exception], timeout_s: float) -> str:
    """Read until ``source.read()`` raises ``error``; its message."""
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        try:
            source.read()
        except error as exc:
            return str(exc)
        except DeviceTimeout:
            pass
        time.sleep(0.01)
    raise SystemExit(f"no {error.__name__} within {timeout_s} s")


def gone(source: RtdeJointSource) -> dict:
    seen = {"lost": read_until(source, DeviceUnreachable, 3.0)}
    channel = source.target_channel()
    for _ in range(5):  # the first write may still leave (the kernel's), the next meets the reset
        try:
            channel.write(1, Q1)
        except DeviceUnreachable as exc:
            seen["write"] = str(exc)
            break
        time.sleep(0.1)
    print("lost", flush=True)
    sys.stdin.readline()
    reading = call_with_reconnect(source, source.read, Backoff(attempts=10, initial_s=0.1, max_s=0.5))
    seen["robot_mode"] = reading.values["robot_mode"]
    channel = source.target_channel()
    seen["no_channel"] = source.no_channel
    if channel is not None:
        channel.write(0, Q0)
    return seen


def frozen(source: RtdeJointSource) -> dict:
    seen = {"silent": read_until(source, DeviceTimeout, 3.0)}
    t0 = time.monotonic()
    source.close()
    seen["close_s"] = time.monotonic() - t0
    return seen


def main(host: str, mode: str) -> None:
    source = RtdeJointSource(host, stale_s=0.3)
    source.open()
    source.read()
    source.target_channel().write(1, Q1)
    print("open", flush=True)
    sys.stdin.readline()
    seen = {"gone": gone, "frozen": frozen}[mode](source)
    source.close()
    del source
    gc.collect()  # whatever ur_rtde's destructors do, they do it now
    print(json.dumps(seen), flush=True)


if __name__ == "__main__":
    main(*sys.argv[1:3])
