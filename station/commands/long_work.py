"""Long work in a command: progress lines on stderr while it lasts, and a refusal, before it
starts, of work the machine's memory cannot hold."""

from __future__ import annotations

import ctypes
import sys
import threading
import time

from errors import InputError

PROGRESS_S = 10.0
"""A progress line this often [s] while the work lasts (none for work done sooner)."""
CALIBRATE_ROW_BYTES = 7_000
"""Peak memory of ``station calibrate`` per sample row [bytes]: 6.1 KB measured between 100,000 and
1,000,000 rows (``benchmarks/calibrate_scaling.py``), rounded up."""
CALIBRATE_BASE_BYTES = 150_000_000
"""Its peak memory with few rows [bytes] (the interpreter, numpy, scipy: 111 MB measured on 2,000)."""


class Ticker:
    """While open, every ``every_s`` [s] a line ``"<label>: <stage>, <elapsed> s so far"`` on
    ``stream`` (stderr); :meth:`stage` names what is being done (said at once once lines began)."""

    def __init__(self, label: str, every_s: float = PROGRESS_S, stream=None):
        self.label, self.every_s = label, every_s
        self.stream = stream if stream is not None else sys.stderr
        self._stage, self._said = "starting", False
        self._t0 = time.monotonic()
        self._done = threading.Event()
        self._lock = threading.Lock()
        self._thread = threading.Thread(target=self._run, daemon=True, name="progress")

    def __enter__(self) -> Ticker:
        self._t0 = time.monotonic()
        self._thread.start()
        return self

    def __exit__(self, *exc) -> None:
        self._done.set()
        self._thread.join()

    def stage(self, text: str) -> None:
        with self._lock:
            self._stage = text
            if self._said:
                self._say()

    def _run(self) -> None:
        while not self._done.wait(self.every_s):
            with self._lock:
                self._say()

    def _say(self) -> None:
        self._said = True
        elapsed = time.monotonic() - self._t0
        self.stream.write(f"{self.label}: {self._stage}, {elapsed:.0f} s so far\n")
        self.stream.flush()


M_TRIM_THRESHOLD, M_MMAP_MAX = -1, -4
"""glibc's ``mallopt`` parameters (``malloc.h``)."""


def reuse_freed_memory() -> None:
    """Have glibc's malloc serve big arrays from its heap and keep what is freed for the next one
    (no ``mmap``, no trimming; nothing where the C library has no ``mallopt``): a calibration
    allocates and frees Jacobians of hundreds of MB at every evaluation, and each fresh mapping is
    paid again in page faults (100,000 rows: about a quarter of the command's CPU time)."""
    libc = ctypes.CDLL(None)
    if hasattr(libc, "mallopt"):
        libc.mallopt(M_MMAP_MAX, 0)
        libc.mallopt(M_TRIM_THRESHOLD, 2**31 - 1)


def available_memory_bytes() -> int | None:
    """Memory the system can give a process now (``MemAvailable``, Linux); None where unknown."""
    try:
        with open("/proc/meminfo") as fh:
            for line in fh:
                if line.startswith("MemAvailable:"):
                    return int(line.split()[1]) * 1024
    except (OSError, ValueError, IndexError):
        return None
    return None


def check_calibrate_memory(where: str, rows: int, available: int | None) -> None:
    """Refuse (InputError) a calibration of ``rows`` rows whose estimated peak memory exceeds the
    ``available`` bytes (None: unknown, no check); ``where`` names the samples."""
    need = CALIBRATE_BASE_BYTES + CALIBRATE_ROW_BYTES * rows
    if available is None or need <= available:
        return
    most = max((available - CALIBRATE_BASE_BYTES) // CALIBRATE_ROW_BYTES, 0)
    raise InputError(
        f"{where}: {rows} rows need about {need / 1e9:.1f} GB of memory to calibrate "
        f"({CALIBRATE_ROW_BYTES / 1e3:.0f} KB a row) and {available / 1e9:.1f} GB is available: at most "
        f"about {most} rows here; average repeated captures of a target into one row, or calibrate "
        "on a machine with more memory"
    )
