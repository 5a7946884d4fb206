"""A sweep session's figures (issue 37): robot time, wall time, rows, flags, the drawstring's
latency estimate against the simulated truth, and the stored joints' timing against the truth.

    python benchmarks/sweep_session.py [--per-line 30] [--passes 2] [--rounds 3] [--time-scale 5]
        [--stated-latency-s 0.004] [--rows-per-s 60]

The simulated JR680 cell (seed 0) sweeps a plan of ``--per-line`` waypoints on each of its three
gauge lines in ``--passes`` passes a line, each line ``--rounds`` times with other orientations
(``World.sweep_configurations``), the simulated devices
in this process (as ``station demo`` runs them), the drawstring with a true latency of 4 ms. The
session (``station.acquire.runner``) runs in this process too; reported:

- robot time: simulated seconds from the first stored pass's start to the last one's end
  (``session.toml robot_time_s``), and the wall time of the session;
- rows stored, rows flagged (by reason), rows per wall second;
- the drawstring's latency: stated, estimated (+- its standard error), true;
- timing of the stored joints: for each row the time shift (real s) that brings the simulated true
  joints closest to the stored ones (median and 5/95 percentiles; rows where the robot moves);
"""

from __future__ import annotations

import argparse
import random
import socket
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
import tomli_w

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
from sim_fixtures.station_sim import SimStation  # noqa: E402
from sim_fixtures.world import World  # noqa: E402
from station.acquire import runner  # noqa: E402
from station.commands.sim import publish_plan  # noqa: E402
from station.config import StationConfig  # noqa: E402
from station.formats.base import read_toml  # noqa: E402
from station.formats.plan import Plan  # noqa: E402
from station.formats.samples import load_samples  # noqa: E402

START_S = 6.0  # real s the simulated robot holds at its first waypoint while the session starts


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def config(folder: Path, time_scale: float, stated_s: float, rows_per_s: float) -> Path:
    raw = {
        "time_scale": time_scale,
        "robot": {"kind": "rtde", "host": f"127.0.0.{random.randint(2, 250)}"},
        "drawstring": {"kind": "modbus_tcp", "port": _free_port()},
        "dial": {"port": str(folder / "dial")},
        "session": {"plan": str(folder / "plan.csv")},
        "sweep": {"drawstring_latency_s": stated_s, "rows_per_s": rows_per_s},
        "sim": {
            "dwell_s": 0.5,
            "speed_deg_s": 60.0,
            "accel_deg_s2": 240.0,
            "plan_csv": str(folder / "plan.csv"),
        },
    }
    path = folder / "station.toml"
    path.write_text(tomli_w.dumps(raw))
    return path


class _Quiet:
    def isatty(self) -> bool:
        return False

    def write(self, text: str) -> None:
        print(text, end="")

    def flush(self) -> None:
        pass


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--per-line", type=int, default=30)
    ap.add_argument("--passes", type=int, default=2)
    ap.add_argument("--rounds", type=int, default=3, help="sweeps of each line, each its own orientations")
    ap.add_argument("--time-scale", type=float, default=5.0)
    ap.add_argument("--stated-latency-s", type=float, default=0.004)
    ap.add_argument("--rows-per-s", type=float, default=60.0)
    args = ap.parse_args()
    q, lines, passes = World.create(0).sweep_configurations(
        args.per_line, args.passes, np.random.default_rng(1), 15.0, args.rounds
    )
    plan = Plan(np.arange(len(lines)), lines, q, sweep_pass=passes)
    with tempfile.TemporaryDirectory() as tmp:
        folder = Path(tmp)
        path = config(folder, args.time_scale, args.stated_latency_s, args.rows_per_s)
        cfg = StationConfig.model_validate(read_toml(path))
        sim = SimStation(cfg, plan=(plan.q_deg, plan.line, plan.sweep_pass), start_delay_s=START_S)
        publish_plan(Path(cfg.sim.plan_csv), plan)
        sim.start()
        try:
            t0 = time.monotonic()
            inputs = runner.new_session(folder / "sess", path, None)
            done = runner.run(inputs, stream=_Quiet())
            wall = time.monotonic() - t0
            done.view.close()
        finally:
            sim.stop()
        header = read_toml(folder / "sess" / "session.toml")
        rows = load_samples(folder / "sess" / "samples.csv")
        shifts = _timing(sim, folder / "sess" / "samples.csv")
    latency = header.get("latency", {}).get("drawstring", {})
    print(
        f"\nplan: {len(plan)} waypoints, {len(set(passes.tolist()))} passes; time scale {args.time_scale:g}"
    )
    print(f"robot time {header['robot_time_s']:.1f} s (simulated); session wall time {wall:.1f} s")
    print(f"rows {len(rows)} ({len(rows) / wall:.0f} per wall s); flagged {header.get('flagged', {})}")
    print(
        f"drawstring latency: stated {args.stated_latency_s * 1e3:.1f} ms, estimated "
        f"{latency.get('estimated_s', np.nan) * 1e3:.2f} +- {latency.get('sigma_s', np.nan) * 1e3:.2f} ms, "
        f"true {cfg.sim.drawstring_latency_s * 1e3:.1f} ms (simulated)"
    )
    print(
        f"stored joints' timing against the truth (real ms): median {np.median(shifts):+.3f}, 5-95 % "
        f"{np.percentile(shifts, 5):+.3f} .. {np.percentile(shifts, 95):+.3f} ({len(shifts)} moving rows)"
    )


def _timing(sim: SimStation, samples: Path) -> np.ndarray:
    """Per row where the robot moves: the shift [real ms] of the true joints' time that best matches
    the stored joints."""
    import csv

    wall_minus_mono = time.time() - time.monotonic()
    grid = np.linspace(-0.004, 0.004, 161)
    out = []
    with samples.open(newline="") as fh:
        for r in csv.DictReader(fh):
            t = float(r["t_wall_s"]) - wall_minus_mono - sim.clock.start_monotonic
            if float(r["q_spread_deg"]) == 0.0:
                continue
            q = np.array([float(r[f"q{i}_deg"]) for i in range(1, 7)])
            errs = [np.max(np.abs(sim.robot.state(t + d).q_deg - q)) for d in grid]
            out.append(grid[int(np.argmin(errs))] * 1e3)
    return np.array(out)


if __name__ == "__main__":
    main()
