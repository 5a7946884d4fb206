"""What every file format of the station shares: TOML reading and validation with one-line errors
naming the file and key, atomic writes, and the writability check before any work."""

from __future__ import annotations

import os
import sys
import tempfile
from pathlib import Path

import tomli_w
from pydantic import BaseModel, ValidationError

from errors import InputError

if sys.version_info >= (3, 11):
    import tomllib
else:  # pragma: no cover
    import tomli as tomllib


def read_toml(path: Path) -> dict:
    """Parse a TOML file; a missing or malformed file is an InputError naming it."""
    path = Path(path)
    try:
        with path.open("rb") as fh:
            return tomllib.load(fh)
    except FileNotFoundError:
        raise InputError(f"{path}: no such file") from None
    except IsADirectoryError:
        raise InputError(f"{path}: is a directory, expected a TOML file") from None
    except tomllib.TOMLDecodeError as exc:
        raise InputError(f"{path}: not valid TOML: {exc}") from None


def validate(schema: type[BaseModel], data: dict, where: str):
    """``schema.model_validate(data)`` with the first error as one line naming ``where`` and the key."""
    try:
        return schema.model_validate(data)
    except ValidationError as exc:
        err = exc.errors()[0]
        key = ".".join(str(p) for p in err["loc"]) or "(top level)"
        if err["type"] in ("too_short", "too_long") and key.endswith("joints"):
            raise InputError(f"{where}: joints: expected 6 joints, got {len(err['input'])}") from None
        if err["type"] in ("too_short", "too_long"):
            raise InputError(f"{where}: {key}: expected 3 numbers, got {len(err['input'])}") from None
        raise InputError(f"{where}: {key}: {err['msg']}") from None


def atomic_write(path: Path, text: str) -> None:
    """Write ``text`` to ``path`` via a temporary file in the same folder and a rename."""
    path = Path(path)
    fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=f".{path.name}.", suffix=".tmp")
    try:
        with os.fdopen(fd, "w") as fh:
            fh.write(text)
            fh.flush()
            os.fsync(fh.fileno())
        os.chmod(tmp, 0o644)  # mkstemp makes it 0600; results are for others to read
        os.replace(tmp, path)
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise


def check_writable(path: Path, what: str) -> Path:
    """Fail early (InputError) if ``path`` cannot be written: missing or read-only folder."""
    path = Path(path)
    folder = path.parent if str(path.parent) else Path(".")
    if not folder.is_dir():
        raise InputError(f"{what} {path}: folder {folder} does not exist")
    if not os.access(folder, os.W_OK):
        raise InputError(f"{what} {path}: folder {folder} is not writable")
    if path.is_dir():
        raise InputError(f"{what} {path}: is a directory")
    return path


def toml_text(data: dict) -> str:
    return tomli_w.dumps(data)
