"""``station read [--config F]``: one reading of every configured device, as one JSON object.

The object holds every value (``q_deg`` in degrees, ``length_mm``, ``dial_mm``, ...) and, per
device, its units and the monotonic and wall-clock times of its reading. The robot's joints are the
model's: the robot file that ``[session] robot_model`` names converts the controller's readings
with its ``[controller]`` (as ``station sample`` does). A device that stays
unreachable after the configured retries ends the command with exit 1, naming it.
"""

from __future__ import annotations

import json
import math

import configs
from drivers.base import Backoff, DeviceUnreachable, Driver, Reading, call_with_reconnect
from errors import DeviceError


def register(subparsers) -> None:
    read = subparsers.add_parser("read", help="read every device once (a wiring check)")
    read.add_argument(
        "--config",
        default=str(configs.path("station.toml")),
        help="station config (default: the shipped one, simulated devices)",
    )
    read.set_defaults(func=run)


def read_once(driver: Driver, backoff: Backoff) -> Reading:
    """Open ``driver``, read it once (retrying transient failures), close it."""

    def attempt() -> Reading:
        driver.open()
        return driver.read()

    try:
        return call_with_reconnect(driver, attempt, backoff)
    finally:
        driver.close()


def as_json(readings: dict[str, Reading]) -> dict:
    """All values side by side, then per device its units and timestamps; a value that is not a
    finite number is null (JSON has no NaN)."""
    out: dict = {}
    for reading in readings.values():
        out.update({name: _finite_or_none(value) for name, value in reading.values.items()})
    out["devices"] = {
        name: {"units": dict(r.units), "t_monotonic": r.t_monotonic, "t_wall": r.t_wall}
        for name, r in readings.items()
    }
    return out


def _finite_or_none(value):
    if isinstance(value, tuple | list):
        return [_finite_or_none(v) for v in value]
    return value if not isinstance(value, float) or math.isfinite(value) else None


def run(args) -> int:
    from station.config import load_station_config, resolve, unreachable_hint
    from station.formats.tables import load_robot

    cfg = load_station_config(args.config)
    controller = load_robot(resolve(cfg.session.robot_model, args.config)).controller
    backoff = cfg.reconnect.backoff()
    try:
        readings = {name: read_once(driver, backoff) for name, driver in cfg.drivers(controller).items()}
    except DeviceUnreachable as exc:
        raise DeviceError(f"{exc} ({unreachable_hint(cfg, exc)})") from exc
    print(json.dumps(as_json(readings), allow_nan=False))
    return 0
