"""``station sample [--config F] [--plan P.csv] (--out DIR | --resume DIR) [--time-scale S] [--until-mm X]
[--viewer] [--web [--web-bind ADDR]]``.

The session runs at the time scale of ``station sim serve`` where it announces that it simulates
the configured robot (``--time-scale`` must then agree), else at ``--time-scale`` or the config's.

Exit 0 when every target is measured or the running calibration's 95 % workspace bound reached
``--until-mm`` (kept in the session: a resume goes on towards it), 130 after Ctrl-C (the sample in
flight stored whole), 1 when a device stays unreachable or no capture happens for the target
timeout (the samples taken so far are kept: continue with ``--resume DIR``).
"""

from __future__ import annotations

from pathlib import Path

import configs
from errors import InputError, OutputError
from station.commands.flags import number

_positive_mm = number(float, "a number (mm)", lambda v: v > 0, "{:g} must be above 0 mm")

EXIT = {"done": 0, "stopped": 130, "timed out": 1}
"""Exit code by the state the session ended in."""


def register(subparsers) -> None:
    p = subparsers.add_parser("sample", help="a sampling session on the gauge-block lines")
    p.add_argument("--config", type=Path, help="station config (default: the shipped one, simulated devices)")
    p.add_argument(
        "--plan",
        type=Path,
        help="plan CSV target,line,q1_deg..q6_deg (default: the config's [session] plan, "
        "where `station sim serve` publishes the plan its robot walks)",
    )
    where = p.add_mutually_exclusive_group(required=True)
    where.add_argument("--out", type=Path, help="new session folder")
    where.add_argument("--resume", type=Path, metavar="DIR", help="continue the session in DIR")
    p.add_argument(
        "--time-scale",
        type=float,
        metavar="S",
        help="simulated seconds per real second of the robot measured (default: what `station sim "
        "serve` announces for the configured robot, else the config's time_scale; 1 = real time)",
    )
    p.add_argument(
        "--until-mm",
        type=_positive_mm,
        metavar="X",
        help="end the session once the running calibration's 95 %% workspace bound is at or below X mm",
    )
    p.add_argument("--viewer", action="store_true", help="stream to a native Rerun viewer")
    p.add_argument(
        "--web",
        action="store_true",
        help="serve the live view to a browser; prints the http:// address to open",
    )
    p.add_argument(
        "--web-bind",
        metavar="ADDR",
        help="address to serve --web on (default 127.0.0.1, this machine only; 0.0.0.0: every "
        "machine that reaches this one, e.g. a tablet on the plant network)",
    )
    p.set_defaults(func=run)


def run(args) -> int:
    from station.acquire import runner

    if args.resume:
        if args.plan:
            raise InputError("--plan: a resumed session keeps the plan embedded in its session.toml")
        inputs = runner.resume_session(args.resume, args.config, args.time_scale)
        print(resuming_text(args.resume, inputs, args.until_mm))
    else:
        config = args.config or configs.path("station.toml")
        inputs = runner.new_session(args.out, config, args.plan, args.time_scale)
    try:
        return _run(args, inputs)
    finally:
        inputs.folder.release()  # the folder's lock: the next writer may start


def _run(args, inputs) -> int:
    from station.acquire import runner

    until_mm = args.until_mm
    if args.until_mm:
        inputs.folder.update_header(until_mm=args.until_mm)
    web = (args.web_bind or "127.0.0.1") if args.web or args.web_bind else None
    outcome = runner.run(inputs, viewer=args.viewer, web=web, until_mm=until_mm)
    outcome.view.close()
    state = outcome.state
    folder = inputs.folder
    if outcome.view.incomplete:
        raise OutputError(
            f"{folder.rrd}: the recording could not be written whole ({outcome.view.incomplete}); the "
            f"{len(folder.rows)} samples in {folder.samples_csv} are whole"
        )
    kept = (
        f"{len(folder.rows)} rows of {len(inputs.plan.passes())} passes"
        if inputs.plan.is_sweep
        else f"{len(folder.rows)}/{len(inputs.plan)} samples"
    )
    print(f"saved: {kept} in {folder.samples_csv}; replay the recording with: rerun {folder.rrd}")
    return EXIT[state.value]


def resuming_text(folder, inputs, until_mm: float | None) -> str:
    """What a resume goes on to do: ``--until-mm`` again stops at that goal; without it the rest of
    the plan is measured, whatever goal the session had (it may have been reached already)."""
    text = f"resuming {folder}: {len(inputs.folder.rows)} of {len(inputs.plan)} targets measured"
    earlier = inputs.folder.header.get("until_mm")
    if until_mm is not None:
        return f"{text}; until the 95 % workspace bound is at or below {until_mm:g} mm"
    if earlier is not None:
        return (
            f"{text}; measuring the rest of the plan (the session's earlier --until-mm {earlier:g} is "
            "not carried over: give --until-mm again to stop at a goal)"
        )
    return f"{text}; measuring the rest of the plan"
