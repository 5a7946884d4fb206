"""The child process that owns ur_rtde's ``RTDEIOInterface`` for :class:`drivers.robot.RtdeTargets`.

    python drivers/rtde_inputs.py HOST

Why a process of its own (ur_rtde 1.6): the IO interface never reads its socket after the
handshake, so ``isConnected()`` stays true after the controller has gone. Its ``disconnect()``
sends a pause request and blocks for the reply (no deadline); on a dead link the write or the read
raises (``read: End of file``) and leaves it "connected". Its destructor calls that same
``disconnect()`` whenever it is still "connected", and an exception out of a C++ destructor is
``std::terminate``: the object, once its controller has gone, aborts whatever process drops it
("write: Broken pipe", SIGABRT). So no station process holds one: this one does, and it never runs
that destructor either (it ends with ``os._exit``, the kernel closing the socket).

Requests on stdin, one JSON object a line; one reply a line on the stdout it was started with
(ur_rtde's own prints go to /dev/null): ``{"ok": true}``, ``{"ok": false}`` (ur_rtde said a write
failed) or ``{"error": "..."}`` (what ur_rtde raised). The first reply says whether the interface
opened (upper-range registers) and wrote ``0`` to int register ``--clear``'s number. Then
``{"op": "write", "registers": [["double" | "int", register, value], ...]}`` writes them in order;
``{"op": "close"}`` disconnects (the pause answered, where the controller is up) and exits;
so does the end of stdin (the station gone). Imports nothing of the station's: it runs by path.
"""

import os
import sys

sys.path[:] = [p for p in sys.path if os.path.abspath(p or ".") != os.path.dirname(os.path.abspath(__file__))]

import json  # noqa: E402


def main(host: str, clear: int) -> None:
    replies = os.fdopen(os.dup(1), "w", buffering=1)
    devnull = os.open(os.devnull, os.O_WRONLY)
    os.dup2(devnull, 1)  # ur_rtde's prints (std::cout) go nowhere, not into the replies

    def reply(**answer) -> None:
        replies.write(json.dumps(answer) + "\n")

    try:
        import rtde_io

        io = rtde_io.RTDEIOInterface(host, False, True)
        io.setInputIntRegister(clear, 0)
    except (RuntimeError, ImportError) as exc:
        reply(error=str(exc))
        return
    reply(ok=True)
    setters = {"double": io.setInputDoubleRegister, "int": io.setInputIntRegister}
    for line in sys.stdin:
        request = json.loads(line)
        if request["op"] == "close":
            try:
                io.disconnect()
            except RuntimeError as exc:  # the controller gone: nothing to pause
                reply(error=str(exc))
                return
            reply(ok=True)
            return
        try:
            ok = all(setters[kind](register, value) for kind, register, value in request["registers"])
        except RuntimeError as exc:
            reply(error=str(exc))
            continue
        reply(ok=bool(ok))


if __name__ == "__main__":
    try:
        main(sys.argv[1], int(sys.argv[2]))
    finally:
        sys.stdout.flush()
        os._exit(0)  # never the IO interface's destructor (module notes)
