"""``station sample`` behind the CLI: prepare a session folder (new or resumed), run the session
with its live view and progress, and close everything whatever happens."""

from __future__ import annotations

import json
import signal
import threading
import time
from dataclasses import dataclass
from datetime import datetime, timezone
from pathlib import Path

import configs
from drivers.base import DeviceReplyError, DriverError, call_with_reconnect
from errors import DeviceError, InputError
from station.acquire.capture import Devices, Rules
from station.acquire.livefit import LiveFit, line_segments
from station.acquire.progress import Progress
from station.acquire.session import Listener, Session, State
from station.config import StationConfig, load_station_config, station_config
from station.formats.base import read_toml, validate
from station.formats.plan import Plan, load_plan
from station.formats.session_folder import SessionFolder, SessionHeader
from station.formats.tables import RobotFile, SetupFile, load_robot, load_setup
from station.view.live import LiveView


@dataclass
class SessionInputs:
    """Everything a session run needs, validated: its folder (new or reopened), the station
    config, the plan, the robot table and the setup."""

    folder: SessionFolder
    cfg: StationConfig
    plan: Plan
    robot: RobotFile
    setup: SetupFile


def resolve(name: str, config_path: Path) -> Path:
    """A file named in the config: beside the config if it is there, else a shipped default."""
    beside = config_path.parent / name
    return beside if beside.exists() else configs.path(name)


def _plain(model) -> dict:
    """A pydantic model as TOML-ready data (no None, tuples as lists)."""
    return json.loads(model.model_dump_json(exclude_none=True))


def default_plan(cfg: StationConfig, config_path: Path) -> Path:
    """The plan named by ``[session] plan``; missing: an InputError that says where plans come from."""
    path = config_path.parent / cfg.session.plan
    if not path.is_file():
        raise InputError(
            f"{config_path}: [session] plan = {cfg.session.plan!r}: no such file; give --plan P.csv "
            "(`station plan` designs one) or start `station sim serve`, which publishes its plan there"
        )
    return path


def new_session(out: Path, config_path: Path, plan_path: Path | None) -> SessionInputs:
    """Validate the inputs, then create ``out`` with ``session.toml`` (fails before any sample)."""
    cfg = load_station_config(config_path)
    robot = load_robot(resolve(cfg.session.robot_model, config_path))
    setup = load_setup(resolve(cfg.session.setup, config_path))
    if setup.drawstring is None:
        raise InputError(f"{resolve(cfg.session.setup, config_path)}: missing table [drawstring]")
    plan_path = plan_path or default_plan(cfg, config_path)
    plan = load_plan(plan_path)
    header = {
        "started_utc": datetime.now(timezone.utc).isoformat(timespec="seconds"),
        "start_wall_s": time.time(),
        "config": str(config_path),
        "plan_source": str(plan_path),
        "robot": _plain(robot),
        "setup": _plain(setup),
        "station": _plain(cfg),
        "plan": plan.rows(),
    }
    return SessionInputs(SessionFolder.create(out, header), cfg, plan, robot, setup)


def resume_session(folder_path: Path, config_path: Path | None) -> SessionInputs:
    """Reopen a session folder; its embedded config serves unless ``config_path`` is given. All of
    ``session.toml`` is validated before the folder is opened (and repaired)."""
    where = Path(folder_path) / "session.toml"
    header = validate(SessionHeader, read_toml(where), str(where))
    if config_path:
        cfg = load_station_config(config_path)
    else:
        cfg = station_config(header.station, f"{where} [station]")
    plan = Plan.from_rows(header.plan, str(where))
    return SessionInputs(SessionFolder.open(folder_path), cfg, plan, header.robot, header.setup)


def open_devices(cfg: StationConfig) -> Devices:
    """Build, open and read every configured device once (DeviceError if one stays unreachable)."""
    backoff = cfg.reconnect.backoff()
    devices = Devices({name: section.build() for name, section in cfg.devices().items()}, backoff)
    try:
        for driver in devices.drivers.values():
            try:
                driver.open()
            except DriverError:
                pass  # the read below retries with a reconnect
            try:
                call_with_reconnect(driver, driver.read, backoff)
            except DeviceReplyError:
                pass  # it answers (e.g. a dial off the edge, out of range): reachable
    except DriverError as exc:
        devices.close()
        raise DeviceError(f"{exc} (is `station sim serve` or the station's wiring up?)") from exc
    return devices


def run(
    inputs: SessionInputs, *, viewer: bool = False, web: bool = False, stream=None
) -> tuple[State, LiveView]:
    """Run the session to its end; the live view stays open for a calibration to log into (the
    caller closes it). Devices are opened first: an unreachable one fails before anything else."""
    devices = open_devices(inputs.cfg)
    view = None
    try:
        view = LiveView(inputs.folder.rrd, viewer=viewer, web=web)
        state = _run_session(inputs, devices, view, stream)
    except BaseException:
        if view is not None:
            view.close()
        raise
    finally:
        devices.close()
    inputs.folder.update_header(last_state=state.value, samples=len(inputs.folder.rows))
    return state, view


def _run_session(inputs: SessionInputs, devices: Devices, view: LiveView, stream) -> State:
    """The session with its live fit, live view and progress wired to it; Ctrl-C stops it."""
    fit = LiveFit(inputs.robot, inputs.setup)
    view.cell(
        inputs.setup.drawstring.anchor_mm, line_segments(fit.tcp_mm(inputs.plan.q_deg), inputs.plan.line)
    )
    _replay(inputs.folder, fit, view)
    progress = Progress(len(inputs.plan), len(inputs.folder.rows), stream=stream)
    for note in view.notes:
        progress.message(note)

    def on_sample(row, cap) -> None:
        tcp, model = fit.add(cap.q_deg, cap.length_mm)
        view.sample(row["sample"], row["t_s"], tcp, cap.length_mm, model, cap.dial_mm)
        progress.sample(row, cap.length_mm - model)

    def on_message(text: str) -> None:
        progress.message(text)
        view.message(text)

    rules = Rules.from_config(inputs.cfg.session, inputs.cfg.time_scale)
    session = Session(inputs.folder, inputs.plan, devices, rules, Listener(on_sample, on_message))
    in_main = threading.current_thread() is threading.main_thread()
    previous = signal.signal(signal.SIGINT, lambda *_: session.request_stop()) if in_main else None
    try:
        return session.run()
    finally:
        if in_main:
            signal.signal(signal.SIGINT, previous)
        progress.close()


def _replay(folder: SessionFolder, fit: LiveFit, view: LiveView) -> None:
    """Log the samples of a resumed session again, so its new .rrd holds the whole session."""
    for row in folder.rows:
        q = [float(row[f"q{i}_deg"]) for i in range(1, 7)]
        length = float(row["length_mm"])
        tcp, model = fit.add(q, length)
        dial = float(row["dial_mm"]) if row["dial_mm"] else float("nan")
        view.sample(int(row["sample"]), float(row["t_s"]), tcp, length, model, dial)
