"""``station history ROBOT --plot`` on long histories: wall time and peak memory of the command
(a fresh interpreter each, imports included) per history size.

The database: one real ``station calibrate`` record (a simulated JR680 cell, 3 lines x 50 poses;
its report is the record's figures, about 12 kB), then records inserted in one transaction, 6 h
apart: every fourth a calibration (the real report, its parameters walking by a tenth of their
sigma, a step of 5 sigma on J2.a_mm every 400th), the others verifications (holds, one in ten
drifted). Usage: ``python benchmarks/history_plot.py [--records 100 1000 10000] [--keep DIR]``
(``--keep``: the databases and PNGs stay there to look at).

Measured (issue 34, the shared 2-core machine at load ~1, one run each), wall time and peak RSS:

| records | before (828c45d: a plot call, a tick label per record) | after (a call per series, dates) |
|---|---|---|
| 100 | 1.47 s, 97 MB | 1.08 s, 93 MB |
| 1,000 | 7.97 s, 141 MB | 0.94 s, 104 MB |
| 10,000 | 113 s, 570 MB | 1.73 s, 209 MB |

At 10,000 records, reading them (``history.records``: the 2,500 calibrations' reports parsed)
takes 0.6 s and 147 MB of that.
"""

from __future__ import annotations

import argparse
import contextlib
import io
import json
import sqlite3
import subprocess
import sys
import tempfile
import time
from datetime import datetime, timedelta
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from sim_fixtures.scenario import write_scenario  # noqa: E402
from station.cli import main as station  # noqa: E402

ROBOT = "HSR-JR680"
COLUMNS = "robot, robot_name, time_utc, command, samples, table_path, table_hash, verdict, rmse_mm, figures"
MEASURE = (
    "import resource, sys; from station.cli import main; code = main(sys.argv[1:]); "
    "print(code, resource.getrusage(resource.RUSAGE_SELF).ru_maxrss)"
)


def seed(folder: Path) -> Path:
    """A history holding one real calibration of robot ``ROBOT`` (``station calibrate``'s record)."""
    cell = write_scenario(folder / "cell", seed=3, n_lines=3, n_per_line=50)
    db = folder / "seed.sqlite"
    flags = ["--robot", str(cell.robot), "--setup", str(cell.setup), "--db", str(db)]
    with contextlib.redirect_stdout(io.StringIO()):
        assert station(["calibrate", str(cell.samples), "--out", str(folder / "t.toml"), *flags]) == 0
    return db


def build(seed_db: Path, db: Path, records: int) -> None:
    """``seed_db`` copied to ``db`` (SQLite's backup) and grown to ``records`` records, 6 h apart."""
    src, conn = sqlite3.connect(seed_db), sqlite3.connect(db)
    src.backup(conn)
    src.close()
    first = conn.execute(f"SELECT {COLUMNS} FROM records").fetchone()
    report = json.loads(first[-1])
    start = datetime.fromisoformat(first[2])
    rows = [_row(first, report, k, start + timedelta(hours=6 * k)) for k in range(1, records)]
    with conn:
        conn.executemany(f"INSERT INTO records ({COLUMNS}) VALUES ({', '.join('?' * 10)})", rows)
    conn.close()


def _row(first: tuple, report: dict, k: int, when: datetime) -> tuple:
    """Record ``k``: a calibration every fourth (parameters walked), else a verification."""
    stamp = when.isoformat(timespec="seconds")
    if k % 4:
        verdict = "drifted" if k % 10 == 3 else "holds"
        rmse = 0.02 + 0.001 * (k % 7)
        figures = json.dumps({"verdict": verdict, "rmse_mm": rmse})
        return (*first[:2], stamp, "verify", f"v{k}.csv", *first[5:7], verdict, rmse, figures)
    params = {}
    for name, p in report["parameters"].items():
        step = 5 * p["sigma"] * (k // 400) if name == "J2.a_mm" else 0.1 * p["sigma"] * ((k * 7919) % 3 - 1)
        params[name] = {**p, "value": p["value"] + step}
    figures = {**report, "parameters": params}
    return (*first[:2], stamp, "calibrate", f"s{k}.csv", *first[5:8], first[8], json.dumps(figures))


def measure(db: Path, png: Path) -> tuple[float, float]:
    """Wall seconds and peak RSS [MB] of ``station history ROBOT --db DB --plot PNG``, a process of
    its own (interpreter start and imports included)."""
    argv = ["history", ROBOT, "--db", str(db), "--plot", str(png)]
    t = time.perf_counter()
    done = subprocess.run([sys.executable, "-c", MEASURE, *argv], capture_output=True, text=True, check=True)
    seconds = time.perf_counter() - t
    code, rss_kb = done.stdout.split()[-2:]
    assert code == "0", done.stderr
    return seconds, int(rss_kb) / 1024


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--records", type=int, nargs="+", default=[100, 1000, 10000])
    p.add_argument("--keep", type=Path, help="folder to leave the databases and PNGs in")
    args = p.parse_args(argv)
    with tempfile.TemporaryDirectory() as tmp:
        folder = args.keep or Path(tmp)
        folder.mkdir(parents=True, exist_ok=True)
        seed_db = seed(folder)
        for n in args.records:
            build(seed_db, folder / f"h{n}.sqlite", n)
            seconds, mb = measure(folder / f"h{n}.sqlite", folder / f"h{n}.png")
            print(f"{n:>6} records: station history --plot {seconds:.2f} s, peak RSS {mb:.0f} MB")
    return 0


if __name__ == "__main__":
    sys.exit(main())
