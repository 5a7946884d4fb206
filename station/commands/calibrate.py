"""``station calibrate``: samples (CSV or session folder) to a corrected D-H table and a report."""

from __future__ import annotations

import dataclasses
import json
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING

from calib.methods import ALL_METHODS, DEFAULT_TERM_MODEL, TERM_MODELS
from errors import InputError
from station.commands.flags import parameters_as_flags
from station.commands.long_work import (
    Ticker,
    available_memory_bytes,
    check_calibrate_memory,
    reuse_freed_memory,
)
from station.commands.verify import add_history_flags, record_history

if TYPE_CHECKING:
    from station.formats.samples import Samples
    from station.formats.tables import RobotFile, SetupFile
    from station.jobs.report import CalibrationReport

FLAGS = {"setup": "--setup", "method": "--method", "select": "--select", "terms": "--model"}
"""The flag that sets each parameter of the calibration service."""


def register(sub) -> None:
    p = sub.add_parser("calibrate", help="identify the robot's D-H table from samples")
    p.add_argument("samples", type=Path, help="samples CSV or a session folder")
    p.add_argument("--robot", type=Path, help="robot model TOML (required for a CSV)")
    p.add_argument("--setup", type=Path, help="setup TOML (required for a drawstring CSV)")
    p.add_argument("--out", type=Path, required=True, help="corrected table TOML to write")
    p.add_argument("--holdout", type=Path, help="samples CSV evaluated with the training setup fit")
    p.add_argument(
        "--method",
        default="lmlc",
        choices=ALL_METHODS,
        help="lmlc (default: robust Levenberg-Marquardt with the line constraint), mcs-lmlc (LMLC on the "
        "configurations MCS selects), or one of the paper's others: pso ekf ukf gn sa pf de",
    )
    p.add_argument(
        "--select",
        type=int,
        metavar="N",
        help="mcs-lmlc: configurations to select (default: where O1 flattens)",
    )
    p.add_argument(
        "--model",
        default=DEFAULT_TERM_MODEL,
        choices=TERM_MODELS,
        help="terms beside the D-H table: geometric (none), compliance (load-bearing joints under "
        "gravity), full (plus 1st and 2nd harmonics of every joint), auto (default: the compliances "
        "where the rows determine them and they do not raise the error at poses left out by region, "
        "then so the 1st harmonics of the joints whose rows cover their whole turn, any other "
        "harmonic only where it cuts that error by >= 5 %%)",
    )
    p.add_argument("--report", type=Path, help="report JSON to write")
    p.add_argument(
        "--no-map",
        action="store_true",
        help="fit no residual map (by default the error the table leaves, learnt from the rows where "
        "the rows left out in turn show a gain, is stored beside the table as OUT's .map.npz)",
    )
    p.add_argument(
        "--plot", type=Path, help="PNG to write: error per sample and per line, predicted workspace error"
    )
    add_history_flags(p)
    p.set_defaults(func=run)


def run(args) -> int:
    from station.formats.base import Output, check_writable, toml_text, write_outputs
    from station.formats.tables import map_entry
    from station.jobs import calibration
    from station.jobs.report import corrected_table
    from station.jobs.residual_map import fit_table_map

    for path, flag in ((args.out, "--out"), (args.report, "--report"), (args.plot, "--plot")):
        if path:
            check_writable(path, flag)
    inputs = load_inputs(args)
    rows = len(inputs.samples) + (len(inputs.holdout) if inputs.holdout is not None else 0)
    check_calibrate_memory(str(args.samples), rows, available_memory_bytes())
    reuse_freed_memory()
    with parameters_as_flags(FLAGS), Ticker(f"calibrate: {len(inputs.samples)} rows") as ticker:
        outcome = calibration.calibrate_samples(
            inputs.samples,
            inputs.robot,
            inputs.setup,
            setup_where=inputs.setup_where,
            holdout=inputs.holdout,
            method=args.method,
            select=args.select,
            terms=args.model,
            notes=inputs.notes,
            stage=ticker.stage,
        )
        found, map_report = None, None
        if not outcome.report.fit_check.refusal:
            ticker.stage("fitting the residual map")
            found, map_report = fit_table_map(
                outcome.model, outcome.calibration.x, outcome.calibration.identified, not args.no_map
            )
    if outcome.report.fit_check.refusal:
        raise InputError(f"{args.samples}: {outcome.report.fit_check.refusal}; nothing written")
    report = dataclasses.replace(outcome.report, map=map_report)
    if found is not None:  # the workspace figure counts what the map leaves at each pose
        workspace = calibration.predicted_workspace(inputs.robot, outcome.calibration, outcome.model, found)
        report = dataclasses.replace(report, workspace=workspace)
    table = corrected_table(
        inputs.robot,
        outcome.calibration,
        inputs.samples,
        args.method,
        model=args.model,
        payload=outcome.payload,
    )
    outputs = []
    if found is not None:
        table["map"], map_path, map_data = map_entry(found, map_report.rows, args.out)
        outputs.append(Output(map_path, "--out", lambda tmp: tmp.write_bytes(map_data)))
    outputs.insert(0, Output.text(args.out, "--out", toml_text(table)))
    if args.report:
        outputs.append(Output.text(args.report, "--report", json.dumps(report.as_json(), indent=2) + "\n"))
    if args.plot:
        from station.view.plots import calibration_figure

        data = calibration.residual_rows(outcome)
        outputs.append(Output(args.plot, "--plot", lambda tmp: calibration_figure(data, tmp)))
    write_outputs(outputs)
    print(summary(report))
    print("wrote " + ", ".join(str(o.path) for o in outputs))
    record_history(args, inputs.robot, "calibrate", inputs.samples.path, args.out, report.as_json())
    return 0


@dataclass(frozen=True)
class Inputs:
    """Validated inputs of a command that takes ``SAMPLES [--robot] [--setup] [--holdout]``."""

    samples: Samples
    robot: RobotFile
    setup: SetupFile | None
    setup_where: str
    holdout: Samples | None
    notes: tuple[str, ...] = ()


def load_inputs(args) -> Inputs:
    """Samples (CSV or session folder), robot, setup and hold-out from ``args``; the flags override
    what a session folder embeds, and ``notes`` say so where they differ from it."""
    from station.formats.samples import load_samples
    from station.formats.session_folder import (
        check_session_rows,
        load_robot_and_setup,
        replaced_by,
        samples_path,
    )

    if not args.samples.exists():
        raise InputError(f"{args.samples}: no such file or folder (a samples CSV or a session folder)")
    session = args.samples if args.samples.is_dir() else None
    if session is None and args.robot is None:
        raise InputError(f"{args.samples}: a samples CSV needs --robot")
    robot, setup, setup_where, session_samples = load_robot_and_setup(session, args.robot, args.setup)
    if session is not None:
        check_session_rows(session)  # each row a target of the session's plan, on its line
    samples = load_samples(session_samples or args.samples)
    holdout = load_samples(samples_path(args.holdout)) if args.holdout else None
    if holdout is not None and holdout.kind != samples.kind:
        raise InputError(f"{args.holdout}: a {holdout.kind} set cannot hold out for a {samples.kind} set")
    notes = ()
    if session is not None:
        flags = {"--robot": (args.robot, robot), "--setup": (args.setup, setup)}
        notes = replaced_by(session, {flag: given for flag, given in flags.items() if given[0]})
    return Inputs(samples, robot, setup, setup_where, holdout, notes)


def summary(report: CalibrationReport) -> str:
    """A short human summary: before -> after on training and hold-out, time, what was held."""
    from station.jobs.report import ERROR_HEADER, error_row

    lines = [
        f"{report.kind} calibration, method {report.method}: "
        f"{report.iterations} solver iteration{'' if report.iterations == 1 else 's'}, {report.time_s:.3f} s",
        ERROR_HEADER,
    ]
    parts = (("train", report.before.train, report.after.train),)
    parts += (("holdout", report.before.holdout, report.after.holdout),)
    for part, before, after in parts:
        for when, m in (("before", before), ("after", after)):
            if m is not None:
                lines.append(error_row(f"{part} {when}", m.rmse_mm, m.mean_mm, m.max_mm))
    from calib.joint_terms import TERM_KINDS
    from station.jobs.fit_check import HOLDOUT_SCOPES

    terms_held = sum(1 for h in report.held if h.param.partition(".")[2] in TERM_KINDS)
    held = ", ".join(h.param for h in report.held if h.param.partition(".")[2] not in TERM_KINDS)
    held += f"; also held: {terms_held} joint-space terms (why: the report's held)" if terms_held else ""
    lines.append(f"identified {len(report.identified)} table parameters; held: {held}")
    lines += terms_summary(report)
    if report.downweighted:
        lines.append(f"down-weighted rows: {list(report.downweighted)}")
    ws = report.workspace
    lines.append(
        f"predicted workspace error: {ws.predicted_rmse_mm:.3f} mm RMS "
        f"(95 %: below {ws.predicted_rmse_95_mm:.3f} mm)"
    )
    lines += dial_summary(report)
    if (timing := getattr(report.setup, "timing_ms", None)) is not None:
        lines.append(
            f"drawstring timing: the swept rows' lengths were true {timing:+.3f} ms after their stamps "
            "(fitted: a device measures somewhere inside its round trip)"
        )
    mode = report.fit_check.dial_mode if report.fit_check else None
    if mode and not any(mode in w for w in report.warnings):
        lines.append(f"dial-less: {mode}")
    if report.map is not None:
        lines.append(report.map.text())
    lines += [f"warning: {w}" for w in report.warnings]
    lines.append(f"note: {HOLDOUT_SCOPES[report.holdout_scope]}")
    lines.append(f"next: {report.next}")
    return "\n".join(lines)


def dial_summary(report: CalibrationReport) -> list[str]:
    """How each gauge line's rows were held to its edge, one line for the lines of each mode."""
    from station.jobs.absorbed import DIAL_MODE_TEXT

    by_mode: dict[str, list[str]] = {}
    for lid, mode in report.line_dial.items():
        by_mode.setdefault(mode, []).append(str(lid))
    return [
        f"gauge line{'s' if len(ids) > 1 else ''} {', '.join(ids)}: {DIAL_MODE_TEXT[mode]}"
        for mode, ids in by_mode.items()
    ]


def terms_summary(report: CalibrationReport) -> list[str]:
    """The model's joint-space terms with their sigmas and, for ``auto``, how they were chosen."""
    lines = []
    if report.cross_validation is not None:
        cv = report.cross_validation
        kept = [r for r in cv.rows if r.kept]
        steps = " -> ".join(f"{r.added or 'table'} {r.rmse_mm:.3f}" for r in kept)
        lines.append(
            f"model auto (cross-validated RMSE on {cv.scheme}, mm; "
            f"nominal table {cv.nominal_rmse_mm:.3f}): {steps}"
        )
    if report.discrepancy is not None:
        d = report.discrepancy
        lines.append(
            f"weighted: poses within {d.length_scale_deg:g} deg of each other (joints 1-3) share an "
            f"error the model cannot express ({d.ratio:g} x the noise's variance; log-likelihood "
            f"+{d.loglik_gain:.0f} over none), so the fit counts them together"
        )
    if report.terms:
        terms = ", ".join(f"{n} {e.value:.4g} +- {e.sigma:.2g}" for n, e in report.terms.items())
        lines.append(f"terms: {terms}")
    else:
        lines.append(f"model {report.model}: no joint-space terms")
    return lines
