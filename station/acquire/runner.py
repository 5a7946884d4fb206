"""``station sample`` behind the CLI: prepare a session folder (new or resumed), run the session
with its live view and progress, and close everything whatever happens."""

from __future__ import annotations

import contextlib
import json
import signal
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass
from datetime import datetime, timezone
from pathlib import Path

from drivers.base import DeviceReplyError, DriverError, call_with_reconnect
from errors import DeviceError, InputError
from station.acquire.capture import Devices, Rules
from station.acquire.convention import AwaySettles
from station.acquire.ending import gate_advice, offline_pass
from station.acquire.livefit import FitWorker, LiveListener, RunningCalibration, line_segments
from station.acquire.progress import Progress
from station.acquire.session import Listener, Session, State
from station.acquire.stream import Streams
from station.acquire.sweep import Kinematics, SweepRules, SweepSession
from station.acquire.targets import TargetFeed
from station.config import StationConfig, load_station_config, resolve, station_config, unreachable_hint
from station.formats.announcement import announcement_path, running_simulator
from station.formats.base import read_toml, validate
from station.formats.plan import Plan, load_plan
from station.formats.session_folder import SessionFolder, SessionHeader
from station.formats.tables import RobotFile, SetupFile, load_robot, load_setup
from station.jobs.running import Refit
from station.view.live import LiveView

WORKER_START_S = 30.0  # the session waits this long at most for the running calibration's worker
RESUME_FIT_S = 120.0  # a resumed session waits this long at most for the refit of its samples
FINAL_FIT_S = 30.0  # the session's end waits this long at most for the refit on every sample
STOP_CHECK_S = 0.1  # a drain looks for a stop request this often [s]


@dataclass
class SessionInputs:
    """Everything a session run needs, validated: its folder (new or reopened), the station
    config (at the session's time scale), the plan, the robot table and the setup; ``notes`` for
    the session's log as it starts; ``robot_where``: the robot file's path."""

    folder: SessionFolder
    cfg: StationConfig
    plan: Plan
    robot: RobotFile
    setup: SetupFile
    notes: tuple[str, ...] = ()
    robot_where: str = "the robot file"  # where the robot file is, for advice on its [controller]


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


def agree_time_scale(cfg: StationConfig, time_scale: float | None) -> tuple[StationConfig, tuple[str, ...]]:
    """``cfg`` at the session's time scale, and a note when it is the simulator's. Where ``station
    sim serve`` announces that it simulates this config's robot, its time scale holds (a different
    ``time_scale`` (``--time-scale``) is an InputError); else ``time_scale`` if given, else the
    config's."""
    sim = running_simulator(cfg.sim.plan_csv)
    if sim is None or sim.robot != cfg.robot.endpoint():
        return cfg.with_time_scale(time_scale), ()
    if time_scale is not None and time_scale != sim.time_scale:
        raise InputError(
            f"--time-scale {time_scale:g}: the simulated robot at {sim.robot} runs at time scale "
            f"{sim.time_scale:g} (`station sim serve`, process {sim.pid}, announced in "
            f"{announcement_path(cfg.sim.plan_csv)}); leave --time-scale out or give {sim.time_scale:g}"
        )
    note = f"time scale {sim.time_scale:g}: the simulated robot's (`station sim serve`, process {sim.pid})"
    return cfg.with_time_scale(sim.time_scale), (note,)


def agree_robot(cfg: StationConfig, robot: RobotFile, where: str) -> None:
    """Bad input where ``station sim serve`` announces that it simulates this config's robot as
    another model than ``robot`` (read from ``where``): the session would measure one robot with
    another's table."""
    sim = running_simulator(cfg.sim.plan_csv)
    if sim is None or sim.robot != cfg.robot.endpoint() or sim.model in (None, robot.name):
        return
    raise InputError(
        f"{where}: robot {robot.name!r}, but the simulated robot at {sim.robot} is a {sim.model!r} "
        f"(`station sim serve`, process {sim.pid}); name that robot's file in [session] robot_model, "
        f"or serve this one: `station sim serve --robot {where} --setup SETUP.toml`"
    )


def new_session(
    out: Path, config_path: Path, plan_path: Path | None, time_scale: float | None = None
) -> SessionInputs:
    """Validate the inputs (``time_scale``: :func:`agree_time_scale`) and check that ``out`` can be a
    new session folder; :func:`run` makes it once every device answered, so a session that never
    starts leaves nothing behind."""
    cfg, notes = agree_time_scale(load_station_config(config_path), time_scale)
    robot = load_robot(resolve(cfg.session.robot_model, config_path))
    agree_robot(cfg, robot, str(resolve(cfg.session.robot_model, config_path)))
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
    where = str(resolve(cfg.session.robot_model, config_path))
    return SessionInputs(SessionFolder.new(out, header), cfg, plan, robot, setup, notes, where)


def resume_session(
    folder_path: Path, config_path: Path | None, time_scale: float | None = None
) -> SessionInputs:
    """Reopen a session folder; its embedded config serves unless ``config_path`` is given, at the
    time scale :func:`agree_time_scale` finds. The folder is locked first (one writer), and all
    of ``session.toml`` is validated before the folder is opened (and repaired)."""
    where = Path(folder_path) / "session.toml"
    lock = SessionFolder.lock_for_resume(folder_path)
    try:
        header = validate(SessionHeader, read_toml(where), str(where))
        if config_path:
            cfg = load_station_config(config_path)
        else:
            cfg = station_config(header.station, f"{where} [station]")
        cfg, notes = agree_time_scale(cfg, time_scale)
        plan = Plan.from_rows(header.plan, str(where))
        agree_robot(cfg, header.robot, f"{where} [robot]")
    except BaseException:
        lock.release()
        raise
    folder = SessionFolder.open(folder_path, lock)
    notes = (*notes, *folder.notes)
    robot_where = f"{where} [robot] (and the robot file it came from)"  # the resumed session's robot
    return SessionInputs(folder, cfg, plan, header.robot, header.setup, notes, robot_where)


def open_devices(cfg: StationConfig, controller=None) -> Devices:
    """Build, open and read every configured device once (DeviceError if one stays unreachable);
    the robot's joints in the model's, under ``controller`` (the robot file's ``[controller]``)."""
    backoff = cfg.reconnect.backoff()
    devices = Devices(cfg.drivers(controller), backoff)
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
        raise DeviceError(f"{exc} ({unreachable_hint(cfg, exc)})") from exc
    return devices


@dataclass
class SessionRun:
    """How a session run ended: its ``state``, the ``view`` (open: the caller closes it), the
    running calibration's ``refit`` on every sample (None if it never answered) and the largest
    live error [mm] of the run (None if the running calibration was never judged)."""

    state: State
    view: LiveView
    refit: Refit | None
    worst_error_mm: float | None


def run(
    inputs: SessionInputs,
    *,
    viewer: bool = False,
    web: str | None = None,
    until_mm: float | None = None,
    stream=None,
    every_sample: bool = True,
) -> SessionRun:
    """Run the session to its end; the live view stays open for a calibration to log into. ``web``
    is the address to serve the web viewer on; ``until_mm`` ends the session once the running
    calibration's 95 % workspace bound reaches it; ``every_sample`` False keeps a plain (non-tty)
    progress to the messages. Devices are opened first: an unreachable one fails before anything
    else, and a new session's folder is made only once they all answered."""
    if inputs.plan.is_sweep:
        return _run_sweep(inputs, viewer, web, stream)
    plan_rows = (inputs.plan.q_deg, inputs.plan.line)  # corrected with each judged refit
    worker = FitWorker.start(inputs.robot, inputs.setup, plan_rows)  # starts while the devices open
    view = None
    try:
        devices = open_devices(inputs.cfg, inputs.robot.controller)
        try:
            if not inputs.folder.made:
                inputs.folder.make()
            view = LiveView(inputs.folder.rrd, viewer=viewer, web=web, resume=bool(inputs.folder.rows))
            progress = Progress(len(inputs.plan), len(inputs.folder.rows), stream, every_sample=every_sample)
            live = Live(inputs.robot, inputs.setup, inputs.plan.line, worker, view, progress, until_mm)
            state = _run_session(inputs, devices, live)
        finally:
            devices.close()
    except BaseException:
        if view is not None:
            view.close()
        raise
    finally:
        worker.close()
    corrected = sorted({*inputs.folder.header.get("corrected_targets", []), *live.corrected_targets()})
    inputs.folder.update_header(
        last_state=state.value, samples=len(inputs.folder.rows), corrected_targets=corrected
    )
    return SessionRun(state, view, live.running.latest, live.worst_mm)


def _run_sweep(inputs: SessionInputs, viewer: bool, web: str | None, stream) -> SessionRun:
    """A sweep session (``station.acquire.sweep``): the devices streamed, each finished pass stored
    whole, the latency check and the faults said at the end; no running calibration (the rows of a
    pass come at once, thousands of them: ``station calibrate`` fits them after)."""
    devices = open_devices(inputs.cfg, inputs.robot.controller)
    view = None
    folder, plan = inputs.folder, inputs.plan
    try:
        if not folder.made:
            folder.make()
        view = LiveView(folder.rrd, viewer=viewer, web=web, resume=bool(folder.rows))
        finished = {int(p) for p in folder.header.get("finished_passes", [])}
        progress = Progress(len(plan.passes()), len(finished), stream, every_sample=False)

        def tell(text: str) -> None:
            progress.message(text)
            view.message(text)

        kin = Kinematics(inputs.robot, inputs.setup)
        tcp = kin.tcp(plan.q_deg)
        view.cell(inputs.setup.drawstring.anchor_mm, line_segments(tcp, plan.line), tcp)
        for note in (*view.notes, *inputs.notes):
            tell(note)
        if dropped := folder.keep_rows(lambda row: int(row["pass"]) in finished):
            tell(f"{dropped} rows of a pass left unfinished dropped: it is swept again")
        robot_hz = float(getattr(inputs.cfg.robot, "frequency_hz", 100.0))
        rules = SweepRules.from_config(
            inputs.cfg, inputs.setup.drawstring.sigma_mm, inputs.setup.line_sigma_mm
        )
        streams = Streams(devices.drivers, robot_hz, rules.row_spacing_s / 2)
        session = SweepSession(folder, plan, streams, rules, kin, tell, view.sweep, view.sweeping)
        with _stops_on_signal(session.request_stop):
            state = session.run()
        for line in session.report():
            tell(line)
        progress.close()
    except BaseException:
        if view is not None:
            view.close()
        raise
    finally:
        devices.close()
    folder.update_header(last_state=state.value, samples=len(folder.rows))
    return SessionRun(state, view, None, None)


@contextlib.contextmanager
def _stops_on_signal(stop: Callable[[], None]):
    """While held, Ctrl-C and the SIGTERM of a service manager or `kill` call ``stop`` (in the main
    thread: signals reach no other), as the operator would stop the session."""
    in_main = threading.current_thread() is threading.main_thread()
    stops = (signal.SIGINT, signal.SIGTERM) if in_main else ()
    previous = {s: signal.signal(s, lambda *_: stop()) for s in stops}
    try:
        yield
    finally:
        for s, handler in previous.items():
            signal.signal(s, handler)


class Live:
    """The running calibration of a session on ``robot`` and ``setup`` following a plan with gauge
    lines ``plan_lines``, refitting with ``worker``, wired to the session (:meth:`listener`), the
    view and the progress line, its corrected targets to the robot's target channel
    (:meth:`feed_targets`); ``until_mm`` as in :func:`run`."""

    def __init__(self, robot, setup, plan_lines, worker, view: LiveView, progress: Progress, until_mm):
        self.view, self.progress = view, progress
        self.ids: list[int] = []  # sample ids in the order the running calibration got them
        self.worst_mm: float | None = None
        self.session: Session | None = None
        self.feed: TargetFeed | None = None
        listener = LiveListener(self.refit, self.message, self.reached, self.corrected)
        self.running = RunningCalibration(robot, setup, worker, plan_lines, listener, until_mm)

    def listener(self) -> Listener:
        """The session's listener: each sample judged and handed on; the worker looked in on at
        every checkpoint, never waited for; each settle at a plan target told to the target feed."""
        return Listener(self.sample, self.message, self.running.poll, self.settled, self.remedy)

    def feed_targets(self, plan: Plan, driver, finished: set[int]) -> None:
        """Hand the corrected targets of ``plan`` to the robot ``driver``'s target channel (opened
        now: a second connection of some controllers), or say once, when they start, that it has
        none; ``finished``: the target ids measured before (a resumed session's, corrected at once)."""
        before = [i for i, t in enumerate(plan.target) if int(t) not in finished]
        self.feed = TargetFeed(
            plan,
            driver.target_channel,
            lambda: driver.no_channel,
            lambda: self.session.pending if self.session is not None else before,
            self.message,
            self.view.message,
        )
        driver.target_channel()

    def corrected(self, correction) -> None:
        if self.feed is not None:
            self.feed.corrected(correction)

    def settled(self, index: int) -> None:
        if self.feed is not None:
            self.feed.settled(index)

    def remedy(self) -> str | None:
        """What to do about the targets left when the session times out (``station.acquire.ending``):
        before the model is determined, widen the dial gate for the targets it kept off the edge;
        after, the channel's correction (``TargetFeed.remedy``) or, without a channel, the offline
        second pass."""
        if self.session is None:
            return None
        folder = self.session.folder
        resume = f"station sample --resume {folder.path}"
        channel = self.feed is not None and self.feed.channel() is not None
        offline = offline_pass(*_plan_and_robot(folder.header), str(folder.path), resume)
        rerun = f"run the robot program again with {resume}: the targets measured already are skipped"
        fit = self.running.latest
        if fit is None or not fit.judged:
            then = CORRECTED_LATER if channel else f"once it is determined, {offline}"
            return self._widen(fit, then) or rerun
        if said := None if self.feed is None else self.feed.remedy(resume):
            return said
        return rerun if channel else offline

    def _widen(self, fit: Refit | None, then: str) -> str | None:
        """The dial gate to widen for the targets kept off the edge before the model is determined
        (``fit``: the latest refit, not judged), ``then``: how the later targets get corrected."""
        folder = self.session.folder
        needed = f" of the {fit.needed} it needs" if fit is not None else ""
        model = f"the model is not determined yet ({len(self.ids)} samples{needed})"
        config = folder.header.get("config", "station.toml")
        again = f"station sample --config {config} --resume {folder.path}"  # under the widened gate
        return gate_advice(self.session.off_edge_left(), model, config, again, then)

    def corrected_targets(self) -> list[int]:
        """The target ids this run handed the program corrected."""
        return [] if self.feed is None else [t for t, n in self.feed.sent.items() if n]

    def add(self, row: dict, q_deg, length_mm: float, dial_mm: float, refit: bool = True) -> None:
        self.ids.append(int(row["sample"]))
        self.running.add(q_deg, length_mm, dial_mm, int(row["line"]), refit)

    def sample(self, row: dict, cap) -> None:
        live = self.running.live_error(cap.q_deg, cap.length_mm)
        chain, approach = self.running.nominal_chain_mm(cap.q_deg)
        tcp = chain[-1]
        self.view.sample(row["sample"], row["t_s"], tcp, cap.length_mm, cap.dial_mm, live, chain, approach)
        self.progress.sample(row, live)
        self.view.progress(self.progress.done, self.progress.total, int(row["line"]))
        if live.error_mm is not None:
            self.worst_mm = max(abs(live.error_mm), self.worst_mm or 0.0)
        if live.suspect:
            self.message(
                f"sample {row['sample']}: reading {live.error_mm:+.3f} mm off the running calibration "
                f"(it explains {live.limit_mm:.3f} mm): check the cable and the gauge contact"
            )
        self.add(row, cap.q_deg, cap.length_mm, cap.dial_mm)

    def refit(self, fit) -> None:
        if fit.workspace is None:
            return
        ws = fit.workspace
        self.view.refit(self.ids[fit.n - 1], ws.predicted_rmse_mm, ws.predicted_rmse_95_mm)
        self.progress.refit(ws.predicted_rmse_mm, ws.predicted_rmse_95_mm)

    def message(self, text: str) -> None:
        self.progress.message(text)
        self.view.message(text)

    def reached(self, text: str) -> None:
        self.progress.show_refit(self.running.latest.n)  # the refit that stopped it, shown first
        self.message(text)
        if self.session is not None:
            self.session.finish("accuracy reached")

    def drain(self, timeout_s: float, stopped: Callable[[], bool] = lambda: False) -> None:
        """Wait (up to ``timeout_s`` [s]) for the refit on every sample taken, or until ``stopped()``."""
        deadline = time.monotonic() + timeout_s
        while self.running.latest is None or self.running.latest.n < len(self.ids):
            left = deadline - time.monotonic()
            if left <= 0 or not self.running.worker.busy or stopped():
                return
            self.running.poll(min(left, STOP_CHECK_S))


CORRECTED_LATER = (
    "once the model is determined, the running calibration corrects the later targets onto the edge "
    "through the robot's target channel"
)


def _plan_and_robot(header: dict) -> tuple[str, str]:
    """The plan file and the robot file a session's ``session.toml`` header names."""
    config = Path(header.get("config", "station.toml"))
    robot = header.get("station", {}).get("session", {}).get("robot_model", "ROBOT.toml")
    return header.get("plan_source", "PLAN.csv"), str(resolve(robot, config))


def _run_session(inputs: SessionInputs, devices: Devices, live: Live) -> State:
    """The session with its running calibration, live view and progress wired to it; Ctrl-C stops
    it. A resumed session's samples are refitted first, so its next capture is judged at once."""
    view, progress, worker, plan = live.view, live.progress, live.running.worker, inputs.plan
    view.cell(
        inputs.setup.drawstring.anchor_mm,
        line_segments(live.running.nominal_tcp_mm(plan.q_deg), plan.line),
        [live.running.nominal_chain_mm(q)[0] for q in plan.q_deg],
    )
    for note in (*view.notes, *inputs.notes):
        progress.message(note)
    if "robot" in devices.drivers:
        live.feed_targets(plan, devices.drivers["robot"], inputs.folder.finished_targets)
    worker.wait_ready(WORKER_START_S)
    resumed = inputs.folder.rows
    for k, row in enumerate(resumed):
        dial = float(row["dial_mm"]) if row["dial_mm"] else float("nan")
        q = [float(row[f"q{i}_deg"]) for i in range(1, 7)]
        live.add(row, q, float(row["length_mm"]), dial, refit=k == len(resumed) - 1)  # one refit, on all
    live.drain(RESUME_FIT_S)
    rules = Rules.from_config(inputs.cfg.session, inputs.cfg.time_scale)
    session = live.session = Session(inputs.folder, plan, devices, rules, live.listener())
    controller, where = inputs.robot.controller, inputs.robot_where
    session.away = AwaySettles(plan.q_deg, plan.target, rules.match_deg, controller, where)
    if live.running.goal_met:
        session.finish("accuracy reached")
    with _stops_on_signal(session.request_stop):
        return _finish(session, live, inputs, progress)


def _finish(session: Session, live: Live, inputs: SessionInputs, progress: Progress) -> State:
    """Run ``session`` to its end, wait for the final refit, say what the corrected targets did."""
    try:
        state = session.run()
        if state is not State.STOPPED:
            live.drain(FINAL_FIT_S, lambda: session.stop_requested)  # a signal now ends the wait
        if corrected := set(live.corrected_targets()):
            taken = sum(int(row["target"]) in corrected for row in inputs.folder.rows)
            progress.message(
                f"corrected targets: {len(corrected)} sent before the program moved there, {taken} of "
                "them measured (session.toml corrected_targets)"
            )
        return state
    finally:
        progress.close()
