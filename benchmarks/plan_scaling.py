"""Memory and time of a session's plan path as the plan grows (issue 21 item 5).

    python benchmarks/plan_scaling.py [--points 20000] [--targets 100000] [--samples 6]

- ``livefit.line_segments`` (the live view's gauge-line segments) on ``--points`` TCPs on one
  line: time and the peak of numpy's allocations (tracemalloc);
- the whole ``station sample --plan`` command (a child process) with a plan of ``--targets``
  targets, and with the simulated robot's own small plan for comparison: the simulated station
  (``sim_fixtures.station_sim``, 3 targets per line, simulated time x30) runs in this process; the
  large plan holds the robot's 9 targets and, in between, joint-space interpolations along each
  line (so the live view draws real lines). The session is stopped (SIGINT) after ``--samples``
  samples; reported: seconds to the first sample, to the stop, and the child's peak RSS
  (``os.wait4``).
"""

from __future__ import annotations

import argparse
import os
import random
import signal
import socket
import subprocess
import sys
import tempfile
import threading
import time
import tracemalloc
from pathlib import Path

import numpy as np
import tomli_w
import tomllib

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
from sim_fixtures.station_sim import SimStation  # noqa: E402
from station.acquire.livefit import line_segments  # noqa: E402
from station.commands.sim import publish_plan  # noqa: E402
from station.config import StationConfig  # noqa: E402
from station.formats.plan import Plan  # noqa: E402

PER_LINE = 3


def segments_cost(n_points: int) -> tuple[float, float]:
    """(seconds, peak MB of traced allocations) of ``line_segments`` on ``n_points`` on one line."""
    rng = np.random.default_rng(0)
    tcp = np.outer(rng.uniform(-200, 200, n_points), [0.6, 0.8, 0.0]) + rng.normal(0, 0.01, (n_points, 3))
    ids = np.zeros(n_points, int)
    tracemalloc.start()
    t0 = time.perf_counter()
    line_segments(tcp, ids)
    seconds = time.perf_counter() - t0
    peak = tracemalloc.get_traced_memory()[1]
    tracemalloc.stop()
    return seconds, peak / 1e6


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def write_config(folder: Path) -> Path:
    raw = {
        "time_scale": 30.0,
        "robot": {"kind": "rtde", "host": f"127.0.0.{random.randint(2, 250)}"},
        "drawstring": {"kind": "modbus_tcp", "port": _free_port()},
        "dial": {"port": str(folder / "dial")},
        "session": {"plan": str(folder / "plan.csv")},
        "sim": {
            "speed_deg_s": 120.0,
            "accel_deg_s2": 480.0,
            "dwell_s": 2.0,
            "targets_per_line": PER_LINE,
            "plan_csv": str(folder / "plan.csv"),
        },
    }
    path = folder / "station.toml"
    path.write_text(tomli_w.dumps(raw))
    return path


def large_plan(small: Plan, n_targets: int) -> Plan:
    """``small``'s targets and, between each line's first and last, joint-space interpolations up
    to ``n_targets`` in all (target ids after ``small``'s)."""
    lines = np.unique(small.line)
    fill = (n_targets - len(small)) // len(lines)
    q, line = [small.q_deg], [small.line]
    for lid in lines:
        ends = small.q_deg[small.line == lid][[0, -1]]
        t = np.linspace(0.0, 1.0, fill + 2)[1:-1, None]
        q.append(ends[0] + t * (ends[1] - ends[0]))
        line.append(np.full(fill, lid))
    q, line = np.concatenate(q), np.concatenate(line)
    return Plan(np.arange(len(q)), line, q)


def session_cost(config: Path, plan: Path, out: Path, samples: int, timeout_s: float) -> dict:
    """Run ``station sample --plan`` until ``samples`` samples, then SIGINT: seconds to the first
    sample and to the end, the child's peak RSS [MB] and exit code."""
    cmd = [sys.executable, "-m", "station.cli", "sample", "--config", str(config), "--plan", str(plan)]
    t0 = time.monotonic()
    proc = subprocess.Popen(
        [*cmd, "--out", str(out)], cwd=ROOT, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True
    )
    log: list[tuple[float, str]] = []
    reader = threading.Thread(target=lambda: log.extend((time.monotonic(), line) for line in proc.stdout))
    reader.start()
    deadline = t0 + timeout_s
    while proc.poll() is None and time.monotonic() < deadline:
        if sum(line.startswith("sample ") for _, line in log) >= samples:
            proc.send_signal(signal.SIGINT)
            break
        time.sleep(0.05)
    else:
        if proc.poll() is None:
            proc.kill()
    _, status, usage = os.wait4(proc.pid, 0)
    reader.join(10)
    first = next((t for t, line in log if line.startswith("sample ")), None)
    return {
        "first_sample_s": None if first is None else first - t0,
        "total_s": time.monotonic() - t0,
        "peak_rss_mb": usage.ru_maxrss / 1024,
        "exit": os.waitstatus_to_exitcode(status),
        "samples": sum(line.startswith("sample ") for _, line in log),
        "tail": [line.rstrip() for _, line in log[-3:]],
    }


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--points", type=int, default=20000)
    parser.add_argument("--targets", type=int, default=100000)
    parser.add_argument("--samples", type=int, default=6)
    parser.add_argument("--timeout-s", type=float, default=300.0)
    args = parser.parse_args()
    for n in (2000, args.points):
        seconds, peak = segments_cost(n)
        print(f"line_segments, {n} points on one line: {seconds * 1e3:.1f} ms, peak {peak:.1f} MB allocated")
    with tempfile.TemporaryDirectory() as tmp:
        folder = Path(tmp)
        config = write_config(folder)
        sim = SimStation(StationConfig.model_validate(tomllib.loads(config.read_text())))
        small = Plan.of(sim.plan_deg, sim.plan_lines)
        publish_plan(folder / "plan.csv", small)
        big = folder / "big.csv"
        big.write_text(large_plan(small, args.targets).csv_text())
        sim.start()
        try:
            runs = ((f"{len(small)} targets", folder / "plan.csv"), (f"{args.targets} targets", big))
            for name, plan in runs:
                r = session_cost(config, plan, folder / name.replace(" ", "-"), args.samples, args.timeout_s)
                first = "none" if r["first_sample_s"] is None else f"{r['first_sample_s']:.1f} s"
                print(
                    f"station sample --plan ({name}): first sample after {first}, stopped after "
                    f"{r['samples']} samples at {r['total_s']:.1f} s (exit {r['exit']}), "
                    f"peak RSS {r['peak_rss_mb']:.0f} MB"
                )
                if r["exit"] != 130:
                    print("  " + "\n  ".join(r["tail"]))
        finally:
            sim.stop()


if __name__ == "__main__":
    main()
