"""The station's configuration file (``configs/station.toml``): devices, sessions, the simulator.

Device sections come from ``drivers.config``; the session's capture rule and the simulated cell's
settings live here. :func:`load_station_config` turns every problem into one ``InputError`` line
naming the file, the key and what is wrong.
"""

from __future__ import annotations

from pathlib import Path
from typing import Annotated, Literal

from pydantic import AfterValidator, Field, TypeAdapter, ValidationError, model_validator

import configs
from calib.params import DH_NAMES
from drivers.base import Driver
from drivers.config import (
    DialConfig,
    DrawstringConfig,
    Name,
    Reconnect,
    RobotConfig,
    Section,
    SerialLine,
    error_key,
)
from drivers.convention import in_model_joints
from errors import InputError
from station.formats.base import MAX_DIAL_MM, MAX_LENGTH_MM, DialReading, Length, TimeScale, read_toml
from station.holders import file_holder, named

UNREACHABLE_HINT = "is `station sim serve` running, or the station's wiring up?"
"""What a device that stays unreachable at the start of ``station read`` or ``station sample`` asks."""


def unreachable_hint(cfg: StationConfig, exc: Exception) -> str:
    """What to check when a device stays unreachable at the start: the process that holds its
    serial port where one does (another session, a terminal program; one this user cannot see is
    "another process" where pyserial found the port locked), else :data:`UNREACHABLE_HINT`."""
    section = cfg.devices().get(getattr(exc, "device", None))
    if not isinstance(section, SerialLine):
        return UNREACHABLE_HINT
    if (pid := file_holder(section.port)) is not None:
        return f"{section.port} is held by {named(pid)}"
    if "exclusively lock" in str(exc):  # pyserial's words for a port another process locked
        return f"{section.port} is held by another process"
    return UNREACHABLE_HINT


Seconds = Annotated[float, Field(gt=0, le=86400)]  # a time of the capture rule, s: up to a day


def _six_or_none(values: list) -> list:
    if len(values) not in (0, 6):
        raise ValueError(f"{len(values)} values: give 6, joint 1 first (or [] for the robot file's)")
    return values


class SimConfig(Section):
    """The simulated cell that ``station sim serve`` runs: world seed, robot program motion, the
    true robot's ``unmodelled`` error (``sim_fixtures.unmodelled.KINDS``), and the joint convention
    its simulated controller publishes and takes targets in (:meth:`convention`)."""

    seed: int = Field(0, ge=0)
    speed_deg_s: float = Field(30.0, gt=0, le=1000)
    accel_deg_s2: float = Field(60.0, gt=0, le=10000)
    dwell_s: float = Field(3.0, ge=0, le=3600)
    targets_per_line: int = Field(70, ge=2, le=10000)  # the cell's plan: targets along each gauge line
    plan_csv: Name = "/tmp/station-sim/plan.csv"  # sim serve publishes the plan it walks here
    change: dict[str, Annotated[float, Field(ge=-100, le=100)]] = {}  # the robot after its calibration
    # the simulated controller's joint convention ([]: the --robot file's [controller], else the identity)
    joint_sign: Annotated[list[Literal[1, -1]], AfterValidator(_six_or_none)] = []
    joint_offset_deg: Annotated[
        list[Annotated[float, Field(ge=-3600, le=3600)]], AfterValidator(_six_or_none)
    ] = []
    unmodelled: Literal["none", "ur10-like"] = "none"
    # a sweep plan (issue 37): the tool's speed and acceleration along a pass, the speed above which
    # the dial lifts off the edge, and each sensor's own latency, its jitter (1 sigma) and the
    # fraction of requests it leaves unanswered (simulated s, mm)
    sweep_speed_mm_s: float = Field(40.0, gt=0, le=2000)
    sweep_accel_mm_s2: float = Field(400.0, gt=0, le=1e5)
    liftoff_speed_mm_s: float = Field(1000.0, gt=0, le=1e5)
    drawstring_latency_s: float = Field(0.004, ge=0, le=1)
    dial_latency_s: float = Field(0.010, ge=0, le=1)
    drawstring_jitter_s: float = Field(0.0002, ge=0, le=0.1)
    dial_jitter_s: float = Field(0.0005, ge=0, le=0.1)
    drawstring_drop: float = Field(0.0, ge=0, le=0.5)
    dial_drop: float = Field(0.0, ge=0, le=0.5)

    def convention(self, controller=None) -> tuple[list[float], list[float]]:
        """The simulated controller's ``joint_sign`` and ``joint_offset_deg`` [deg] (6 each): this
        section's where given, else ``controller``'s (a robot file's ``[controller]``; None: the
        identity)."""
        sign = self.joint_sign or (controller.joint_sign if controller is not None else [1] * 6)
        offset = self.joint_offset_deg or (
            controller.joint_offset_deg if controller is not None else [0.0] * 6
        )
        return [float(v) for v in sign], [float(v) for v in offset]

    @model_validator(mode="after")
    def _change_names(self) -> SimConfig:
        unknown = sorted(set(self.change) - set(DH_NAMES))
        if unknown:
            raise ValueError(f"change: {unknown[0]!r} is no D-H parameter (J1.theta_deg .. J6.alpha_deg)")
        return self


class SessionConfig(Section):
    """``station sample``: what is calibrated (robot model and setup files, relative to this config
    or to the shipped ``configs/``) and the capture rule. Times are simulated seconds (divided by
    ``time_scale`` at the station), speeds as the controller reports them."""

    robot_model: Name = "robots/hsr_jr680.toml"
    setup: Name = "setups/sim.toml"
    plan: Name = "/tmp/station-sim/plan.csv"  # the plan when `station sample` gets no --plan
    settle_speed_deg_s: float = Field(0.05, gt=0, le=1000)  # every |qd| below this ...
    settle_s: Seconds = 0.5  # ... for this long, robot mode RUNNING: settled
    readings: int = Field(5, ge=2, le=1000)  # K readings of every device per capture
    window_s: Seconds = 1.5  # all K rounds inside this synchronisation window
    still_deg: float = Field(0.005, gt=0, le=360)  # joint span during a capture: else "robot moved"
    jump_mm: float = Field(0.15, gt=0, le=MAX_LENGTH_MM)  # drawstring span in a capture: else "jumped"
    dial_range_mm: tuple[DialReading, DialReading] = (-2.0, 2.0)  # dial gate (in range to capture)
    dial_stable_mm: float = Field(0.02, gt=0, le=MAX_DIAL_MM)  # dial span during a capture (noise 0.002 mm)
    length_range_mm: tuple[Length, Length] = (50.0, 5000.0)  # drawstring outside: slack or jump
    match_deg: float = Field(2.0, gt=0, le=360)  # a settle this far (max |dq|) from every target is ignored
    target_timeout_s: Seconds = 120.0  # no capture for this long: the session ends
    unreachable_s: Seconds = 30.0  # real s a device may stay silent while suspended

    @model_validator(mode="after")
    def _ranges_ordered(self) -> SessionConfig:
        for key in ("dial_range_mm", "length_range_mm"):
            low, high = getattr(self, key)
            if not low < high:
                raise ValueError(f"{key}: the low end {low:g} must be below the high end {high:g}")
        return self


class SweepConfig(Section):
    """A sweep session (a plan with passes, ``station.acquire.sweep``): each sensor's stated
    latency (how long before its reply the value it reports was true), the TCP speed along the edge
    above which a row is not trusted, the longest gap bridged by interpolation, the rows kept per
    second (decimation), how far an estimated latency may lie from the stated one before the
    session names it, and ``timing_share``: a row whose length is uncertain by more than this share
    of the drawstring's stated noise (the setup's ``sigma_mm``) from its timing alone (half the
    reading's round trip, where in it the device measured, and the joints' linear interpolation
    between two robot packages, times the length's rate) is flagged, not stored (1: an error spread
    evenly within that bound adds at most sigma/sqrt(3), 15 % in quadrature; 0.5 flags about every row
    moving along the string at 40 mm/s, where half a fast 0.5 ms round trip is 0.01 mm already).
    Times in simulated seconds, as the session's."""

    drawstring_latency_s: float = Field(0.004, ge=0, le=1)
    dial_latency_s: float = Field(0.010, ge=0, le=1)
    max_speed_mm_s: float = Field(150.0, gt=0, le=1e5)
    max_gap_s: float = Field(0.1, gt=0, le=10)
    rows_per_s: float = Field(240.0, gt=0, le=1e4)
    latency_tolerance_s: float = Field(0.0025, gt=0, le=1)
    timing_share: float = Field(1.0, gt=0, le=100)


class StationConfig(Section):
    """``configs/station.toml``: one section per device, plus the shared ``time_scale``."""

    time_scale: TimeScale = 1.0
    session: SessionConfig = SessionConfig()
    sweep: SweepConfig = SweepConfig()
    robot: RobotConfig
    drawstring: DrawstringConfig
    dial: DialConfig | None = None
    reconnect: Reconnect = Reconnect()
    sim: SimConfig = SimConfig()

    def with_time_scale(self, time_scale: float | None) -> StationConfig:
        """This config at ``time_scale`` (None: as it is; from ``--time-scale`` or a simulator's
        announcement); a value out of range is an InputError naming ``--time-scale``."""
        if time_scale is None:
            return self
        try:
            valid = TypeAdapter(TimeScale).validate_python(time_scale)
        except ValidationError as exc:
            raise InputError(f"--time-scale {time_scale:g}: {exc.errors()[0]['msg']}") from None
        return self.model_copy(update={"time_scale": valid})

    def devices(self) -> dict[str, Section]:
        """The configured device sections by name, robot first."""
        found = {"robot": self.robot, "drawstring": self.drawstring, "dial": self.dial}
        return {name: section for name, section in found.items() if section is not None}

    def drivers(self, controller=None) -> dict[str, Driver]:
        """Every configured device's driver (unopened) by name, robot first; the robot's read and
        written in the model's joints under ``controller`` (a robot file's ``[controller]``; None:
        the controller's own)."""
        built = {name: section.build() for name, section in self.devices().items()}
        built["robot"] = in_model_joints(built["robot"], controller)
        return built


def resolve(name: str, config_path: str | Path) -> Path:
    """A file named in the config: beside the config if it is there, else a shipped default."""
    beside = Path(config_path).parent / name
    return beside if beside.exists() else configs.path(name)


def load_station_config(path: str | Path) -> StationConfig:
    """Read and validate a station config; any problem is an ``InputError`` naming file and key."""
    return station_config(read_toml(path), str(path))


def station_config(raw: dict, where: str) -> StationConfig:
    """Validate a station config's content; a problem is an ``InputError`` naming ``where`` and the key."""
    try:
        return StationConfig.model_validate(raw)
    except ValidationError as exc:
        err = exc.errors()[0]
        message = err["msg"].removeprefix("Value error, ")
        raise InputError(f"{where}: {error_key(err['loc'])}: {message}") from None
