"""``station demo [--out DIR] [--viewer/--no-viewer]``: the operator's whole job on simulated devices.

Starts the simulated devices (the machinery of ``station sim serve``: RTDE controller in a child
process, Modbus TCP drawstring, serial dial on a pty) on the contract's addresses, or on free ones
when those are taken; runs a session over the simulated cell's plan (3 gauge lines x 70 targets)
with simulated time running ``TIME_SCALE`` times faster; calibrates the session folder (LMLC,
and MCS-LMLC beside it when available) with a simulated hold-out set; writes ``DIR/session/``,
``DIR/corrected.toml`` and ``DIR/report.json``; prints before -> after and the simulated truth.
"""

from __future__ import annotations

import argparse
import json
import random
import socket
from pathlib import Path

from errors import DeviceError, InputError
from station.commands.calibrate import summary

TIME_SCALE = 40.0
CONTRACT = {"rtde": ("127.0.0.1", 30004), "modbus": ("127.0.0.1", 5020), "dial": "/tmp/station-sim/dial"}


def register(sub) -> None:
    p = sub.add_parser("demo", help="the whole job on simulated devices: session -> calibration -> report")
    p.add_argument("--out", type=Path, default=Path("demo-out"), help="output folder (default ./demo-out)")
    p.add_argument(
        "--viewer",
        action=argparse.BooleanOptionalAction,
        default=False,
        help="open the Rerun viewer (needs a display; the .rrd is saved either way)",
    )
    p.add_argument("--seed", type=int, default=0, help=argparse.SUPPRESS)
    p.add_argument("--targets-per-line", type=int, default=70, help=argparse.SUPPRESS)
    p.set_defaults(func=run)


def run(args) -> int:
    import tomli_w

    from sim_fixtures.station_sim import SimStation
    from station.acquire import runner
    from station.acquire.session import State
    from station.config import StationConfig
    from station.formats.base import atomic_write, check_writable
    from station.formats.plan import Plan

    out = args.out
    if (out / "session").exists():
        raise InputError(f"{out / 'session'}: exists already; choose another --out or remove it")
    out.mkdir(parents=True, exist_ok=True)
    check_writable(out / "report.json", "--out")
    raw, notes = demo_config(out, args.seed, args.targets_per_line)
    for note in notes:
        print(note)
    config_path = out / "station.toml"
    atomic_write(config_path, tomli_w.dumps(raw))
    sim = SimStation(StationConfig.model_validate(raw))
    try:
        sim.start()
    except (OSError, RuntimeError) as exc:
        raise DeviceError(f"cannot start the simulated devices: {exc}") from exc
    try:
        plan_path = out / "plan.csv"
        atomic_write(plan_path, Plan.of(sim.plan_deg, sim.plan_lines).csv_text())
        inputs = runner.new_session(out / "session", config_path, plan_path)
        print(
            f"session of {len(inputs.plan)} targets on 3 gauge lines -> {inputs.folder.path} "
            f"(simulated time x{TIME_SCALE:g})"
        )
        state, view = runner.run(inputs, viewer=args.viewer)
    finally:
        sim.stop()
    try:
        if state is not State.DONE:
            print(f"session {state.value}: calibrating the {len(inputs.folder.rows)} samples taken")
        return _calibrate(out, inputs, view, args.seed, args.targets_per_line)
    finally:
        view.close()


def demo_config(out: Path, seed: int, targets_per_line: int) -> tuple[dict, list[str]]:
    """The demo's station config: contract addresses where free, else free ones (with a note)."""
    notes = []
    rtde_host = CONTRACT["rtde"][0]
    if not _free(*CONTRACT["rtde"]):
        rtde_host = next(
            h for h in (f"127.0.0.{random.randint(2, 250)}" for _ in range(50)) if _free(h, 30004)
        )
        notes.append(f"RTDE 127.0.0.1:30004 is taken: the simulated controller serves {rtde_host}:30004")
    modbus_port = CONTRACT["modbus"][1]
    if not _free(*CONTRACT["modbus"]):
        modbus_port = _free_port()
        notes.append(
            f"Modbus 127.0.0.1:5020 is taken: the simulated drawstring serves 127.0.0.1:{modbus_port}"
        )
    dial = Path(CONTRACT["dial"])
    if dial.exists() or dial.is_symlink():
        dial = (out / "dial-pty").resolve()
        notes.append(f"{CONTRACT['dial']} is in use: the simulated dial is at {dial}")
    raw = {
        "time_scale": TIME_SCALE,
        "robot": {"kind": "rtde", "host": rtde_host},
        "drawstring": {"kind": "modbus_tcp", "host": "127.0.0.1", "port": modbus_port},
        "dial": {"port": str(dial)},
        "session": {"target_timeout_s": 1200.0},  # over one robot cycle: a missed target comes round
        "sim": {
            "seed": seed,
            "speed_deg_s": 120.0,
            "accel_deg_s2": 480.0,
            "dwell_s": 2.5,
            "targets_per_line": targets_per_line,
        },
    }
    return raw, notes


def _free(host: str, port: int) -> bool:
    with socket.socket() as s:
        try:
            s.bind((host, port))
        except OSError:
            return False
    return True


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def _calibrate(out: Path, inputs, view, seed: int, targets_per_line: int) -> int:
    import numpy as np

    from sim_fixtures.station_sim import make_cell
    from station.formats.base import atomic_write, toml_text
    from station.formats.samples import load_samples
    from station.jobs import calibration
    from station.jobs.report import corrected_table

    world = make_cell(seed, targets_per_line).world
    holdout_path = out / "holdout.csv"
    world.sample_set(max(targets_per_line // 4, 2), np.random.default_rng([seed, 4])).to_csv(holdout_path)
    samples, holdout = load_samples(inputs.folder.samples_csv), load_samples(holdout_path)
    where = str(inputs.folder.path / "session.toml")
    methods = [m for m in ("lmlc", "mcs-lmlc") if m in calibration.METHODS]
    outcomes = {}
    for method in methods:
        outcome = calibration.calibrate_samples(
            samples, inputs.robot, inputs.setup, setup_where=where, holdout=holdout, method=method
        )
        outcomes[method] = outcome
        cal = outcome.calibration
        view.calibration(
            method,
            outcome.model.row_error_mm(cal.before.x),
            outcome.model.row_error_mm(cal.x),
            [it.cost for it in cal.after.history],
        )
        print(summary(outcome.report))
        print(truth_line(world, outcome))
    main_outcome = outcomes["lmlc"]
    table = corrected_table(inputs.robot, main_outcome.calibration, samples, "lmlc")
    atomic_write(out / "corrected.toml", toml_text(table))
    atomic_write(out / "report.json", json.dumps(main_outcome.report.as_json(), indent=2) + "\n")
    for method, outcome in outcomes.items():
        if method != "lmlc":
            report = json.dumps(outcome.report.as_json(), indent=2) + "\n"
            atomic_write(out / f"report-{method}.json", report)
    print(f"wrote {out / 'corrected.toml'}, {out / 'report.json'} and {inputs.folder.rrd}")
    return 0


def truth_line(world, outcome) -> str:
    """Workspace TCP error against the simulated truth, nominal vs corrected (rigid base re-fit)."""
    import numpy as np

    from calib.kinematics import dh_table, tcp_position
    from calib.metrics import aligned_errors

    q = world.random_configurations(1000, np.random.default_rng(7))
    p_true = world.true_tcp_mm(q)
    cal = outcome.calibration
    rms = [
        float(
            np.sqrt(
                np.mean(aligned_errors(tcp_position(dh_table(x), np.radians(q), np.zeros(3)), p_true) ** 2)
            )
        )
        for x in (cal.before.x, cal.x)
    ]
    return f"true workspace error over 1000 random poses (simulation): {rms[0]:.3f} -> {rms[1]:.3f} mm RMS"
