"""Which process holds a file the station needs (a serial port another program has open, a session
folder another session writes), so that a refusal names it instead of guessing (Linux ``/proc``;
elsewhere nothing is found and the caller says what it can)."""

from __future__ import annotations

import os
from pathlib import Path


def process_command(pid: int, limit: int = 120) -> str | None:
    """The command line of process ``pid`` (cut to ``limit`` characters); None where unknown."""
    try:
        raw = Path(f"/proc/{pid}/cmdline").read_bytes()
    except OSError:
        return None
    text = " ".join(raw.replace(b"\0", b" ").decode("utf-8", "backslashreplace").split())  # one line
    return text if len(text) <= limit else text[: limit - 3] + "..."


def named(pid: int) -> str:
    """``PID n (command line)``, the command line where it can be read."""
    command = process_command(pid)
    return f"PID {pid}" + (f" ({command})" if command else "")


def file_holder(path) -> int | None:
    """A process other than this one that locks (``flock``, as pyserial's exclusive open does) or
    has open the file ``path`` (a symbolic link is followed); None where none is found."""
    try:
        st = os.stat(path)
    except OSError:
        return None
    return _locker(st) or _opener(os.path.realpath(path))


def _locker(st: os.stat_result) -> int | None:
    """From ``/proc/locks``: ``1: FLOCK ADVISORY WRITE <pid> <major>:<minor>:<inode> 0 EOF``."""
    key = f"{os.major(st.st_dev):02x}:{os.minor(st.st_dev):02x}:{st.st_ino}"
    try:
        lines = Path("/proc/locks").read_text().splitlines()
    except OSError:
        return None
    for line in lines:
        fields = line.split()
        if "->" not in fields and len(fields) > 5 and fields[5] == key and fields[4] != str(os.getpid()):
            return int(fields[4])
    return None


def _opener(real: str) -> int | None:
    """A process with ``real`` open, from ``/proc/<pid>/fd`` (processes this user may look into)."""
    for proc in Path("/proc").iterdir():
        if not proc.name.isdigit() or proc.name == str(os.getpid()):
            continue
        try:
            if any(os.readlink(fd) == real for fd in (proc / "fd").iterdir()):
                return int(proc.name)
        except OSError:
            continue
    return None
