"""Two simulated cells on one machine, started at once on the same addresses (issue 20, item 8:
``station demo`` twice): each binds first and then announces where it serves, so neither fails
("cannot bind RTDE ... 30004") and each station reads its own cell. Addresses are a random
127.0.0.x and a free port, never the contract's (other tests run beside this one)."""

from __future__ import annotations

import copy
import json
import subprocess
import sys
import threading

import tomli_w
import tomllib

from sim_fixtures.station_sim import SimStation
from station.commands.demo import serve_at
from station.config import StationConfig
from tests.system.test_session import ROOT, write_config


def test_two_cells_started_at_once_on_the_same_addresses_each_serve_and_read_their_own(tmp_path):
    raw = tomllib.loads(write_config(tmp_path).read_text())
    sims = {name: SimStation(StationConfig.model_validate(raw), start_delay_s=1e6) for name in "ab"}
    served, failed = {}, {}

    def start(name):
        (tmp_path / name).mkdir()
        try:
            served[name] = sims[name].start(elsewhere=tmp_path / name)
        except Exception as exc:  # noqa: BLE001 - the test reports it
            failed[name] = exc

    starts = [threading.Thread(target=start, args=(name,)) for name in sims]
    try:
        for t in starts:
            t.start()
        for t in starts:
            t.join(60)
        assert not failed, failed
        configs, notes = {}, {}
        for name in sims:
            cell = copy.deepcopy(raw)
            notes[name] = serve_at(cell, served[name])
            configs[name] = tmp_path / f"{name}.toml"
            configs[name].write_text(tomli_w.dumps(cell))
        readings = {
            name: subprocess.run(
                [sys.executable, "-m", "station.cli", "read", "--config", str(path)],
                cwd=ROOT,
                capture_output=True,
                text=True,
                timeout=60,
            )  # fmt: skip
            for name, path in configs.items()
        }
    finally:
        for sim in sims.values():
            sim.stop()
    # one cell has the configured addresses, the other moved every device and said so
    assert sorted(len(n) for n in notes.values()) == [0, 3], notes
    moved = next(name for name in sims if notes[name])
    assert notes[moved][0].endswith(f"serves {served[moved][0]['host']}:30004")
    assert served["a"][0]["host"] != served["b"][0]["host"]
    assert served["a"][1]["port"] != served["b"][1]["port"]
    assert served["a"][2]["port"] != served["b"][2]["port"]
    for name, result in readings.items():
        assert result.returncode == 0, result.stderr
        assert set(json.loads(result.stdout)["devices"]) == {"robot", "drawstring", "dial"}, name
