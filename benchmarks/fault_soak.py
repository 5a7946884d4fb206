"""A whole ``station sample`` session against the simulated devices while faults strike every device
at random, then an audit of what was stored.

    python benchmarks/fault_soak.py [--targets 60] [--seed 0] [--timeout-s 900] [--json]

The simulated station (``sim_fixtures.station_sim``: RTDE controller, Modbus RTU drawstring on a
linked pty pair, serial dial) runs in this process; the session is the real command in a child
process (``python -m station.cli sample``), its log read from its stdout. Every ``--interval-s``
(exponential, seeded) one fault, drawn at random:

- Modbus drawstring: no reply, a reply with a bad CRC, garbage, a Modbus exception reply, the
  cable unplugged (and plugged back 0.2 .. 0.8 s later);
- dial: garbage, silence, unplugged (and back);
- controller: the RTDE server gone (restarted 0.3 .. 1 s later; it takes about 1 s to start);
  protective stops (robot mode IDLE for 4 .. 10 simulated s every 40 .. 100, scheduled at random
  in the robot program before it starts);
- cable slack: the cable off the tool for 0.2 .. 1 s (the reading outside its gate).

A fault counts once it could be seen: a fault on a request once a request took it
(``FaultPlan.applied``), a slack cable once the drawstring was read while it was off, an unplugged
sensor once the robot dwelt at a target still to measure meanwhile (the station reads the sensors
only there), a protective stop while the controller was up. The audit: every
target measured once (``duplicates``: targets or sample ids stored twice), every row whole
(``torn``: a row of the wrong width or a sample without its K raw readings), every capture the
session announced is in samples.csv (``lost``), every stored reading the simulated truth within
its noise (``corrupt``), and every fault named in the session log (``unlogged``: a fault with no
log line of its kind after it). The last line (``--json``) is ``{"targets", "measured",
"faults_injected": {kind: n}, "suspensions", "duplicates", "torn", "lost", "exit", ...}``.
"""

from __future__ import annotations

import argparse
import collections
import csv
import json
import random
import re
import socket
import subprocess
import sys
import tempfile
import threading
import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import tomli_w
import tomllib

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
from sim_fixtures.robot_program import IDLE, RobotFault  # noqa: E402
from sim_fixtures.station_sim import SimStation, make_cell  # noqa: E402
from station.commands.sim import publish_plan  # noqa: E402
from station.config import StationConfig  # noqa: E402
from station.formats.plan import Plan  # noqa: E402

TIME_SCALE = 20.0
K = 5  # readings per capture (the default rule)

# fault kind -> the log line that names it
NAMED_BY = {
    "modbus no reply": r"drawstring.*no reply",
    "modbus CRC error": r"drawstring.*bad CRC",
    "modbus garbled": r"drawstring.*unparseable reply",
    "modbus exception reply": r"drawstring.*Modbus exception code",
    "modbus unplugged": r"drawstring.*(link lost|cannot connect|not answering)",
    "dial garbage": r"dial.*unparseable reply",
    "dial silent": r"dial.*(no reply|incomplete reply)",
    "dial unplugged": r"dial.*(link lost|cannot open|not open|not answering)",
    "controller gone": r"robot.*(connection lost|cannot connect|not connected|not answering)",
    "protective stop": r"robot not running",
    "cable slack": r"cable slack",
}
MENU = ("modbus request",) * 3 + ("dial request",) * 2 + (
    "modbus unplugged", "dial unplugged", "controller gone", "cable slack", "cable slack",
)  # fmt: skip
"""What a strike does, drawn uniformly: a fault on the next request (its kind drawn in turn),
an outage, or a slack cable."""
OUTAGE_OF = {"modbus unplugged": "drawstring", "dial unplugged": "dial", "controller gone": "robot"}
ON_REQUEST = {  # (device, FaultPlan kind) -> fault kind
    ("drawstring", "silence"): "modbus no reply",
    ("drawstring", "crc"): "modbus CRC error",
    ("drawstring", "garbled"): "modbus garbled",
    ("drawstring", "error"): "modbus exception reply",
    ("dial", "garbled"): "dial garbage",
    ("dial", "silence"): "dial silent",
}
SAME_REQUEST = {
    kind: "|".join(NAMED_BY[k] for (d, _), k in ON_REQUEST.items() if d == device)
    for (device, _), kind in ON_REQUEST.items()
}
"""Per fault on a request: what names any failure of that device's request."""


def _free_loopback() -> str:
    while True:
        host = f"127.0.0.{random.randint(2, 250)}"
        with socket.socket() as s:
            try:
                s.bind((host, 30004))
                return host
            except OSError:
                continue


def write_config(folder: Path, targets: int, seed: int) -> Path:
    """The soak's station: RTU drawstring and dial on pty links in ``folder``, short timeouts,
    3 attempts, simulated time x20, ``targets`` over three gauge lines."""
    raw = {
        "time_scale": TIME_SCALE,
        "robot": {"kind": "rtde", "host": _free_loopback()},
        "drawstring": {"kind": "modbus_rtu", "port": str(folder / "drawstring"), "timeout_s": 0.1},
        "dial": {"port": str(folder / "dial"), "timeout_s": 0.1},
        "reconnect": {"attempts": 3, "initial_s": 0.05, "max_s": 0.2},
        "session": {"target_timeout_s": 4000.0, "plan": str(folder / "plan.csv")},
        "sim": {
            "seed": seed,
            "speed_deg_s": 120.0,
            "accel_deg_s2": 480.0,
            "dwell_s": 8.0,
            "targets_per_line": targets // 3,
            "plan_csv": str(folder / "plan.csv"),
        },
    }
    path = folder / "station.toml"
    path.write_text(tomli_w.dumps(raw))
    return path


def protective_stops(rng: np.random.Generator, horizon_s: float) -> list[RobotFault]:
    """Robot mode IDLE for 4 .. 10 simulated s, every 40 .. 100 simulated s up to ``horizon_s``."""
    stops, t = [], float(rng.uniform(20, 60))
    while t < horizon_s:
        length = float(rng.uniform(4, 10))
        stops.append(RobotFault(t, t + length, robot_mode=IDLE))
        t += length + float(rng.uniform(40, 100))
    return stops


@dataclass
class Strike:
    """A fault not on a request: when (``time.monotonic()``), what, until when (outages), and
    whether anything could see it."""

    t: float
    kind: str
    end: float = 0.0
    seen: bool = True


@dataclass
class Injector:
    """Strikes the simulated devices at random; ``strikes`` lists the faults that are not on a
    request (those are in each device's ``FaultPlan.applied``)."""

    sim: SimStation
    rng: random.Random
    opening: list[str] = field(default_factory=list)
    """Kinds (of ``MENU``) struck first, in this order, before the random draws."""
    strikes: list[Strike] = field(default_factory=list)
    _busy: set = field(default_factory=set)

    def strike(self) -> None:
        kind = self.opening.pop(0) if self.opening else self.rng.choice(MENU)
        if kind in self._busy:
            return
        if kind.endswith("request"):
            device = kind.split()[0].replace("modbus", "drawstring")
            plan = self.sim.devices[device].faults
            slack = device == "drawstring" and "cable slack" in self._busy  # a slack read must arrive
            if plan.pending == 0 and not slack:  # one fault at a time per device: each is an event
                options = [k for (d, k) in ON_REQUEST if d == device]
                plan.inject(self.rng.choice(options))
        elif kind == "cable slack":
            if self.sim.devices["drawstring"].faults.pending == 0:
                self._slack(self.rng.uniform(0.2, 1.0))
        else:
            self._outage(kind)

    def _slack(self, seconds: float) -> None:
        """The cable off for ``seconds``; seen if the drawstring was read meanwhile."""
        strike = Strike(time.monotonic(), "cable slack", time.monotonic() + seconds)
        self.strikes.append(strike)
        self._busy.add("cable slack")
        self.sim.slacken(seconds)

        def over():
            strike.seen = self.sim.slack_read > 0
            self._busy.discard("cable slack")

        threading.Timer(seconds + 0.05, over).start()

    def _outage(self, kind: str) -> None:
        """Unplug a device (or stop the controller) and bring it back after a random while."""
        device = OUTAGE_OF[kind]
        dev = self.sim.devices[device]
        if device != "robot" and dev.faults.pending:  # its fault would strike the unplugging itself
            return
        self._busy.add(kind)
        strike = Strike(time.monotonic(), kind)
        self.strikes.append(strike)
        if device == "robot":
            dev.stop()
            back, restore = self.rng.uniform(0.3, 1.0), dev.start  # the server takes ~1 s to start
        else:
            dev.unplug()
            back, restore = self.rng.uniform(0.2, 0.8), dev.replug

        def plug_back():
            restore()
            strike.end = time.monotonic()
            self._busy.discard(kind)

        threading.Timer(back, plug_back).start()

    def applied(self, plans: dict, stops: list[tuple[float, float]]) -> list[tuple[float, str]]:
        """Every fault that struck and could be seen, in time order: ``plans`` (each device's
        FaultPlan), ``stops`` (protective stops, real start and end: seen unless the controller
        was gone meanwhile)."""
        on_request = [(t, ON_REQUEST[(name, k)]) for name, plan in plans.items() for t, k in plan.applied]
        gone = [(s.t, s.end or float("inf")) for s in self.strikes if s.kind == "controller gone"]
        seen_stops = [
            (a, "protective stop") for a, b in stops if not any(g0 < b and a < g1 for g0, g1 in gone)
        ]
        strikes = [(s.t, s.kind) for s in self.strikes if s.seen]
        return sorted(strikes + on_request + seen_stops)

    def mark_unneeded_outages(self, log: list[tuple[float, str]]) -> None:
        """A sensor unplugged and back while the station did not need it (the robot moving, or
        dwelling at targets measured already: the station reads the sensors only at a target it
        still has to measure) went unseen."""
        measured = [
            (t, int(m.group(1))) for t, line in log if (m := re.match(r"sample \d+ target (\d+)", line))
        ]
        start = self.sim.clock.start_monotonic
        for s in self.strikes:
            if s.kind not in ("modbus unplugged", "dial unplugged"):
                continue
            done_before = {target for t, target in measured if t < s.t}
            states = (self.sim.robot.state(t - start) for t in np.arange(s.t, s.end or s.t, 0.01))
            s.seen = any(st.dwelling and st.target_index not in done_before for st in states)


def run_session(config: Path, out: Path, injector: Injector, interval_s: float, timeout_s: float):
    """``station sample`` in a child process while the injector strikes; (exit code, log lines
    with their arrival times)."""
    cmd = [sys.executable, "-m", "station.cli", "sample", "--config", str(config), "--out", str(out)]
    proc = subprocess.Popen(cmd, cwd=ROOT, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
    log: list[tuple[float, str]] = []
    reader = threading.Thread(target=lambda: log.extend((time.monotonic(), line) for line in proc.stdout))
    reader.start()
    deadline = time.monotonic() + timeout_s
    while not any(line.startswith("sample ") for _, line in log) and proc.poll() is None:
        time.sleep(0.05)  # the first sample: the devices are up and the session runs
    next_strike = time.monotonic() + injector.rng.expovariate(1.0 / interval_s)
    while proc.poll() is None and time.monotonic() < deadline:
        if time.monotonic() >= next_strike:
            injector.strike()
            next_strike = time.monotonic() + injector.rng.expovariate(1.0 / interval_s)
        time.sleep(0.02)
    if proc.poll() is None:
        proc.kill()
    reader.join(10)
    return proc.wait(10), log


def unlogged(faults: list[tuple[float, str]], log: list[tuple[float, str]]) -> list[tuple[float, str]]:
    """Faults no log line names: each line of a fault's kind names the latest fault of that kind
    before it that no earlier line named (a fault the station could not see, e.g. one applied to a
    request it had already given up on, then leaves no line that a later fault needs). A fault on a
    request counts as named by any line on that request's failure (``SAME_REQUEST``): on a loaded
    machine a bad CRC or a garbled reply arriving late is rightly a "no reply"."""
    named: set[int] = set()
    for tl, line in log:
        seen = [
            i
            for i, (t, kind) in enumerate(faults)
            if i not in named and t <= tl + 0.05 and re.search(SAME_REQUEST.get(kind, NAMED_BY[kind]), line)
        ]
        if seen:
            named.add(max(seen, key=lambda i: faults[i][0]))
    return [f for i, f in enumerate(faults) if i not in named]


def audit(folder: Path, log: list[tuple[float, str]], seed: int, per_line: int) -> dict:
    """Duplicates, torn rows, lost and corrupt readings of a finished session folder."""
    text = (folder / "samples.csv").read_text()
    lines = text.split("\n")
    width = len(lines[0].split(","))
    torn = sum(len(line.split(",")) != width for line in lines[1:-1]) + (lines[-1] != "")
    with (folder / "samples.csv").open(newline="") as fh:
        rows = [r for r in csv.DictReader(fh) if None not in r.values()]
    with (folder / "raw.csv").open(newline="") as fh:
        raw = collections.Counter(r["sample"] for r in csv.DictReader(fh))
    torn += sum(raw[r["sample"]] != K for r in rows)
    targets = [r["target"] for r in rows]
    samples = [r["sample"] for r in rows]
    duplicates = (len(targets) - len(set(targets))) + (len(samples) - len(set(samples)))
    announced = {m.group(1) for _, line in log if (m := re.match(r"sample (\d+) target", line))}
    world = make_cell(seed, per_line).world
    q = np.array([[float(r[f"q{i}_deg"]) for i in range(1, 7)] for r in rows])
    lines_ = np.array([int(r["line"]) for r in rows])
    length_err = np.array([float(r["length_mm"]) for r in rows]) - world.true_length_mm(q)
    dial_err = np.array([float(r["dial_mm"]) for r in rows]) - world.true_dial_mm(q, lines_)
    # 5 standard errors of a mean of K readings, plus half the 1 um resolution
    corrupt = (np.abs(length_err) > 5 * world.noise.length_mm / np.sqrt(K) + 0.0005) | (
        np.abs(dial_err) > 5 * world.noise.dial_mm / np.sqrt(K) + 0.0005
    )
    if corrupt.any():
        bad = [(r["sample"], r["target"]) for r, c in zip(rows, corrupt, strict=True) if c]
        print("corrupt samples (sample, target):", bad)
        print("length errors (mm):", length_err[corrupt], "dial errors (mm):", dial_err[corrupt])
    return {
        "measured": len(set(targets)),
        "duplicates": duplicates,
        "torn": int(torn),
        "lost": len(announced - set(samples)),
        "corrupt": int(corrupt.sum()),
    }


@dataclass
class Soak:
    """A finished soak: the audit ``result``, the session's ``log``, the ``faults`` that struck
    while it ran and those ``missing`` from its log, and when it started (``t0``)."""

    result: dict
    log: list[tuple[float, str]]
    faults: list[tuple[float, str]]
    missing: list[tuple[float, str]]
    t0: float


def soak(targets: int, seed: int, interval_s: float, timeout_s: float, opening: tuple[str, ...] = ()) -> Soak:
    """Run one session under faults (see the module notes) and audit it; ``opening``: the kinds
    (of ``MENU``) struck first, whatever the seed draws."""
    per_line = max(targets // 3, 2)
    with tempfile.TemporaryDirectory() as tmp:
        folder = Path(tmp)
        config = write_config(folder, 3 * per_line, seed)
        cfg = StationConfig.model_validate(tomllib.loads(config.read_text()))
        stops = protective_stops(np.random.default_rng([seed, 7]), timeout_s * TIME_SCALE)
        sim = SimStation(cfg, faults=stops)
        publish_plan(folder / "plan.csv", Plan.of(sim.plan_deg, sim.plan_lines))
        injector = Injector(sim, random.Random(seed), list(opening))
        sim.start()
        plans = {name: sim.devices[name].faults for name in ("drawstring", "dial")}
        t0 = time.monotonic()
        try:
            code, log = run_session(config, folder / "sess", injector, interval_s, timeout_s)
            seconds = time.monotonic() - t0
        finally:
            time.sleep(2.0)  # let pending replugs finish before the devices stop
            sim.stop()
        start = sim.clock.start_monotonic
        real = [(start + s.start_s / TIME_SCALE, start + s.end_s / TIME_SCALE) for s in stops]
        injector.mark_unneeded_outages(log)
        # the faults struck from the first sample (when the strikes begin) to the session's end
        began = next((t for t, line in log if line.startswith("sample ")), t0 + seconds)
        ended = next((t for t, line in log if re.match(r"(done|stopped|timed out): ", line)), t0 + seconds)
        faults = [f for f in injector.applied(plans, real) if began < f[0] < ended]
        missing = unlogged(faults, log)
        result = {
            "targets": 3 * per_line,
            **audit(folder / "sess", log, seed, per_line),
            "faults_injected": dict(collections.Counter(kind for _, kind in faults)),
            "suspensions": sum(line.startswith("suspended:") for _, line in log),
            "unlogged": dict(collections.Counter(kind for _, kind in missing)),
            "exit": code,
            "seconds": round(seconds, 1),
            "seed": seed,
        }
    return Soak(result, log, faults, missing, t0)


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--targets", type=int, default=60, help="targets of the plan (3 gauge lines)")
    parser.add_argument("--seed", type=int, default=0, help="seed of the cell and of every fault")
    parser.add_argument("--interval-s", type=float, default=1.0, help="mean time between faults, real s")
    parser.add_argument(  # 60 targets: 90 s on a quiet machine, 200-400 s with two busy loops beside it
        "--timeout-s", type=float, default=900.0, help="give up after this long, real s"
    )
    parser.add_argument("--json", action="store_true", help="end with one JSON line")
    parser.add_argument("--log", type=Path, help="write the session's log and the faults here")
    args = parser.parse_args()
    run = soak(args.targets, args.seed, args.interval_s, args.timeout_s)
    r = run.result
    if args.log:  # the session's log and the faults, in time order (s since the session started)
        marks = [(t, f"FAULT {k}{' (unlogged)' if (t, k) in run.missing else ''}\n") for t, k in run.faults]
        args.log.write_text("".join(f"{t - run.t0:8.3f} {line}" for t, line in sorted([*run.log, *marks])))
    print(
        f"{r['measured']}/{r['targets']} targets measured in {r['seconds']:.0f} s under "
        f"{sum(r['faults_injected'].values())} faults of {len(r['faults_injected'])} kinds; "
        f"{r['suspensions']} suspensions; duplicates {r['duplicates']}, torn {r['torn']}, lost {r['lost']}, "
        f"corrupt {r['corrupt']}, unlogged {sum(r['unlogged'].values())}; exit {r['exit']}"
    )
    if args.json:
        print(json.dumps(r))
    clean = not (r["duplicates"] or r["torn"] or r["lost"] or r["corrupt"] or r["unlogged"])
    return 0 if r["measured"] == r["targets"] and r["exit"] == 0 and clean else 1


if __name__ == "__main__":
    sys.exit(main())
