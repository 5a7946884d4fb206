"""``station demo [--out DIR] [--viewer/--no-viewer]``: the operator's workflow on simulated devices.

The steps a user takes at a real station, each with a one-line summary:

1. plan: ``station plan`` on the shipped robot and the simulated setup's gauge lines -> ``plan.csv``;
2. the simulated devices (the machinery of ``station sim serve``: RTDE controller in a child
   process, Modbus TCP drawstring, serial dial on a pty) on the contract's addresses, or free ones
   when those are taken; the simulated robot walks the plan, each pose moved onto its true line;
3. session: ``station sample`` with the running calibration, simulated time ``TIME_SCALE`` times
   faster -> ``session/`` (samples, ``session.rrd``);
4. calibrate: LMLC and MCS-LMLC on the session, with a simulated hold-out set -> ``corrected.toml``,
   ``report.json``, ``report-mcs-lmlc.json``, each with the simulated truth beside it;
5. export: the corrected table as URDF beside ``corrected.toml``;
6. verify: a second, short simulated session (``station plan --verify``'s poses) judged with the
   table just written (holds) and with the nominal table (drifted) -> ``verify.csv``,
   ``verify.json``, ``verify-nominal.json``.

``--sweep``: the same cell measured by sweeps: ``station plan --sweep`` (``SWEEP_PASSES`` passes per
line and ``SWEEP_EXTRA`` more where they promise most), the simulated robot sweeping each pass at
the plan's TCP speed, ``station sample`` streaming rows along it; LMLC alone calibrates (MCS
chooses among static poses, not among a stream's rows); steps 1-5 (the verification is a static session's).
Either way the demo prints its robot time: the simulated seconds the robot program takes to walk
the plan once (every move, dwell and sweep, back to its start).
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path
from typing import TYPE_CHECKING

from calib.methods import DEFAULT_TERM_MODEL
from errors import DeviceError, InputError
from station.commands.flags import parameters_as_flags, seed

DEMO_FLAGS = {"n_select": "--plan-size", "per_line": "the candidates per line (station plan --per-line)"}
"""The planning job's parameters as the demo's user sets them."""

if TYPE_CHECKING:
    from station.acquire.runner import SessionRun
    from station.formats.plan import Plan

TIME_SCALE = 40.0
SWEEP_TIME_SCALE = 1.0  # real time, as a cell sweeps: faster, a reading's round trip spans more of the sweep
START_S = 4.0  # the simulated robot waits at its first target while the session starts
HOLDOUT_PER_LINE = 12
SWEEP_PASSES = 2  # per gauge line ...
SWEEP_EXTRA = 2  # ... then these more, on the lines that promise most: about 115 s of robot time
SWEEP_DWELL_S = 1.0  # the simulated robot's stop at each end of a pass
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
    p.add_argument(
        "--seed", type=seed, default=0, help="the simulated cell: true robot, gauge lines, noise (default 0)"
    )
    p.add_argument(
        "--sweep",
        action="store_true",
        help="measure by sweeps: continuous passes along each gauge line, the station streaming",
    )
    p.add_argument(
        "--plan-size",
        type=int,
        metavar="N",
        help="poses the plan selects (default: where MCS's O1 flattens; fewer: a shorter demo)",
    )
    p.set_defaults(func=run)


def run(args) -> int:
    import tomli_w

    from sim_fixtures.station_sim import SimStation
    from station.acquire import runner
    from station.config import StationConfig
    from station.formats.base import atomic_write, check_writable

    out = args.out
    if (out / "session").exists():
        raise InputError(f"{out / 'session'}: exists already; choose another --out or remove it")
    out.mkdir(parents=True, exist_ok=True)
    check_writable(out / "report.json", "--out")
    raw = demo_config(args.seed, sweep=args.sweep)
    config_path = out / "station.toml"
    atomic_write(config_path, tomli_w.dumps(raw))
    plan = _sweep_plan(out, config_path) if args.sweep else _plan(out, config_path, args.plan_size)
    sim = SimStation(
        StationConfig.model_validate(raw),
        plan=(plan.q_deg, plan.line, plan.sweep_pass),
        start_delay_s=START_S,
    )
    print(
        f"robot:     {sim.robot.cycle_s:.1f} s of robot time (simulated: the program walks the plan once, "
        "every move, dwell and sweep)",
        flush=True,
    )
    try:  # bound first (where the contract's addresses are taken: free ones), then announced
        served = sim.start(elsewhere=out.resolve())
    except (OSError, RuntimeError) as exc:
        raise DeviceError(f"cannot start the simulated devices: {exc}") from exc
    try:
        for note in serve_at(raw, served):
            print(note)
        atomic_write(config_path, tomli_w.dumps(raw))
        inputs = runner.new_session(out / "session", config_path, out / "plan.csv")
        session = _session(inputs, args.viewer)
    finally:
        sim.stop()
    try:
        methods = ("lmlc",) if args.sweep else ("lmlc", "mcs-lmlc")
        outcome = _calibrate(out, inputs, session.view, args.seed, methods)
    finally:
        session.view.close()
    _export(out)
    if not args.sweep:
        _verify(out, inputs, args.seed)
    return outcome


def _plan(out: Path, config_path: Path, plan_size: int | None) -> Plan:
    """Step 1: ``station plan`` on the session's robot and setup (the shipped ones)."""
    from station.acquire import runner
    from station.config import load_station_config
    from station.formats.base import atomic_write
    from station.formats.tables import load_robot, load_setup
    from station.jobs import planning

    t0 = time.perf_counter()
    cfg = load_station_config(config_path)
    robot = load_robot(runner.resolve(cfg.session.robot_model, config_path))
    setup_path = runner.resolve(cfg.session.setup, config_path)
    setup = load_setup(setup_path)
    readings = cfg.session.readings
    with parameters_as_flags(DEMO_FLAGS):
        design = planning.design(
            robot, setup, str(setup_path), n_select=plan_size, suggest=False, readings=readings
        )
    atomic_write(out / "plan.csv", design.plan.csv_text())
    promise = design.report["predicted"]["plan"]
    print(
        f"plan:      {len(design.plan)} poses on {len(set(design.plan.line.tolist()))} gauge lines, "
        f"promising {promise['predicted_rmse_mm']:.3f} mm workspace error "
        f"(95 %: {promise['predicted_rmse_95_mm']:.3f} mm) at the stated noise, {readings} readings per "
        f"capture -> {out / 'plan.csv'} "
        f"({time.perf_counter() - t0:.1f} s)",
        flush=True,
    )
    return design.plan


def _sweep_plan(out: Path, config_path: Path) -> Plan:
    """Step 1 of ``--sweep``: ``station plan --sweep`` on the session's robot and setup."""
    from station.acquire import runner
    from station.config import load_station_config
    from station.formats.base import atomic_write
    from station.formats.tables import load_robot, load_setup
    from station.jobs import sweeping

    t0 = time.perf_counter()
    cfg = load_station_config(config_path)
    robot = load_robot(runner.resolve(cfg.session.robot_model, config_path))
    setup_path = runner.resolve(cfg.session.setup, config_path)
    setup = load_setup(setup_path)
    design = sweeping.sweep_design(robot, setup, str(setup_path), passes=SWEEP_PASSES, extra=SWEEP_EXTRA)
    atomic_write(out / "plan.csv", design.plan.csv_text())
    r = design.report
    print(
        f"plan:      {len(r['passes'])} passes on {len(set(design.plan.line.tolist()))} gauge lines, "
        f"{r['swept_s']:.1f} s swept at {r['limits']['tcp_mm_s']:g} mm/s, about {r['rows']} rows, promising "
        f"{r['predicted']['plan']['predicted_rmse_mm']:.3f} mm workspace error at the stated noise "
        f"-> {out / 'plan.csv'} ({time.perf_counter() - t0:.1f} s)",
        flush=True,
    )
    return design.plan


def _session(inputs, viewer: bool) -> SessionRun:
    """Step 3: the session with its running calibration."""
    from station.acquire import runner

    t0 = time.perf_counter()
    print(
        f"session:   the simulated robot walks the plan (simulated time x{inputs.cfg.time_scale:g}); "
        "live errors and predicted workspace error in the live view",
        flush=True,
    )
    done = runner.run(inputs, viewer=viewer, every_sample=False)
    n = len(inputs.folder.rows)
    plan = inputs.plan
    of = f"{n} rows on {len(plan.passes())} passes" if plan.is_sweep else f"{n}/{len(plan)} samples"
    fit = done.refit
    running = (
        "no running calibration"
        if fit is None or fit.workspace is None
        else f"running calibration {fit.workspace.predicted_rmse_mm:.3f} mm predicted "
        f"(95 %: {fit.workspace.predicted_rmse_95_mm:.3f} mm)"
    )
    worst = "" if done.worst_error_mm is None else f", worst live error {done.worst_error_mm:.2f} mm"
    print(
        f"session:   {of} in {time.perf_counter() - t0:.1f} s, {running}{worst} -> {inputs.folder.path}",
        flush=True,
    )
    return done


def demo_config(seed: int, sweep: bool = False) -> dict:
    """The demo's station config, on the contract's addresses (:func:`serve_at` moves a device
    to where the simulator bound it); ``sweep``: simulated time ``SWEEP_TIME_SCALE`` times faster,
    the robot sweeping at the sweep plan's TCP speed, stopping ``SWEEP_DWELL_S`` at a pass's ends,
    the station keeping the plan's rows per second."""
    from station.jobs.sweeping import SWEEP

    raw = {
        "time_scale": TIME_SCALE,
        "robot": {"kind": "rtde", "host": CONTRACT["rtde"][0]},
        "drawstring": {"kind": "modbus_tcp", "host": "127.0.0.1", "port": CONTRACT["modbus"][1]},
        "dial": {"port": CONTRACT["dial"]},
        "session": {"target_timeout_s": 1200.0},  # over one robot cycle: a missed target comes round
        "sim": {
            "seed": seed,
            "speed_deg_s": 120.0,
            "accel_deg_s2": 480.0,
            "dwell_s": 2.5,
        },
    }
    if sweep:
        raw["time_scale"] = SWEEP_TIME_SCALE
        raw["sim"].update(sweep_speed_mm_s=SWEEP.tcp_mm_s, dwell_s=SWEEP_DWELL_S)
        raw["sweep"] = {"rows_per_s": SWEEP.row_hz}
    return raw


def serve_at(raw: dict, served: list[dict]) -> list[str]:
    """Point the config ``raw`` at the addresses the simulated devices bound (``served``: what
    ``SimStation.start`` returns); a note for each that is not the contract's."""
    by = {a["device"]: a for a in served}
    notes = []
    if (host := by["robot"]["host"]) != raw["robot"]["host"]:
        notes.append(f"RTDE 127.0.0.1:30004 is taken: the simulated controller serves {host}:30004")
        raw["robot"]["host"] = host
    if (port := by["drawstring"]["port"]) != raw["drawstring"]["port"]:
        notes.append(f"Modbus 127.0.0.1:5020 is taken: the simulated drawstring serves 127.0.0.1:{port}")
        raw["drawstring"]["port"] = port
    if (link := by["dial"]["port"]) != raw["dial"]["port"]:
        notes.append(f"{CONTRACT['dial']} is in use: the simulated dial is at {link}")
        raw["dial"]["port"] = link
    return notes


def _calibrate(out: Path, inputs, view, seed: int, methods=("lmlc", "mcs-lmlc")) -> int:
    """Step 4: ``methods`` (LMLC first) on the session, a simulated hold-out set, the truth beside
    each."""
    import numpy as np

    from sim_fixtures.world import World
    from station.formats.base import Output, toml_text, write_outputs
    from station.formats.samples import load_samples
    from station.jobs import calibration
    from station.jobs.report import corrected_table

    world = World.create(seed)
    holdout_path = out / "holdout.csv"
    world.sample_set(HOLDOUT_PER_LINE, np.random.default_rng([seed, 4])).to_csv(holdout_path)
    samples, holdout = load_samples(inputs.folder.samples_csv), load_samples(holdout_path)
    where = str(inputs.folder.path / "session.toml")
    outcomes = {}
    for method in methods:
        outcome = calibration.calibrate_samples(
            samples,
            inputs.robot,
            inputs.setup,
            setup_where=where,
            holdout=holdout,
            method=method,
            terms=DEFAULT_TERM_MODEL,
        )
        outcomes[method] = outcome
        cal = outcome.calibration
        view.calibration(
            method,
            outcome.model.row_error_mm(cal.before.x),
            outcome.model.row_error_mm(cal.x),
            [it.cost for it in cal.after.history],
        )
        print(f"calibrate: {_one_line(outcome.report)}; {truth_line(world, outcome)}", flush=True)
    main_outcome = outcomes["lmlc"]
    table = corrected_table(
        inputs.robot, main_outcome.calibration, samples, "lmlc", payload=main_outcome.payload
    )
    outputs = [Output.text(out / "corrected.toml", "--out", toml_text(table))]
    for method, outcome in outcomes.items():  # report.json is lmlc's; all written, or none
        name = "report.json" if method == "lmlc" else f"report-{method}.json"
        report = json.dumps(outcome.report.as_json(), indent=2) + "\n"
        outputs.append(Output.text(out / name, "--out", report))
    write_outputs(outputs)
    print(f"calibrate: wrote {out / 'corrected.toml'} and {out / 'report.json'} (lmlc)", flush=True)
    return 0


def _one_line(report) -> str:
    """A calibration's report in one line: method, hold-out before -> after, prediction, time."""
    m = report.before.holdout, report.after.holdout
    ws = report.workspace
    return (
        f"{report.method:8s} hold-out {m[0].rmse_mm:.3f} -> {m[1].rmse_mm:.3f} mm RMSE, predicted "
        f"workspace {ws.predicted_rmse_mm:.3f} mm (95 %: {ws.predicted_rmse_95_mm:.3f}), "
        f"{report.time_s:.2f} s"
    )


def _export(out: Path) -> None:
    """Step 5: the corrected table as URDF beside it (what ``station export --format urdf`` writes)."""
    from station.formats.base import atomic_write
    from station.formats.tables import load_robot
    from station.jobs import export as exporting

    table = out / "corrected.toml"
    urdf = out / "corrected.urdf"
    result = exporting.export(load_robot(table), "urdf", source=str(table))
    atomic_write(urdf, result.text)
    notes = "".join(f"; note: {n}" for n in result.notes)
    print(f"export:    {urdf} (URDF: base_link -> tcp, the corrected joint origins){notes}", flush=True)


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
    return f"true workspace error (simulation, 1000 random poses) {rms[0]:.3f} -> {rms[1]:.3f} mm RMS"


def _verify(out: Path, inputs, seed: int) -> None:
    """Step 6: a short second session of the same cell, verified with the corrected table and with
    the nominal one (what ``station verify`` prints, in one line each)."""
    import numpy as np

    from sim_fixtures.world import World
    from station.formats.base import atomic_write
    from station.formats.samples import load_samples
    from station.formats.tables import load_robot
    from station.jobs import planning, verification

    t0 = time.perf_counter()
    plan = planning.verify_design(inputs.robot, inputs.setup, n_select=planning.VERIFY_POSES).plan
    world = World.create(seed)
    rng = np.random.default_rng([seed, 8])
    q, lines = world.touch_lines(plan.q_deg, plan.line, rng)
    world.measure(q, lines, rng, readings=inputs.cfg.session.readings).to_csv(out / "verify.csv")
    samples = load_samples(out / "verify.csv")
    tables = {"corrected": load_robot(out / "corrected.toml"), "nominal": inputs.robot}
    for label, table in tables.items():
        name = "verify.json" if label == "corrected" else f"verify-{label}.json"
        report = verification.verify_samples(samples, table, inputs.setup, table_where=label).report
        atomic_write(out / name, json.dumps(report.as_json(), indent=2) + "\n")
        likely = ", ".join(p.param for p in report.likely[:3])
        missed = report.missed if report.verdict == "holds" else None
        print(
            f"verify:    {len(samples)} new poses on line {plan.line[0]} with the {label} table: "
            f"{report.verdict} "
            f"(RMSE {report.rmse_mm:.3f} mm, {report.test.noise_ratio:.2f} x the stated noise"
            f"{'; most likely moved: ' + likely if likely else ''}"
            f"{missed.text(brief=True) if missed else ''}) -> {out / name}",
            flush=True,
        )
    print(f"verify:    ({time.perf_counter() - t0:.1f} s)", flush=True)
