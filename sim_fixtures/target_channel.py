"""Corrected targets a station hands a running robot program, as the simulated controller keeps them.

A real controller keeps the last value written to each of its inputs (RTDE input registers, OPC UA
nodes); its program reads them before it moves to a target. The simulated program is computed for
any instant it is asked about (``SimRobot.state``), possibly after the fact and in several processes
(the RTDE server's child, the sensors' parent), so the channel keeps a short history of the writes,
each stamped with the program time it arrived at: what the channel held when a move began is then
the same whoever asks, and whenever. The history lives in shared memory (a ``multiprocessing``
array of the spawn context), so a spawned RTDE server writes what the parent's program reads.
"""

from __future__ import annotations

import multiprocessing
from dataclasses import dataclass
from typing import Any

import numpy as np

SLOTS = 64  # writes kept: a program asks about a move's start within a few writes of it
_ROW = 8  # target id, program time [s], six joints [deg]


class TargetChannel:
    """The writes of (target id, joints [deg]) at program times [s], the last ``SLOTS`` of them."""

    def __init__(self):
        self._data = multiprocessing.get_context("spawn").Array("d", 1 + SLOTS * _ROW)

    def write(self, target: int, q_deg, at_s: float) -> None:
        """Target ``target``'s corrected joints ``q_deg`` (6,) [deg], written at program time ``at_s``."""
        with self._data.get_lock():
            count = int(self._data[0])
            start = 1 + (count % SLOTS) * _ROW
            self._data[start : start + _ROW] = [float(target), float(at_s), *map(float, q_deg)]
            self._data[0] = count + 1

    def at(self, at_s: float) -> tuple[int, np.ndarray] | None:
        """What the channel held at program time ``at_s``: the last write up to then (target id,
        joints (6,) [deg]), None before the first."""
        with self._data.get_lock():
            count = int(self._data[0])
            rows = np.array(self._data[1:]).reshape(SLOTS, _ROW)
        kept = [rows[k % SLOTS] for k in range(max(0, count - SLOTS), count)]
        before = [row for row in kept if row[1] <= at_s]
        if not before:
            return None
        last = max(before, key=lambda row: row[1])
        return int(last[0]), last[2:].copy()


@dataclass(frozen=True)
class TargetInbox:
    """The controller's side of a channel: each corrected target written to its inputs, stamped
    with the program time of ``robot`` (``program_time``, ``time_scale``) on ``clock`` (``now()``,
    real s since the program started). Picklable: a spawned RTDE server gets its own copy."""

    channel: TargetChannel
    robot: Any  # sim_fixtures.robot_program.SimRobot
    clock: Any  # sim_fixtures.sources.SimClock

    def __call__(self, target: int, q_deg) -> None:
        self.channel.write(target, q_deg, self.robot.program_time(self.clock.now() * self.robot.time_scale))
