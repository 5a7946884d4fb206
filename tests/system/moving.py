"""A robot program that moves, served by a simulated joint source on a free loopback address: what
the OPC UA and ROS joint-source tests read."""

import random
import socket
import time

from drivers.base import RETRYABLE
from sim_fixtures.robot_program import SimRobot


def free_address() -> tuple[str, int]:
    """A free port on a random 127.0.0.x (other tests may serve on 127.0.0.1 at the same time)."""
    host = f"127.0.0.{random.SystemRandom().randint(2, 250)}"
    with socket.socket() as s:
        s.bind((host, 0))
        return host, s.getsockname()[1]


def two_targets(dwell_s: float):
    """A program between two targets (30 deg/s), the monotonic time it started, and its state now
    as a source serves it: ``state() -> (q_deg, qd_deg_s)``."""
    robot = SimRobot(
        [[0.0] * 6, [90.0, -45, 30, 10, 20, 60]], speed_deg_s=30.0, accel_deg_s2=60.0, dwell_s=dwell_s
    )
    t0 = time.monotonic()

    def state():
        s = robot.state(time.monotonic() - t0)
        return s.q_deg, s.qd_deg_s

    return robot, t0, state


def fails_retryably(source) -> bool:
    """Whether reading ``source`` (opened, its server stopped) raises a retryable error within 50
    reads 0.05 s apart, as a session's device loop needs to reconnect rather than give up."""
    try:
        for _ in range(50):
            source.read()
            time.sleep(0.05)
    except RETRYABLE:
        return True
    finally:
        source.close()
    return False
