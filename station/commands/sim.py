"""``station sim serve [--config F] [--hold] [--plan P.csv] [--time-scale S]``: run the simulated
devices until SIGINT/SIGTERM.

Publishes the plan its robot walks at ``[sim] plan_csv`` (where ``station sample`` looks by
default) and announces its robot and time scale beside it (``station.formats.announcement``: a
``station sample`` on that robot adopts the time scale), prints one JSON line per device with its
address (the robot's with the time scale), then serves; on a signal it stops every device, removes
the pty links and its announcement.
"""

from __future__ import annotations

import json
import signal
import threading
from pathlib import Path
from typing import TYPE_CHECKING

import configs
from errors import DeviceError

if TYPE_CHECKING:
    from station.formats.plan import Plan


def register(subparsers) -> None:
    sim = subparsers.add_parser("sim", help="simulated devices")
    actions = sim.add_subparsers(dest="action", required=True, metavar="ACTION")
    serve = actions.add_parser("serve", help="serve the simulated devices until interrupted")
    serve.add_argument(
        "--config",
        default=str(configs.path("station.toml")),
        help="station config (default: the shipped one, contract addresses)",
    )
    serve.add_argument(
        "--hold", action="store_true", help="keep the simulated robot still at its first target"
    )
    serve.add_argument(
        "--plan", type=Path, help="plan CSV (station plan) for the simulated robot to walk instead of its own"
    )
    serve.add_argument(
        "--time-scale",
        type=float,
        metavar="S",
        help="simulated seconds per real second (default: the config's time_scale, 1 = real time; "
        "20: a 210-target session in about a minute); `station sample` adopts it",
    )
    serve.set_defaults(func=run)


def run(args) -> int:
    from sim_fixtures.station_sim import SimStation
    from station.config import load_station_config
    from station.formats.announcement import withdraw
    from station.formats.plan import Plan, load_plan

    cfg = load_station_config(args.config).with_time_scale(args.time_scale)
    stop = threading.Event()
    plan = load_plan(args.plan) if args.plan else None
    station = SimStation(cfg, hold=args.hold, plan=None if plan is None else (plan.q_deg, plan.line))
    publish_plan(Path(cfg.sim.plan_csv), plan or Plan.of(station.plan_deg, station.plan_lines))
    try:
        # Children start with Ctrl-C ignored (a terminal sends it to the whole process group):
        # this process alone handles it and stops them.
        signal.signal(signal.SIGINT, signal.SIG_IGN)
        try:
            addresses = station.start()
        except (OSError, RuntimeError) as exc:
            raise DeviceError(f"cannot start the simulated devices: {exc}") from exc
        for signum in (signal.SIGINT, signal.SIGTERM):
            signal.signal(signum, lambda *_: stop.set())
        _announce(cfg)
        for address in addresses:
            print(json.dumps(address), flush=True)
        while not stop.wait(0.5):
            pass
    finally:
        withdraw(cfg.sim.plan_csv)
        station.stop()
    return 0


def _announce(cfg) -> None:
    """Say beside the published plan which robot this simulator serves, at which time scale."""
    from station.formats.announcement import announce

    try:
        announce(cfg.sim.plan_csv, cfg.robot.endpoint(), cfg.time_scale)
    except OSError as exc:
        raise DeviceError(
            f"cannot announce the simulator beside {cfg.sim.plan_csv}: {exc.strerror or exc}"
        ) from exc


def publish_plan(path: Path, plan: Plan) -> None:
    """Write the plan the simulated robot walks where ``station sample`` finds it by default."""
    from station.formats.base import atomic_write

    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        atomic_write(path, plan.csv_text())
    except OSError as exc:
        raise DeviceError(f"cannot publish the simulated plan at {path}: {exc.strerror or exc}") from exc
