"""Progress of a session for the operator: a bar on a terminal, one plain line per sample otherwise."""

from __future__ import annotations

import sys
import time


class Progress:
    """Samples taken of ``total``, capture rate (samples/s) and the last live error (mm)."""

    def __init__(self, total: int, done: int = 0, stream=None, width: int = 30):
        self.stream = stream or sys.stdout
        self.tty = self.stream.isatty()
        self.total, self.done, self.width = total, done, width
        self.start_done, self.t0 = done, time.monotonic()
        self.last = ""

    @property
    def rate(self) -> float:
        elapsed = time.monotonic() - self.t0
        return (self.done - self.start_done) / elapsed if elapsed > 0 else 0.0

    def sample(self, row: dict, error_mm: float) -> None:
        self.done += 1
        if self.tty:
            filled = int(self.width * self.done / max(self.total, 1))
            self.last = (
                f"[{'#' * filled}{'.' * (self.width - filled)}] {self.done}/{self.total}  "
                f"{self.rate:.1f} samples/s  last error {error_mm:+.3f} mm"
            )
            self.stream.write("\r" + self.last)
        else:
            self.stream.write(
                f"sample {row['sample']} target {row['target']} line {row['line']}: "
                f"length {row['length_mm']:.3f} mm, error {error_mm:+.3f} mm "
                f"({self.done}/{self.total}, {self.rate:.1f}/s)\n"
            )
        self.stream.flush()

    def message(self, text: str) -> None:
        if self.tty:
            self.stream.write("\r\033[K" + text + "\n" + self.last)
        else:
            self.stream.write(text + "\n")
        self.stream.flush()

    def close(self) -> None:
        if self.tty and self.last:
            self.stream.write("\n")
            self.stream.flush()
