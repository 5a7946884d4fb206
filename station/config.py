"""The station's configuration file (``configs/station.toml``): devices, sessions, the simulator.

Device sections come from ``drivers.config``; the session's capture rule and the simulated cell's
settings live here. :func:`load_station_config` turns every problem into one ``InputError`` line
naming the file, the key and what is wrong.
"""

from __future__ import annotations

import sys
from pathlib import Path

from pydantic import BaseModel, ConfigDict, Field, ValidationError

from drivers.config import DialConfig, DrawstringConfig, Reconnect, RobotConfig, error_key
from errors import InputError

if sys.version_info >= (3, 11):
    import tomllib
else:  # pragma: no cover
    import tomli as tomllib


class _Section(BaseModel):
    model_config = ConfigDict(extra="forbid", frozen=True)


class SimConfig(_Section):
    """The simulated cell that ``station sim serve`` runs: world seed, robot program motion."""

    seed: int = 0
    speed_deg_s: float = Field(30.0, gt=0)
    accel_deg_s2: float = Field(60.0, gt=0)
    dwell_s: float = Field(3.0, ge=0)
    targets_per_line: int = Field(70, ge=2)  # the cell's plan: targets along each gauge line
    plan_csv: str = "/tmp/station-sim/plan.csv"  # sim serve publishes the plan it walks here


class SessionConfig(_Section):
    """``station sample``: what is calibrated (robot model and setup files, relative to this config
    or to the shipped ``configs/``) and the capture rule. Times are simulated seconds (divided by
    ``time_scale`` at the station), speeds as the controller reports them."""

    robot_model: str = "robots/hsr_jr680.toml"
    setup: str = "setups/sim.toml"
    plan: str = "/tmp/station-sim/plan.csv"  # the plan when `station sample` gets no --plan
    settle_speed_deg_s: float = Field(0.05, gt=0)  # every |qd| below this ...
    settle_s: float = Field(0.5, gt=0)  # ... for this long, robot mode RUNNING: settled
    readings: int = Field(5, ge=2)  # K readings of every device per capture
    window_s: float = Field(1.5, gt=0)  # all K rounds inside this synchronisation window
    still_deg: float = Field(0.005, gt=0)  # joint span during a capture: else "robot moved"
    jump_mm: float = Field(0.15, gt=0)  # drawstring span during a capture: else "sensor jumped"
    dial_range_mm: tuple[float, float] = (-2.0, 2.0)  # dial gate (in range to capture)
    dial_stable_mm: float = Field(0.02, gt=0)  # dial span during a capture (noise 0.002 mm)
    length_range_mm: tuple[float, float] = (50.0, 5000.0)  # drawstring outside: slack or jump
    match_deg: float = Field(2.0, gt=0)  # a settle this far (max |dq|) from every target is ignored
    target_timeout_s: float = Field(120.0, gt=0)  # no capture for this long: the session ends
    unreachable_s: float = Field(30.0, gt=0)  # real s a device may stay silent while suspended


class StationConfig(_Section):
    """``configs/station.toml``: one section per device, plus the shared ``time_scale``."""

    time_scale: float = Field(1.0, gt=0)
    session: SessionConfig = SessionConfig()
    robot: RobotConfig
    drawstring: DrawstringConfig
    dial: DialConfig | None = None
    reconnect: Reconnect = Reconnect()
    sim: SimConfig = SimConfig()

    def devices(self) -> dict[str, BaseModel]:
        """The configured device sections by name, robot first."""
        found = {"robot": self.robot, "drawstring": self.drawstring, "dial": self.dial}
        return {name: section for name, section in found.items() if section is not None}


def load_station_config(path: str | Path) -> StationConfig:
    """Read and validate a station config; any problem is an ``InputError`` naming file and key."""
    path = Path(path)
    try:
        raw = tomllib.loads(path.read_text())
    except OSError as exc:
        raise InputError(f"{path}: cannot read: {exc.strerror or exc}") from exc
    except tomllib.TOMLDecodeError as exc:
        raise InputError(f"{path}: not valid TOML: {exc}") from exc
    try:
        return StationConfig.model_validate(raw)
    except ValidationError as exc:
        err = exc.errors()[0]
        raise InputError(f"{path}: {error_key(err['loc'])}: {err['msg']}") from exc
