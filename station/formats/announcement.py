"""What ``station sim serve`` announces beside the plan it publishes: ``simulator.toml`` in the
folder of ``[sim] plan_csv`` (``/tmp/station-sim/simulator.toml`` by default) names the robot it
simulates, its time scale and its process id, so that ``station sample`` on that robot runs at the
simulator's time scale or refuses a ``--time-scale`` that disagrees.

An announcement whose process is gone (a simulator killed without its clean-up) is stale and read
as none; ``sim serve`` removes its own when it stops.
"""

from __future__ import annotations

import os
from pathlib import Path
from typing import Annotated

from pydantic import Field

from errors import InputError
from station.formats.base import Strict, TimeScale, atomic_write, read_toml, toml_text, validate

FILE_NAME = "simulator.toml"


class Announcement(Strict):
    """A running simulator: the robot it serves (its ``[robot]`` section's ``endpoint()``), simulated
    seconds per real second, its process id, the robot model it simulates (its file's ``name``)."""

    robot: Annotated[str, Field(min_length=1)]
    time_scale: TimeScale
    pid: Annotated[int, Field(gt=0)]
    model: str | None = None  # the robot model simulated (its robot file's name)


def announcement_path(plan_csv: str | Path) -> Path:
    """Where a simulator publishing its plan at ``plan_csv`` announces itself."""
    return Path(plan_csv).parent / FILE_NAME


def announce(plan_csv: str | Path, robot: str, time_scale: float, model: str | None = None) -> Path:
    """Announce this process as the simulator of ``robot`` (a ``model``) at ``time_scale``; returns
    the file."""
    path = announcement_path(plan_csv)
    found = Announcement(robot=robot, time_scale=time_scale, pid=os.getpid(), model=model)
    atomic_write(path, toml_text(found.model_dump(exclude_none=True)))
    return path


def withdraw(plan_csv: str | Path) -> None:
    """Remove this process's announcement (one by another simulator stays)."""
    path = announcement_path(plan_csv)
    try:
        if read_toml(path).get("pid") == os.getpid():
            path.unlink()
    except (InputError, OSError):
        pass


def running_simulator(plan_csv: str | Path) -> Announcement | None:
    """The simulator announced beside ``plan_csv`` if its process still runs, else None. A file
    that is there but unreadable is an InputError naming it."""
    path = announcement_path(plan_csv)
    if not path.exists():
        return None
    found = validate(Announcement, read_toml(path), str(path))
    try:
        os.kill(found.pid, 0)
    except ProcessLookupError:
        return None
    except PermissionError:  # another user's process: it runs
        pass
    return found
