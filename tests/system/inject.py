"""Run ``station`` with a signal sent to itself at a named step, deterministically:

    python -m tests.system.inject SIGNAL before|after MODULE:NAME MATCH -- station-args...

wraps the function ``NAME`` of module ``MODULE`` (``os:replace``, ``rerun:RecordingStream.flush``)
so that its first call with an argument whose text contains ``MATCH`` (``""``: any call) is
preceded or followed by ``SIGNAL`` (``SIGKILL``, ``SIGTERM``) to this process; then runs the
station's console script with the arguments after ``--``. Used to kill or stop a command at each
rename and hand-over instead of by luck of timing.
"""

from __future__ import annotations

import functools
import importlib
import os
import signal
import sys


def inject(sig: signal.Signals, when: str, target: str, match: str) -> None:
    module_name, _, path = target.partition(":")
    *owners, name = path.split(".")
    owner = importlib.import_module(module_name)
    for part in owners:
        owner = getattr(owner, part)
    original = getattr(owner, name)
    fired = []

    @functools.wraps(original)
    def wrapper(*args, **kwargs):
        hit = not fired and any(match in str(a) for a in (*args, *kwargs.values(), ""))
        if hit:
            fired.append(True)
        if hit and when == "before":
            os.kill(os.getpid(), sig)
        result = original(*args, **kwargs)
        if hit and when == "after":
            os.kill(os.getpid(), sig)
        return result

    setattr(owner, name, wrapper)


def main(argv: list[str]) -> int:
    sig, when, target, match, dashes, *rest = argv
    assert dashes == "--" and when in ("before", "after"), argv
    inject(signal.Signals[sig], when, target, match)
    from station import cli

    return cli.main(rest)


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
