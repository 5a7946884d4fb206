"""A scripted instrument on a real pty for byte-exact tests: it expects exact request bytes and
answers with exact reply bytes, as a vendor manual lists them."""

from __future__ import annotations

import os
import select
import threading
import time

from sim_fixtures.serial_device import PtyPort


class ScriptedSerial:
    """Answers ``script`` [(expected request, reply), ...] in order on a pty at ``link``.

    ``received`` collects what the driver actually sent, one entry per script step; a step whose
    request does not arrive within ``timeout_s`` ends the script (the driver then times out).
    """

    def __init__(self, link, script, timeout_s=2.0):
        self.port = PtyPort(link)
        self.script = list(script)
        self.timeout_s = timeout_s
        self.received: list[bytes] = []
        self._thread = threading.Thread(target=self._run, daemon=True)

    def __enter__(self):
        self._thread.start()
        return self

    def __exit__(self, *exc_info):
        self._thread.join(timeout=self.timeout_s + 1)
        self.port.unplug()

    def _read_exactly(self, n: int) -> bytes:
        got, deadline = b"", time.monotonic() + self.timeout_s
        while len(got) < n and (left := deadline - time.monotonic()) > 0:
            if select.select([self.port.master], [], [], left)[0]:
                got += os.read(self.port.master, n - len(got))
        return got

    def _run(self) -> None:
        for expected, reply in self.script:
            got = self._read_exactly(len(expected))
            self.received.append(got)
            if got != expected:
                return
            if reply:
                os.write(self.port.master, reply)
