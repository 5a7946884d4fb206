"""Console script ``station``: parse, call, print. Each command lives in ``station.commands``."""

from __future__ import annotations

import argparse
import importlib
import sys

from errors import DeviceError, InputError, OutputError

# One module per command; each exposes ``register(subparsers)``, which adds its parser with
# ``func`` set to the module's one entry ``run(args)`` (returns the exit code). A command module
# imports at its top only what its parser needs (the standard library, ``errors``, names): numpy,
# scipy, pydantic, the drivers, Rerun and matplotlib are imported in ``run``, where they are used,
# so that ``station --help`` answers at once and each command loads only its own libraries.
COMMANDS = (
    "demo",
    "calibrate",
    "sim",
    "read",
    "import-ipa",
    "sample",
    "compare",
    "plan",
    "export",
    "compensate",
)


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog="station", description=__doc__.splitlines()[0])
    sub = parser.add_subparsers(dest="command", required=True, metavar="COMMAND")
    for name in COMMANDS:
        importlib.import_module(f"station.commands.{name.replace('-', '_')}").register(sub)
    return parser


def main(argv: list[str] | None = None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    try:
        return int(args.func(args) or 0)
    except InputError as exc:
        print(f"station: error: {exc}", file=sys.stderr)
        return 2
    except DeviceError as exc:
        print(f"station: device error: {exc}", file=sys.stderr)
        return 1
    except OutputError as exc:
        print(f"station: cannot write: {exc}", file=sys.stderr)
        return 1
    except KeyboardInterrupt:
        print("station: interrupted", file=sys.stderr)
        return 130


if __name__ == "__main__":
    sys.exit(main())
