"""``station sample [--config F] [--plan P.csv] (--out DIR | --resume DIR) [--viewer] [--web]``.

Exit 0 when every target is measured, 130 after Ctrl-C (the sample in flight stored whole),
1 when a device stays unreachable or no capture happens for the target timeout (the samples
taken so far are kept: continue with ``--resume DIR``).
"""

from __future__ import annotations

from pathlib import Path

import configs
from errors import InputError, OutputError

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
    p.add_argument("--viewer", action="store_true", help="stream to a native Rerun viewer")
    p.add_argument("--web", action="store_true", help="serve a Rerun web viewer")
    p.set_defaults(func=run)


def run(args) -> int:
    from station.acquire import runner

    if args.resume:
        if args.plan:
            raise InputError("--plan: a resumed session keeps the plan embedded in its session.toml")
        inputs = runner.resume_session(args.resume, args.config)
        print(f"resuming {args.resume}: {len(inputs.folder.rows)} of {len(inputs.plan)} targets measured")
    else:
        inputs = runner.new_session(args.out, args.config or configs.path("station.toml"), args.plan)
    state, view = runner.run(inputs, viewer=args.viewer, web=args.web)
    view.close()
    folder = inputs.folder
    if view.incomplete:
        raise OutputError(
            f"{folder.rrd}: the recording could not be written whole ({view.incomplete}); the "
            f"{len(folder.rows)} samples in {folder.samples_csv} are whole"
        )
    print(
        f"{state.value}: {len(folder.rows)}/{len(inputs.plan)} samples in {folder.samples_csv}; "
        f"recording {folder.rrd}"
    )
    return EXIT[state.value]
