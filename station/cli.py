"""Console script ``station``: parse, call, print. Each command lives in ``station.commands``."""

from __future__ import annotations

import argparse
import importlib
import os
import signal
import sys
from pathlib import Path

from errors import DeviceError, InputError, OutputError
from station import DISTRIBUTION  # noqa: F401  (the distribution's name, imported from here by tests)

# One module per command; each exposes ``register(subparsers)``, which adds its parser with
# ``func`` set to the module's one entry ``run(args)`` (returns the exit code). A command module
# imports at its top only what its parser needs (the standard library, ``errors``, names): numpy,
# scipy, pydantic, the drivers, Rerun and matplotlib are imported in ``run``, where they are used,
# so that ``station --help`` answers at once and each command loads only its own libraries.
DESCRIPTION = """\
Robot calibration station: measure a robot along gauge-block lines with a drawstring sensor, a dial
indicator and its joint angles, and calibrate its Denavit-Hartenberg table.

A session: `station plan` (which poses) -> `station program` (the robot program that measures
them) -> `station sample` (measure them, with a running calibration) -> `station calibrate` (the
corrected table and its report) -> `station export` or `station compensate` (use it). Later,
`station verify` judges the table on new samples, `station history` lists each robot's records and
`station report` writes a calibration certificate.
`station demo` runs all of it on simulated devices; `station sim serve` starts those devices for the
other commands; `station read` checks the wiring."""

COMMANDS = (  # in the order of the workflow, as the help lists them
    "demo",
    "sim",
    "read",
    "plan",
    "program",
    "sample",
    "calibrate",
    "compare",
    "export",
    "compensate",
    "verify",
    "history",
    "report",
    "import-ipa",
)


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="station", description=DESCRIPTION, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("--version", action=_Version)
    sub = parser.add_subparsers(dest="command", required=True, metavar="COMMAND")
    for name in COMMANDS:
        importlib.import_module(f"station.commands.{name.replace('-', '_')}").register(sub)
    return parser


class _Version(argparse.Action):
    """``--version``: the installed package's version, looked up only when asked (importlib.metadata)."""

    def __init__(self, option_strings, dest, **kwargs):
        super().__init__(option_strings, dest, nargs=0, help="print the station's version and exit")

    def __call__(self, parser, namespace, values, option_string=None):
        from station import installed_version

        print(f"station {installed_version()}")
        parser.exit()


BLAS_THREADS = ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS")
"""Set to 1 unless the environment sets them: the station's matrices are a few dozen unknowns
wide, and OpenBLAS threads spin waiting for a core that another process holds (the capture, the
viewer: on a loaded 2-core machine ``station calibrate`` on 210 samples took 1.7 s with them, 0.6 s
without, ``benchmarks/calibrate_speed.py``). Set ``OPENBLAS_NUM_THREADS`` for sets of millions of
rows on an idle machine."""


def main(argv: list[str] | None = None) -> int:
    for key in BLAS_THREADS:  # before numpy is imported: the commands import it in ``run``
        os.environ.setdefault(key, "1")
    parser = build_parser()
    args = parser.parse_args(argv)
    # a path with bytes that are not UTF-8 (a folder named on another system) prints as it is named
    for stream in (sys.stdout, sys.stderr):
        if hasattr(stream, "reconfigure"):
            stream.reconfigure(errors="surrogateescape")
    # a service manager's or `kill`'s SIGTERM ends a command as Ctrl-C does: files closed, children
    # (the viewer, the refit worker) stopped, exit 130
    previous = signal.signal(signal.SIGTERM, _interrupt)
    try:
        _check_paths(args)
        code = int(args.func(args) or 0)
        sys.stdout.flush()  # here, not at exit: a reader gone (`| head`) is then ours to handle
        return code
    except BrokenPipeError:
        _stdout_gone()
        return 1
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
    finally:
        signal.signal(signal.SIGTERM, previous)


def _check_paths(args) -> None:
    """Every path a command was given fits a file system (InputError naming it): checked once here
    for all commands, before any work."""
    from station.formats.base import check_path

    for value in vars(args).values():
        for path in value if isinstance(value, list | tuple) else (value,):
            if isinstance(path, Path):
                check_path(path)


def _stdout_gone() -> None:
    """The reader of standard output has gone (``station history --json | head``): say nothing
    more, and point stdout at /dev/null so that the interpreter's last flush has nowhere to fail."""
    devnull = os.open(os.devnull, os.O_WRONLY)
    os.dup2(devnull, sys.stdout.fileno())
    os.close(devnull)


def _interrupt(signum, frame) -> None:
    raise KeyboardInterrupt


if __name__ == "__main__":
    sys.exit(main())
