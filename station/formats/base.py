"""What every file format of the station shares: TOML reading and validation with one-line errors
naming the file and key, the ranges a value may take, number cells of a CSV, atomic writes, and the
writability check before any work.

Ranges: a number a file gives must be finite and within what a robot cell can hold (lengths within
``MAX_LENGTH_MM``, dial readings within ``MAX_DIAL_MM``, joint angles within ``MAX_JOINT_DEG``, noise
between ``MIN_SIGMA_MM`` and ``MAX_SIGMA_MM``). Values beyond them are typing or unit mistakes, and
they make the maths overflow far from the file (a 1e308 mm length, a 1e-300 mm sigma, a dial
reading of a metre): the loader refuses them, naming the key.
"""

from __future__ import annotations

import contextlib
import math
import os
import signal
import sys
import tempfile
import threading
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Annotated

import tomli_w
from pydantic import AfterValidator, BaseModel, ConfigDict, Field, ValidationError

from errors import InputError

if sys.version_info >= (3, 11):
    import tomllib
else:  # pragma: no cover
    import tomli as tomllib


MAX_LENGTH_MM = 1e5  # 100 m: any length, position or reading of a robot cell
MAX_DIAL_MM = 100.0  # the longest dial indicators' travel
MAX_JOINT_DEG = 3600.0  # ten turns: joint readings and limits
MAX_ANGLE_DEG = 360.0  # D-H table angles
MIN_SIGMA_MM, MAX_SIGMA_MM = 1e-6, 100.0  # instrument noise: a nanometre to 100 mm
MAX_ID = 10**9  # sample, target and line ids: whole numbers 0 .. MAX_ID
# Unit mistakes recognisable over a whole file (``station.formats.units``): joint readings all
# within +-2 pi in a degrees column, a joint's range narrower than 2 pi rad, twists all within
# +-pi/2 in a degrees field, every gauge-line point within this many mm of the base (metres).
RADIANS_AS_DEG = 2 * math.pi + 1e-6
MIN_JOINT_RANGE_DEG = 7.0
MAX_TWIST_RAD = math.pi / 2 + 1e-6
METRES_AS_MM = 10.0
NAME_MAX = 255  # bytes in one name of a path: the limit of Linux's file systems

Length = Annotated[float, Field(ge=-MAX_LENGTH_MM, le=MAX_LENGTH_MM)]
DialReading = Annotated[float, Field(ge=-MAX_DIAL_MM, le=MAX_DIAL_MM)]
PositiveLength = Annotated[float, Field(gt=0, le=MAX_LENGTH_MM)]
Angle = Annotated[float, Field(ge=-MAX_ANGLE_DEG, le=MAX_ANGLE_DEG)]
JointAngle = Annotated[float, Field(ge=-MAX_JOINT_DEG, le=MAX_JOINT_DEG)]
Sigma = Annotated[float, Field(ge=MIN_SIGMA_MM, le=MAX_SIGMA_MM)]
Id = Annotated[int, Field(ge=0, le=MAX_ID)]
Vec3 = Annotated[list[Length], Field(min_length=3, max_length=3)]
TimeScale = Annotated[float, Field(ge=1e-3, le=1e3, allow_inf_nan=False)]  # simulated s per real s


def _non_zero(v: list[float]) -> list[float]:
    if math.hypot(*v) < 1e-9:
        raise ValueError("must be a direction, not the zero vector")
    return v


Direction = Annotated[Vec3, AfterValidator(_non_zero)]
"""A direction (normalised where used): three numbers, not all zero."""


class Strict(BaseModel):
    """A table of a station file: unknown keys, NaN and infinity are refused."""

    # validators built at a file's first read, not at import: a command pays only for the files it
    # reads (building every format's at import cost each command 50-75 ms, issue 36)
    model_config = ConfigDict(extra="forbid", allow_inf_nan=False, defer_build=True)


def read_toml(path: Path) -> dict:
    """Parse a TOML file; a missing or malformed file is an InputError naming it."""
    path = Path(path)
    try:
        with path.open("rb") as fh:
            return tomllib.load(fh)
    except FileNotFoundError:
        raise InputError(f"{path}: no such file") from None
    except IsADirectoryError:
        raise InputError(f"{path}: {folder_kind(path)}, expected a TOML file") from None
    except OSError as exc:
        raise InputError(f"{path}: cannot read: {exc.strerror or exc}") from None
    except tomllib.TOMLDecodeError as exc:
        raise InputError(f"{path}: not valid TOML: {exc}") from None
    except UnicodeDecodeError:
        raise InputError(f"{path}: not valid TOML: not UTF-8 text") from None
    except RecursionError:
        raise InputError(f"{path}: not valid TOML: nested too deeply") from None


def folder_kind(path: Path) -> str:
    """What a folder given for a file is, for a message: a session folder (``session.toml`` inside,
    whose files are named) or any directory."""
    if (Path(path) / "session.toml").is_file():
        return f"a session folder (its files: {Path(path) / 'session.toml'}, {Path(path) / 'samples.csv'})"
    return "is a directory"


def validate(schema: type[BaseModel], data: dict, where: str):
    """``schema.model_validate(data)`` with the first error as one line naming ``where`` and the key."""
    try:
        return schema.model_validate(data)
    except ValidationError as exc:
        err = exc.errors()[0]
        key = ".".join(str(p) for p in err["loc"]) or "(top level)"
        if err["type"] in ("too_short", "too_long"):
            expected = err["ctx"]["min_length" if err["type"] == "too_short" else "max_length"]
            items = "joints" if key.endswith("joints") else "numbers"
            raise InputError(
                f"{where}: {key}: expected {expected} {items}, got {len(err['input'])}"
            ) from None
        raise InputError(f"{where}: {key}: {err['msg'].removeprefix('Value error, ')}") from None


def number_cell(cell: str, limit: float, unit: str) -> float:
    """The number in a CSV cell, finite and within ``-limit .. limit`` (``unit`` for the message);
    ValueError saying what is wrong with the cell."""
    try:
        value = float(cell)
    except ValueError:
        value = math.nan
    if not math.isfinite(value):
        raise ValueError(f"{cell or '(empty)'!r} is not a finite number")
    if abs(value) > limit:
        raise ValueError(f"{cell!r} is outside -{limit:g} .. {limit:g} {unit}")
    return value


def id_cell(cell: str, what: str) -> int:
    """The id in a CSV cell: a whole number 0 .. ``MAX_ID``; ValueError naming ``what`` it is not."""
    try:
        value = float(cell)
    except ValueError:
        value = math.nan
    if not (0 <= value <= MAX_ID and value == int(value)):
        raise ValueError(f"{cell or '(empty)'!r} is not {what} (a whole number 0 .. {MAX_ID:.0e})")
    return int(value)


def atomic_write(path: Path, text: str) -> None:
    """Write ``text`` to ``path`` via a temporary file in the same folder and a rename."""
    path = Path(path)
    tmp = _temporary(path)
    try:
        _write_text(tmp, text)
        os.replace(tmp, path)
    except BaseException:
        tmp.unlink(missing_ok=True)
        raise


@dataclass(frozen=True)
class Output:
    """One result file of a command: its ``path``, the ``flag`` that named it, and ``write``, which
    writes the content to the path it is given (a temporary file beside ``path``)."""

    path: Path
    flag: str
    write: Callable[[Path], None]

    @classmethod
    def text(cls, path: Path, flag: str, text: str) -> Output:
        return cls(Path(path), flag, lambda tmp: _write_text(tmp, text))


def write_outputs(outputs: Sequence[Output]) -> None:
    """Every output to a temporary file beside it, then all renamed into place: a command leaves
    all its results or none (a file already there stays as it was). A failure (a folder that
    cannot be written after all, a full disk) is bad input naming the output, with nothing written."""
    temps: list[Path] = []
    try:
        for out in outputs:
            temps.append(_temporary(out.path))
            out.write(temps[-1])
            os.chmod(temps[-1], 0o644)  # mkstemp makes it 0600; results are for others to read
        with signals_deferred():  # a SIGTERM or Ctrl-C now takes effect once every rename is done
            for out, tmp in zip(outputs, temps, strict=True):
                os.replace(tmp, out.path)
    except OSError as exc:
        names = ", ".join(str(o.path) for o in outputs)
        raise InputError(
            f"{out.flag} {out.path}: cannot write ({exc.strerror or exc}); nothing written ({names})"
        ) from None
    finally:
        for tmp in temps:
            tmp.unlink(missing_ok=True)


@contextlib.contextmanager
def signals_deferred():
    """SIGINT and SIGTERM held back for the block and acted on after it, as they would have been:
    a group of renames that makes a command's outputs is never cut in two by a Ctrl-C or a service
    manager's stop. (Handlers, not a signal mask: the kernel hands a process's signal to any of its
    threads, e.g. a BLAS worker's, which a mask on this one would not stop.) Python sets handlers
    in the main thread only; elsewhere the block runs as it is."""
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    caught: list[int] = []
    held = {
        s: signal.signal(s, lambda signum, _: caught.append(signum)) for s in (signal.SIGINT, signal.SIGTERM)
    }
    try:
        yield
    finally:
        for s, handler in held.items():
            signal.signal(s, handler)
        for signum in caught:
            signal.raise_signal(signum)


def printable(text: str) -> str:
    """``text`` with the bytes a path holds that are not UTF-8 (``os.fsdecode`` keeps them as lone
    surrogates, which no UTF-8 output takes) written ``\\xNN``."""
    return text.encode("utf-8", "surrogateescape").decode("utf-8", "backslashreplace")


def shown(path) -> str:
    """A path as text that any output takes: bytes that are not UTF-8 (a folder named on another
    system) as ``\\xNN``, names longer than 40 characters cut to their start and size."""
    text = printable(str(path))
    return "/".join(n if len(n) <= 40 else f"{n[:20]}...({len(n.encode())} bytes)" for n in text.split("/"))


def check_path(path) -> None:
    """InputError unless every name in ``path`` fits a file system (``NAME_MAX`` bytes): a name
    too long fails here, in one line, instead of in the middle of a command's work."""
    for name in Path(path).parts:
        size = len(os.fsencode(name))
        if size > NAME_MAX:
            raise InputError(f"{shown(path)}: a name in this path is {size} bytes long; at most {NAME_MAX}")


def check_writable(path: Path, what: str) -> Path:
    """Fail early (InputError) if ``path`` cannot be written: missing or read-only folder, or one
    where a file cannot be created (tried: permissions are not all, e.g. a read-only mount)."""
    path = Path(path)
    folder = path.parent if str(path.parent) else Path(".")
    if not folder.is_dir():
        raise InputError(f"{what} {path}: folder {folder} does not exist")
    if not os.access(folder, os.W_OK):
        raise InputError(f"{what} {path}: folder {folder} is not writable")
    if path.is_dir():
        raise InputError(f"{what} {path}: is a directory")
    try:
        _temporary(path).unlink()
    except OSError as exc:
        raise InputError(f"{what} {path}: cannot write in folder {folder} ({exc.strerror or exc})") from None
    return path


def _temporary(path: Path) -> Path:
    """A new empty file beside ``path``, hidden, ending like it (matplotlib picks a format by it);
    its name is cut to fit the file system's limit on a name (a name near it stays writable)."""
    path = Path(path)
    stem = os.fsencode(path.name)[: NAME_MAX - len(os.fsencode(path.suffix)) - 12]
    fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=f".{os.fsdecode(stem)}.", suffix=path.suffix)
    os.close(fd)
    return Path(tmp)


def _write_text(path: Path, text: str) -> None:
    with open(path, "w") as fh:
        fh.write(text)
        fh.flush()
        os.fsync(fh.fileno())
    os.chmod(path, 0o644)


def toml_text(data: dict) -> str:
    """TOML of plain ``data``; text that cannot be UTF-8 (a path with bytes that are not: see
    :func:`shown`) is written as it is shown."""
    return tomli_w.dumps(_encodable(data))


def _encodable(value):
    if isinstance(value, dict):
        return {_encodable(k): _encodable(v) for k, v in value.items()}
    if isinstance(value, list | tuple):
        return [_encodable(v) for v in value]
    if isinstance(value, str) and not value.isascii():
        return printable(value)
    return value
