"""``station read [--config F]``: one reading of every configured device, as one JSON object.

The object holds every value (``q_deg`` in degrees, ``length_mm``, ``dial_mm``, ...) and, per
device, its units and the monotonic and wall-clock times of its reading. The robot's joints are the
model's: the robot file that ``[session] robot_model`` names converts the controller's readings
with its ``[controller]`` (as ``station sample`` does). A device that stays
unreachable after the configured retries ends the command with exit 1, naming it.

An instrument that answers with an error code it states the meaning of (the dial's ``ERR3``: out
of range, the tool off the edge) leaves its values null and its ``error``, ``code`` and ``meaning``
under ``devices``; every other device is still read and printed, stderr says in one line per such
device what its code means, and the exit code is 3: not every value was read.
"""

from __future__ import annotations

import json
import math
import sys
from typing import TYPE_CHECKING

import configs
from errors import DeviceError

if TYPE_CHECKING:  # the drivers are imported where a device is read: every command builds this parser
    from drivers.base import Backoff, DeviceReplyError, Driver, Reading

NOT_ALL_READ = 3
"""Exit code of a read in which an instrument answered with an error code (its values are null)."""


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
    from drivers.base import call_with_reconnect

    def attempt() -> Reading:
        driver.open()
        return driver.read()

    try:
        return call_with_reconnect(driver, attempt, backoff)
    finally:
        driver.close()


def as_json(readings: dict[str, Reading], failed: dict[str, dict] | None = None) -> dict:
    """All values side by side, then per device its units and timestamps; a value that is not a
    finite number is null (JSON has no NaN). ``failed``: per device that answered with an error
    code, its fields (null) and what it answered (:func:`failure`)."""
    out: dict = {}
    for reading in readings.values():
        out.update({name: _finite_or_none(value) for name, value in reading.values.items()})
    for said in (failed or {}).values():
        out.update(dict.fromkeys(said["units"]))
    out["devices"] = {
        name: {"units": dict(r.units), "t_monotonic": r.t_monotonic, "t_wall": r.t_wall}
        for name, r in readings.items()
    }
    out["devices"].update(failed or {})
    return out


def failure(driver: Driver, exc: DeviceReplyError) -> dict:
    """What a device's error code says: its fields' units, the reply, the code and its meaning."""
    meaning = driver.error_meanings.get(str(exc.code), "a code the station does not know: see the manual")
    units = {name: field.units for name, field in driver.fields.items()}
    return {"units": units, "error": exc.cause, "code": str(exc.code), "meaning": meaning}


def _finite_or_none(value):
    if isinstance(value, tuple | list):
        return [_finite_or_none(v) for v in value]
    return value if not isinstance(value, float) or math.isfinite(value) else None


def run(args) -> int:
    from drivers.base import DeviceReplyError, DeviceUnreachable
    from station.config import load_station_config, resolve, unreachable_hint
    from station.formats.tables import load_robot

    cfg = load_station_config(args.config)
    controller = load_robot(resolve(cfg.session.robot_model, args.config)).controller
    backoff = cfg.reconnect.backoff()
    readings, failed = {}, {}
    for name, driver in cfg.drivers(controller).items():
        try:
            readings[name] = read_once(driver, backoff)
        except DeviceUnreachable as exc:
            raise DeviceError(f"{exc} ({unreachable_hint(cfg, exc)})") from exc
        except DeviceReplyError as exc:
            if not hasattr(driver, "error_meanings"):  # no instrument's reading: a wiring fault
                raise
            failed[name] = failure(driver, exc)
    print(json.dumps(as_json(readings, failed), allow_nan=False))
    for name, said in failed.items():
        print(
            f"station: {name}: {said['error']}: {said['meaning']} (the other devices were read; "
            f"exit {NOT_ALL_READ}: not every value)",
            file=sys.stderr,
        )
    return NOT_ALL_READ if failed else 0
