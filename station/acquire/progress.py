"""Progress of a session for the operator: a bar on a terminal, one plain line per sample otherwise
(or only the messages); both carry the last live error and the running calibration's predicted
workspace error."""

from __future__ import annotations

import sys
import time


class Progress:
    """Samples taken of ``total``, capture rate (samples/s), the last live error (mm) and the
    latest predicted workspace error (mm, with its 95 % bound)."""

    def __init__(
        self,
        total: int,
        done: int = 0,
        stream=None,
        width: int = 30,
        every_sample: bool = True,
        clock=time.monotonic,
    ):
        self.stream = stream or sys.stdout
        self.clock = clock
        self.tty = self.stream.isatty()
        self.every_sample = every_sample
        self.total, self.done, self.width = total, done, width
        self.start_done, self.t0 = done, clock()
        self.last = ""
        self.workspace = ""  # the latest prediction, as shown
        self._shown = ""  # what the last plain line showed of it
        self._error = ""

    @property
    def rate(self) -> float:
        elapsed = self.clock() - self.t0
        return (self.done - self.start_done) / elapsed if elapsed > 0 else 0.0

    def sample(self, row: dict, live) -> None:
        """A stored sample ``row`` and its ``live`` error (``error_mm``, ``limit_mm``: None until the
        running calibration is judged; then ``fitted`` of ``needed`` samples)."""
        self.done += 1
        error = _error_text(live)
        if self.tty:
            self._bar(error)
            return
        if not self.every_sample:
            return
        predicted = ""
        if self.workspace != self._shown:
            predicted, self._shown = f"; predicted workspace {self.workspace}", self.workspace
        self.stream.write(
            f"sample {row['sample']} target {row['target']} line {row['line']}: "
            f"length {row['length_mm']:.3f} mm, {error} ({self.done}/{self.total}, {self.rate:.1f}/s)"
            f"{predicted}\n"
        )
        self.stream.flush()

    def refit(self, predicted_mm: float, bound_95_mm: float) -> None:
        """The running calibration's latest predicted workspace error [mm] and 95 % bound [mm]."""
        self.workspace = workspace_text(predicted_mm, bound_95_mm)
        if self.tty and self.last:
            self._bar(self._error)

    def show_refit(self, n: int) -> None:
        """Show the latest refit (of ``n`` samples) now where no plain line has shown it yet: the
        one a session stops at is seen before the stop quotes it."""
        if self.tty or not self.every_sample or self.workspace == self._shown:
            return
        self._shown = self.workspace
        self.stream.write(f"running calibration, {n} samples: predicted workspace {self.workspace}\n")
        self.stream.flush()

    def _bar(self, error: str) -> None:
        self._error = error
        filled = int(self.width * self.done / max(self.total, 1))
        workspace = f"  workspace {self.workspace}" if self.workspace else ""
        self.last = (
            f"[{'#' * filled}{'.' * (self.width - filled)}] {self.done}/{self.total}  "
            f"{self.rate:.1f} samples/s  {error}{workspace}"
        )
        self.stream.write("\r\033[K" + self.last)
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


def workspace_text(predicted_mm: float, bound_95_mm: float) -> str:
    """A refit's predicted workspace error and 95 % bound as every line of the session shows them."""
    return f"{predicted_mm:.3g} mm (95 %: {bound_95_mm:.3g} mm)"


def _error_text(live) -> str:
    if live.error_mm is not None:
        return f"error {live.error_mm:+.3f} mm (limit {live.limit_mm:.3f})"
    if live.needed is None:
        return f"{UNDETERMINED} (first fit under way)"
    return f"{UNDETERMINED} ({live.fitted} of {live.needed} samples)"


UNDETERMINED = "error: none until the model is determined"
"""What the progress shows before the live error starts, one phrase for every step of it."""
