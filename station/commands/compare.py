"""``station compare``: every method of the paper's Table II on the same samples, one table."""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

from calib.methods import ALL_METHODS
from station.commands.calibrate import FLAGS, load_inputs
from station.commands.flags import parameters_as_flags, seed


def register(sub) -> None:
    p = sub.add_parser("compare", help="run every calibrator of the paper's Table II on the same samples")
    p.add_argument("samples", type=Path, help="samples CSV or a session folder")
    p.add_argument("--robot", type=Path, help="robot model TOML (required for a CSV)")
    p.add_argument("--setup", type=Path, help="setup TOML (required for a drawstring CSV)")
    p.add_argument("--holdout", type=Path, help="samples CSV evaluated with each method's training fit")
    p.add_argument("--report", type=Path, help="comparison JSON to write")
    p.add_argument("--plot", type=Path, help="PNG to write: accuracy bars, training curves, time")
    p.add_argument(
        "--methods",
        type=_methods,
        default=ALL_METHODS,
        help=f"comma-separated subset of {','.join(ALL_METHODS)} (default: all)",
    )
    p.add_argument("--seed", type=seed, default=0, help="seed of every random choice (default 0)")
    p.set_defaults(func=run)


def run(args) -> int:
    from calib.baselines import BaselineOptions
    from station.formats.base import Output, check_writable, write_outputs
    from station.jobs import comparison

    for path, flag in ((args.report, "--report"), (args.plot, "--plot")):
        if path:
            check_writable(path, flag)
    inputs = load_inputs(args)
    with parameters_as_flags(FLAGS):
        result = comparison.compare(
            inputs.samples,
            inputs.robot,
            inputs.setup,
            setup_where=inputs.setup_where,
            holdout=inputs.holdout,
            methods=args.methods,
            options=BaselineOptions(seed=args.seed),
            progress=lambda message: print(f"... {message}", file=sys.stderr, flush=True),
        )
    outputs = []
    if args.report:
        outputs.append(Output.text(args.report, "--report", json.dumps(result.report, indent=2) + "\n"))
    if args.plot:
        from station.view.plots import comparison_figure

        outputs.append(
            Output(args.plot, "--plot", lambda tmp: comparison_figure(result.report, tmp, comparison.LABELS))
        )
    write_outputs(outputs)
    print(comparison.table(result.report))
    if outputs:
        print("wrote " + ", ".join(str(o.path) for o in outputs))
    return 0


def _methods(text: str) -> tuple[str, ...]:
    names = tuple(m.strip() for m in text.split(",") if m.strip())
    unknown = [m for m in names if m not in ALL_METHODS]
    if unknown or not names:
        raise argparse.ArgumentTypeError(
            f"unknown method {unknown[0] if unknown else text!r}; choose from {ALL_METHODS}"
        )
    return names
