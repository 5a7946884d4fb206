"""The running calibration of a session: refits off the capture path, the live error of every
sample against the latest refit, and the guidance its predicted workspace error gives.

Refits run in a worker process (:class:`FitWorker`), one at a time: the session hands it every
sample taken so far and carries on capturing; when it answers, the next refit starts on all
samples taken by then, so refits coalesce when they fall behind the captures. A process and not
a thread because the solver's Python loop holds the GIL: a refit thread would delay the capture
path's reads by the interpreter's switch interval each time (``benchmarks/live_fit.py``).

The live error of a sample is its reading minus the length the latest refit predicts, taken
before the sample joins a fit, once the samples determine the unknowns (``Refit.judged``; 26
samples on the simulated cell's first line): then the prediction carries an uncertainty, and a
reading more than ``SUSPECT_SIGMAS`` of it (and of the noise) off is called suspect. Before that
there is no live error: a fit of fewer samples than unknowns extrapolates to the next pose by up
to millimetres (in simulated cells, 0.3-2 mm typical over the first seven samples, 15 mm once),
which says nothing about the reading. Guidance, once per gauge line: the line stops paying when its last
``SATURATION_SAMPLES`` samples improved the predicted workspace error by less than
``SATURATION_GAIN``; the message names the next placement (the plan's next line, else the
planner's best new one, else the model's advice).

Corrected targets: a worker started with the plan's rows corrects every plan target for the model
of each judged refit, in the same job (``station.jobs.correction``, milliseconds; a job of its own
would cost a round trip between refits), and the listener's ``corrected`` hears them: the session
hands them to a running program (``station.acquire.targets``).
"""

from __future__ import annotations

import contextlib
import dataclasses
import multiprocessing
import os
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from calib.kinematics import base_from_frames, tcp_position, tool_point
from calib.params import dh_from_degrees
from station.formats.tables import RobotFile, SetupFile
from station.jobs.correction import TargetCorrection, correct_targets
from station.jobs.planning import NextPlacement, next_placement
from station.jobs.planning import vector_text as _vec
from station.jobs.running import Refit, SessionSamples, refit

SUSPECT_SIGMAS = 5.0
WORKER_NICE = 10
SATURATION_SAMPLES, SATURATION_GAIN = 10, 0.05
WORKER_ENDED = "running calibration stopped: the worker process ended; sampling goes on"


class FitFailed(Exception):
    """A job the worker could not finish; the message says why."""


def _job(kind: str, robot: RobotFile, setup: SetupFile, samples: SessionSamples, plan_rows):
    if kind == "refit":
        fit = refit(robot, setup, samples)
        if plan_rows is None or not fit.judged:
            return fit
        try:
            targets = correct_targets(robot, setup, fit, *plan_rows)
        except Exception as exc:  # noqa: BLE001 - the refit stands; the session says why once
            targets = FitFailed(f"{type(exc).__name__}: {exc}")
        return dataclasses.replace(fit, targets=targets)
    return next_placement(robot, setup, samples.q_deg, samples.line)


def _serve(conn, robot: RobotFile, setup: SetupFile, plan_rows=None) -> None:
    """The worker process: answer each ``(kind, samples)`` with ``(kind, result)`` until the pipe
    closes; a failed job answers with :class:`FitFailed`. Says ``("ready", None)`` first.
    ``plan_rows``: the plan's joints (M, 6) [deg] and lines (M,), corrected with each judged refit."""
    _yield_cpu()
    try:
        conn.send(("ready", None))
        while True:
            kind, samples = conn.recv()
            try:
                result = _job(kind, robot, setup, samples, plan_rows)
            except Exception as exc:  # noqa: BLE001 - reported to the session, which goes on
                result = FitFailed(f"{type(exc).__name__}: {exc}")
            conn.send((kind, result))
    except (EOFError, OSError):  # the station closed the pipe, or is gone
        return


def _yield_cpu() -> None:
    """Leave the CPU to the capture path: niceness ``WORKER_NICE`` and, on Linux, an autogroup of
    its own at that niceness (in the session's autogroup, the fit's CPU time counts against the
    capture path's share of a loaded machine). Not the idle class: a browser showing the live view
    on the same machine would starve the running calibration."""
    try:
        os.setsid()
        with open("/proc/self/autogroup", "w") as fh:
            fh.write(str(WORKER_NICE))
    except (AttributeError, OSError):
        pass
    os.nice(WORKER_NICE)


class FitWorker:
    """Jobs (``"refit"``, ``"next"``) on a session's samples in a worker process, one at a time,
    over the pipe ``conn`` to ``proc`` (:meth:`start` spawns them): :meth:`submit` never waits,
    :meth:`poll` returns a finished ``(kind, result)`` or None. Once the process is gone (killed,
    crashed) the worker has ``ended``: never busy, it drops every job."""

    def __init__(self, conn, proc):
        self._conn, self._proc = conn, proc
        self.busy = True  # until it says it is ready
        self.ended = False

    @classmethod
    def start(cls, robot: RobotFile, setup: SetupFile, plan_rows=None) -> FitWorker:
        """A worker for ``robot`` and ``setup``; with ``plan_rows`` (joints (M, 6) [deg], lines (M,))
        each judged refit carries the plan's corrected targets (``Refit.targets``)."""
        ctx = multiprocessing.get_context("spawn")  # no fork of a process with device threads
        conn, child = ctx.Pipe()
        proc = ctx.Process(
            target=_serve, args=(child, robot, setup, plan_rows), daemon=True, name="station-refit"
        )
        with _one_blas_thread():  # the spawned interpreter reads these as numpy loads
            proc.start()
        child.close()
        return cls(conn, proc)

    def wait_ready(self, timeout_s: float) -> bool:
        """Wait up to ``timeout_s`` for the worker to have started (imports take a second or two)."""
        self.poll(timeout_s)
        return not self.busy

    def submit(self, kind: str, samples: SessionSamples) -> None:
        if self.ended:
            return
        try:
            self._conn.send((kind, samples))
        except OSError:  # BrokenPipeError, ConnectionResetError: the process is gone
            self._end()
            return
        self.busy = True

    def poll(self, timeout_s: float = 0.0):
        """The finished job's ``(kind, result)``, waiting up to ``timeout_s``; None if none."""
        try:
            if not self.busy or not self._conn.poll(timeout_s):
                return None
            answer = self._conn.recv()
        except (EOFError, OSError):
            self._end()
            return None
        self.busy = False
        return None if answer[0] == "ready" else answer

    def _end(self) -> None:
        self.ended, self.busy = True, False

    def close(self) -> None:
        self._conn.close()
        self._proc.terminate()
        self._proc.join(timeout=5)


@contextlib.contextmanager
def _one_blas_thread():
    """The environment a worker starts in: one BLAS/OpenMP thread (one core for the fit; OpenBLAS
    threads spin while they wait, taking a second core from the capture path)."""
    keys = ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS")
    saved = {k: os.environ.get(k) for k in keys}
    os.environ.update(dict.fromkeys(keys, "1"))
    try:
        yield
    finally:
        for k, v in saved.items():
            if v is None:
                os.environ.pop(k)
            else:
                os.environ[k] = v


@dataclass(frozen=True)
class LiveError:
    """A sample against the running calibration: the length it predicted ``model_mm``, the
    ``error_mm`` (reading - model) and ``limit_mm``, the largest error the prediction's
    uncertainty and the noise explain (``SUSPECT_SIGMAS`` of them), all None until a refit is
    judged; ``suspect`` beyond the limit. Before that, the latest refit's ``fitted`` samples of the
    ``needed`` (None before the first refit)."""

    model_mm: float | None = None
    error_mm: float | None = None
    limit_mm: float | None = None
    fitted: int | None = None
    needed: int | None = None

    @property
    def suspect(self) -> bool:
        return self.error_mm is not None and abs(self.error_mm) > self.limit_mm


@dataclass
class LiveListener:
    """What the running calibration reports: each ``refit``, ``message(text)`` for the operator,
    ``reached(text)`` once the ``until_mm`` goal is met, and each judged refit's corrected plan
    targets (``corrected``)."""

    refit: Callable[[Refit], None] = lambda r: None
    message: Callable[[str], None] = lambda text: None
    reached: Callable[[str], None] = lambda text: None
    corrected: Callable[[TargetCorrection], None] = lambda c: None


class RunningCalibration:
    """The running calibration of a session on ``robot`` and ``setup`` following a plan with
    gauge lines ``plan_lines`` (M,), refitting with ``worker`` (its judged refits carry the plan's
    corrected targets where it was started with the plan: ``listener.corrected``); ``until_mm`` is
    the 95 % workspace bound that ends the session."""

    def __init__(
        self,
        robot: RobotFile,
        setup: SetupFile,
        worker,
        plan_lines: np.ndarray,
        listener: LiveListener | None = None,
        until_mm: float | None = None,
    ):
        self.robot, self.setup, self.worker = robot, setup, worker
        self.listener = listener or LiveListener()
        self.until_mm = until_mm
        self.plan_lines = [int(v) for v in dict.fromkeys(plan_lines)]  # distinct, in plan order
        self.dh = dh_from_degrees(robot.table_deg())
        self.tool = np.asarray(robot.tool_mm, float)
        self.samples = SessionSamples(np.empty((0, 6)), np.empty(0), np.empty(0), np.empty(0, int))
        self.latest: Refit | None = None
        # each judged refit's predicted workspace error [mm] and samples per line (not the refit: it
        # holds its samples, and a long session's refits together would hold N^2 rows)
        self.history: list[tuple[float, dict[int, int]]] = []
        self.saturated: set[int] = set()
        self.goal_met = False
        self._want_next = False  # a planner suggestion is wanted and not yet started
        self._refit_n = 0  # samples in the latest refit started (a failed one is not retried on them)
        self._said_undetermined = False
        self._said_ended = False
        self._said_uncorrected = False

    def nominal_tcp_mm(self, q_deg) -> np.ndarray:
        """Nominal TCPs (N, 3) [mm] of configurations (N, 6) [deg]."""
        return tcp_position(self.dh, np.radians(np.atleast_2d(q_deg)), self.tool)

    def nominal_chain_mm(self, q_deg) -> tuple[np.ndarray, np.ndarray]:
        """The nominal robot at ``q_deg`` (6,) [deg]: its D-H frame origins, base to flange, and
        the TCP (8, 3) [mm], and the tool's approach (the flange's z axis, unit, base frame)."""
        frames = base_from_frames(self.dh, np.radians(np.atleast_2d(q_deg)))[0]
        tcp = tool_point(frames[None, -1], self.tool)[0]
        return np.vstack([frames[:, :3, 3], tcp]), frames[-1, :3, 2]

    def live_error(self, q_deg, length_mm: float) -> LiveError:
        """The sample against the latest refit (before it joins one), once a refit is judged."""
        fit = self.latest
        if fit is None:
            return LiveError()
        if not fit.judged:
            return LiveError(fitted=fit.n, needed=fit.needed)
        model_mm, sigma_mm = fit.predict(q_deg, self.setup.drawstring.sigma_mm)
        limit = SUSPECT_SIGMAS * float(np.hypot(sigma_mm, fit.noise_mm))
        return LiveError(model_mm, float(length_mm) - model_mm, limit)

    def add(self, q_deg, length_mm: float, dial_mm: float, line: int, refit: bool = True) -> None:
        """A stored sample: joins the next refit (started now if the worker is idle and ``refit``:
        a resumed session's samples are added all before the first refit starts, on all of them)."""
        s = self.samples
        self.samples = SessionSamples(
            np.vstack([s.q_deg, np.asarray(q_deg, float)[None]]),
            np.append(s.length_mm, float(length_mm)),
            np.append(s.dial_mm, float(dial_mm)),
            np.append(s.line, int(line)),
        )
        if refit:
            self._next_job()

    def poll(self, timeout_s: float = 0.0) -> Refit | None:
        """Look in on the worker (waiting up to ``timeout_s``): a finished refit is reported and
        judged for guidance, and the next job starts whenever the worker is idle (also once it is
        ready, for samples added while it started). Returns the refit that arrived, if any."""
        answer = self.worker.poll(timeout_s)
        fit = None if answer is None else self._answer(*answer)
        self._next_job()
        return fit

    def _answer(self, kind: str, result) -> Refit | None:
        if isinstance(result, FitFailed):
            self.listener.message(f"running calibration: {kind} failed: {result}")
        elif kind == "next":
            self.listener.message(_next_text(result))
        else:
            self._take(result)
            return result
        return None

    def _next_job(self) -> None:
        if self.worker.busy or self._ended():
            return
        if self._want_next:
            self.worker.submit("next", self.samples)
            self._want_next = False
        elif len(self.samples) > self._refit_n:
            self.worker.submit("refit", self.samples)
            self._refit_n = len(self.samples)
        self._ended()  # the submit found the worker gone

    def _ended(self) -> bool:
        """Whether the worker process is gone (the session goes on without it); said once."""
        if self.worker.ended and not self._said_ended:
            self._said_ended = True
            self.listener.message(WORKER_ENDED)
        return self.worker.ended

    def _take(self, fit: Refit) -> None:
        self.latest = fit
        self.listener.refit(fit)
        if not fit.judged:
            if not self._said_undetermined:
                self._said_undetermined = True
                self.listener.message(
                    f"running calibration: live errors and the predicted workspace error start once "
                    f"the samples determine the model ({fit.n} of {fit.needed} so far; the number needed "
                    "grows while the first samples let the fit see more of the robot's parameters)"
                )
            return
        if not self.history:
            self.listener.message(f"running calibration: the model is determined by {fit.n} samples")
        if isinstance(fit.targets, FitFailed):
            if not self._said_uncorrected:
                self._said_uncorrected = True
                self.listener.message(f"running calibration: correcting the targets failed: {fit.targets}")
        elif fit.targets is not None:
            self.listener.corrected(fit.targets)
        counts = _counts(self.samples.line[: fit.n])
        self.history.append((fit.workspace.predicted_rmse_mm, counts))
        self._saturation(fit, counts)
        bound = fit.workspace.predicted_rmse_95_mm
        if self.until_mm is not None and not self.goal_met and bound <= self.until_mm:
            self.goal_met = True
            self.listener.reached(
                f"accuracy reached: predicted workspace error {fit.workspace.predicted_rmse_mm:.3g} mm, "
                f"95 % bound {bound:.3g} mm <= {self.until_mm:g} mm after {fit.n} samples"
            )

    def _saturation(self, fit: Refit, counts: dict[int, int]) -> None:
        """Say once per line when its last samples stopped paying (see the module notes)."""
        line = int(self.samples.line[fit.n - 1])
        if line < 0 or line in self.saturated:
            return
        earlier = [e for e, c in self.history if c.get(line, 0) <= counts[line] - SATURATION_SAMPLES]
        if not earlier:
            return
        before, now = earlier[-1], fit.workspace.predicted_rmse_mm
        gain = 1.0 - now / before
        if gain >= SATURATION_GAIN:
            return
        self.saturated.add(line)
        bound = fit.workspace.predicted_rmse_95_mm
        change = f"improved it only {100 * gain:.0f} %" if gain > 0 else "did not improve it"
        head = (
            f"line {line} saturated at {now:.3g} mm predicted (95 %: {bound:.3g} mm): "
            f"its last {SATURATION_SAMPLES} samples {change}"
        )
        self.listener.message(f"{head}; next: {self._next_placement(fit, counts)}")

    def _next_placement(self, fit: Refit, counts: dict[int, int]) -> str:
        """The plan's next unmeasured line; else the planner's best new line (asked of the worker,
        reported when it answers) where the setup places its lines; else the model's advice."""
        for lid in self.plan_lines:
            if counts.get(lid, 0) == 0:
                return _planned_line_text(self.setup, lid)
        if all(ln.point_mm is not None and ln.direction is not None for ln in self.setup.lines) and (
            self.setup.lines
        ):
            self._want_next = True
            self._next_job()
            return "the planner is placing a new line (a message follows)"
        return fit.advice

    def close(self) -> None:
        self.worker.close()


def _counts(line: np.ndarray) -> dict[int, int]:
    ids, counts = np.unique(line, return_counts=True)
    return {int(i): int(c) for i, c in zip(ids, counts, strict=True)}


def _planned_line_text(setup: SetupFile, lid: int) -> str:
    placed = next((ln for ln in setup.lines if ln.id == lid), None)
    if placed is None or placed.point_mm is None or placed.direction is None:
        return f"line {lid} of the plan"
    return f"line {lid} of the plan (through {_vec(placed.point_mm, 0)} mm along {_vec(placed.direction, 2)})"


def _next_text(found: NextPlacement | None) -> str:
    if found is None:
        return "next placement: the planner found no better line near the present ones"
    return (
        f"next placement: a line along {_vec(found.direction, 2)} through {_vec(found.point_mm, 0)} mm, "
        f"tool approach {_vec(found.approach, 2)}: the planner expects it to cut the predicted workspace "
        f"error by {100 * found.gain:.0f} %"
    )


def line_segments(tcp_mm: np.ndarray, line_ids: np.ndarray) -> dict[int, np.ndarray]:
    """Each gauge line as a segment (2, 3): the principal axis of its TCPs, over their extent."""
    out = {}
    for lid in np.unique(line_ids):
        p = tcp_mm[line_ids == lid]
        centre = p.mean(axis=0)
        direction = _principal_axis(p - centre)
        s = (p - centre) @ direction
        out[int(lid)] = centre + np.outer([s.min() - 20.0, s.max() + 20.0], direction)
    return out


def _principal_axis(centred: np.ndarray) -> np.ndarray:
    """The unit direction (3,) of largest spread of the points ``centred`` (n, 3): the leading
    eigenvector of their 3 x 3 scatter matrix (memory and time linear in n); x for one point."""
    if len(centred) < 2:
        return np.array([1.0, 0.0, 0.0])
    return np.linalg.eigh(centred.T @ centred)[1][:, -1]
