"""Corrected targets handed to a running measurement program during a session.

Once the running calibration has determined the model, every judged refit corrects the plan's
targets (``station.jobs.correction``). The program (``station program``) moves through the plan in
order and, before it moves to a target, reads the robot controller's target channel (RTDE input
registers, OPC UA nodes, a ROS topic: ``drivers.base.TargetChannel``): if the channel names that
target, it moves to the joints there instead of the planned ones. So whenever the robot settles at a plan
target, the station writes the next unfinished target after it, corrected by the latest refit,
once per target; the first correction is written at once (the robot may be on its way already,
then that one arrives too late and the next is in time), before the robot has settled anywhere the
plan's first unfinished target (a program run again starts at the plan's beginning). A robot
without a channel (Modbus registers, ROS without a target topic, a controller that refuses the
inputs) is told once: the offline route corrects the remaining targets then.
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np

from drivers.base import DriverError, TargetChannel
from station.formats.plan import Plan
from station.jobs.correction import TargetCorrection

NO_CHANNEL = (
    "targets are not corrected in-session: the robot connection offers no target channel ({why}); "
    "where the tool lands off the edge, correct the remaining targets offline: station calibrate "
    "the session, station program the plan with --table (that table) and --session (this session), "
    "run that program and continue with station sample --resume"
)


class TargetFeed:
    """Corrected targets of ``plan`` for the program, written to the robot's ``channel()`` (None:
    none, because ``why()``); ``unfinished()`` gives the plan rows still to measure,
    ``message(text)`` tells the operator, ``note(text)`` only the session's log (the live view):
    each target written. ``sent``: each target id handed on, with the sample count of the refit
    its correction came from (0: it could not be corrected)."""

    def __init__(
        self,
        plan: Plan,
        channel: Callable[[], TargetChannel | None],
        why: Callable[[], str | None],
        unfinished: Callable[[], list[int]],
        message: Callable[[str], None],
        note: Callable[[str], None],
    ):
        self.plan, self.channel, self.why = plan, channel, why
        self.unfinished, self.message, self.note = unfinished, message, note
        self.correction: TargetCorrection | None = None
        self.at: int | None = None  # the plan row the robot last settled at
        self.sent: dict[int, int] = {}
        self.stopped = False  # a write failed: no more corrections this session

    def corrected(self, correction: TargetCorrection) -> None:
        """The latest refit's corrected targets: from now on the ones to hand on."""
        first, self.correction = self.correction is None, correction
        if first:
            channel = self.channel()
            if channel is None:
                self.message(NO_CHANNEL.format(why=self.why()))
                self.stopped = True
                return
            self.message(
                f"running calibration: correcting the remaining targets in-session (model of "
                f"{correction.n} samples) through {channel.where}"
            )
        self._next()

    def settled(self, index: int) -> None:
        """The robot settled at plan row ``index``: hand on the next unfinished target after it."""
        self.at = index
        self._next()

    def remedy(self, resume: str) -> str | None:
        """What to do about the targets left when the session times out, where the channel corrects
        them (None where it does not): ``resume`` is the command that continues."""
        if self.stopped or self.correction is None:
            return None
        left = self.unfinished()
        target = None if self.at is None else int(self.plan.target[self.at])
        if self.at in left and self.sent.get(target):  # standing at it, corrected, not measured
            return (
                f"target {target}'s corrected joints missed the edge too (model of {self.sent[target]} "
                "samples): calibrate what was measured (station calibrate) and follow its next step, or "
                "widen [session] dial_range_mm"
            )
        fixable = int(np.sum(self.correction.ok[left]))
        model = f"the model of {self.correction.n} samples"
        if not fixable:
            return (
                f"{model} cannot correct the {_targets(len(left))} left (station compensate says why, "
                "e.g. a joint limit): widen [session] dial_range_mm or calibrate without them"
            )
        which = (
            f"the {_targets(fixable)}" if fixable == len(left) else f"{fixable} of the {_targets(len(left))}"
        )
        return f"run the robot program again with {resume}: {model} corrects {which} left as it reaches them"

    def _next(self) -> None:
        """Write the next unfinished target after the one the robot is at (before it has settled
        anywhere: from the plan's beginning), once."""
        if self.stopped or self.correction is None:
            return
        at = -1 if self.at is None else self.at
        later = [i for i in self.unfinished() if i > at]
        if not later or int(self.plan.target[min(later)]) in self.sent:
            return
        index = min(later)
        target = int(self.plan.target[index])
        channel = self.channel()
        if channel is None:  # gone with a reconnect that the controller then refused: not now
            return
        if not self.correction.ok[index]:
            self.sent[target] = 0  # it keeps its planned joints, as the program's own
            self.note(f"target {target}: not corrected (station compensate says why); the planned joints")
            return
        try:
            channel.write(target, self.correction.q_deg[index])
        except DriverError as exc:
            self.message(f"{exc}; targets are no longer corrected in-session")
            self.stopped = True
            return
        say = self.note if any(self.sent.values()) else self.message  # the first one: the operator too
        self.sent[target] = self.correction.n
        say(
            f"target {target}: corrected target sent ({self.correction.shift_mm[index]:.2f} mm from the "
            f"planned contact, model of {self.correction.n} samples)"
        )


def _targets(n: int) -> str:
    return f"{n} target{'s' if n != 1 else ''}"
