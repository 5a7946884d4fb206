"""A simulated robot program that sweeps: the tool slides along each gauge edge through a pass's
waypoints, contact kept, orientation varying; the robot stops only at a pass's two ends.

The path of one pass (computed once, at start): between consecutive waypoints (true
configurations whose TCPs touch the true line) the contact pose is interpolated, position linearly
(so the TCP stays on the true line, off it along the dial axis by the waypoints' placements, blended)
and orientation by spherical interpolation, every ``KNOT_MM`` of TCP travel; the true robot's IK
solves each knot (seeded by the joint-linear blend of the two waypoints). Between knots the joints
are interpolated linearly: the TCP leaves the edge sideways by the chord's sag, which grows with
the knots' spacing squared (2 mm knots: up to 14 um where the tool turns fast, enough to bias a
sweep's calibration by 0.1 mm; 0.5 mm: under 1 um, half the dial's noise).
The time law along a pass is a trapezoid in the TCP's arc length: ``speed_mm_s`` and
``accel_mm_s2`` (simulated), as a controller's linear move (``movel``) with blending would.

The cycle, forever: dwell ``dwell_s`` at pass 0's first waypoint, sweep to its last, dwell there,
move (joint space, ``sim_fixtures.robot_program``'s synchronised trapezoid) to pass 1's first, ...
and from the last pass back to pass 0. Times as in ``SimRobot``: ``state(t_s)`` takes real seconds,
the program runs on ``t_s * time_scale`` simulated seconds. ``RobotState.target_index`` is the
plan row of the waypoint the robot is nearest along its pass (the next pass's first on a transit),
``speed_mm_s`` the TCP's speed along the line (0 on transits and dwells: the transit's is not the
sweep's, and a transit is off the edge anyway).
"""

from __future__ import annotations

import bisect
import dataclasses
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from scipy.spatial.transform import Rotation, Slerp

from sim_fixtures.robot_program import RUNNING, RobotState, move_duration, trapezoid

KNOT_MM = 0.5  # TCP travel between the IK-solved knots of a pass's path


@dataclass(frozen=True)
class PassPath:
    """One pass's dense path: arc length ``s_mm`` (K,) along the TCP path, joints ``q_deg`` (K, 6)
    there, and the plan rows of its waypoints ``rows`` with their arc lengths ``row_s_mm``."""

    s_mm: np.ndarray
    q_deg: np.ndarray
    rows: np.ndarray
    row_s_mm: np.ndarray

    @property
    def length_mm(self) -> float:
        return float(self.s_mm[-1])

    def at(self, s_mm: float) -> tuple[np.ndarray, np.ndarray]:
        """Joints [deg] at arc length ``s_mm`` and their derivative [deg/mm]."""
        k = int(np.clip(np.searchsorted(self.s_mm, s_mm, side="right") - 1, 0, max(len(self.s_mm) - 2, 0)))
        if len(self.s_mm) == 1:
            return self.q_deg[0].copy(), np.zeros(6)
        ds = self.s_mm[k + 1] - self.s_mm[k]
        w = (s_mm - self.s_mm[k]) / ds
        slope = (self.q_deg[k + 1] - self.q_deg[k]) / ds
        return self.q_deg[k] + w * (self.q_deg[k + 1] - self.q_deg[k]), slope

    def nearest_row(self, s_mm: float) -> int:
        return int(self.rows[int(np.argmin(np.abs(self.row_s_mm - s_mm)))])


def pass_path(robot, q_way_deg: np.ndarray, rows: np.ndarray) -> PassPath:
    """The dense path through waypoints ``q_way_deg`` (W, 6) [deg] of the true ``robot``
    (``sim_fixtures.world.Robot``), plan rows ``rows`` (W,) (module notes)."""
    poses = np.array([robot.pose(q) for q in q_way_deg])
    s_all, q_all, row_s = [0.0], [q_way_deg[0]], [0.0]
    for a in range(len(q_way_deg) - 1):
        pa, pb = poses[a, :3, 3], poses[a + 1, :3, 3]
        n = max(int(np.ceil(np.linalg.norm(pb - pa) / KNOT_MM)), 1)
        w = np.arange(1, n + 1) / n
        slerp = Slerp([0.0, 1.0], Rotation.from_matrix(poses[a : a + 2, :3, :3]))
        targets = np.repeat(np.eye(4)[None], n, axis=0)
        targets[:, :3, :3] = slerp(w).as_matrix()
        targets[:, :3, 3] = pa + w[:, None] * (pb - pa)
        seeds = q_way_deg[a] + w[:, None] * (q_way_deg[a + 1] - q_way_deg[a])
        q, reached = robot.ik(targets, seeds)
        q[~reached] = seeds[
            ~reached
        ]  # (a knot the true robot misses: its blend, as a controller's joint move)
        q[-1] = q_way_deg[a + 1]
        start = s_all[-1]
        s_all += list(start + w * np.linalg.norm(pb - pa))
        q_all += list(q)
        row_s.append(s_all[-1])
    return PassPath(np.array(s_all), np.array(q_all), np.asarray(rows, int), np.array(row_s))


@dataclass(frozen=True)
class _Piece:
    """A dwell at pass ``p``'s end (``at_end``) or start, a sweep along pass ``p``, or a transit
    from pass ``p``'s last waypoint to pass ``to``'s first; from ``start_s``, lasting ``duration_s``."""

    start_s: float
    duration_s: float
    kind: str  # "dwell", "sweep" or "transit"
    p: int
    to: int = 0
    at_end: bool = False


class SweepRobot:
    """The sweeping program over ``paths`` (one :class:`PassPath` per pass, in order); transits at
    ``speed_deg_s`` / ``accel_deg_s2``, sweeps at ``speed_mm_s`` / ``accel_mm_s2``, dwells of
    ``dwell_s`` (all simulated); ``hold``: still at pass 0's start for good."""

    def __init__(
        self,
        paths: list[PassPath],
        *,
        speed_mm_s: float,
        accel_mm_s2: float,
        speed_deg_s: float,
        accel_deg_s2: float,
        dwell_s: float,
        time_scale: float = 1.0,
        hold: bool = False,
    ):
        if not paths:
            raise ValueError("a sweep needs one pass at least")
        self.paths = paths
        self.speed_mm_s, self.accel_mm_s2 = float(speed_mm_s), float(accel_mm_s2)
        self.speed_deg_s, self.accel_deg_s2 = float(speed_deg_s), float(accel_deg_s2)
        self.dwell_s, self.time_scale, self.hold = float(dwell_s), float(time_scale), hold
        self.targets_deg = np.array([p.q_deg[0] for p in paths])  # where each pass starts
        self._pieces = self._schedule()
        self._starts = [p.start_s for p in self._pieces]
        self.cycle_s = self._pieces[-1].start_s + self._pieces[-1].duration_s

    def _schedule(self) -> list[_Piece]:
        pieces, t = [], 0.0
        for p, path in enumerate(self.paths):
            nxt = (p + 1) % len(self.paths)
            sweep = move_duration(path.length_mm, self.speed_mm_s, self.accel_mm_s2)
            way = float(np.max(np.abs(self.paths[nxt].q_deg[0] - path.q_deg[-1])))
            transit = move_duration(way, self.speed_deg_s, self.accel_deg_s2)
            for duration, kind, at_end in (
                (self.dwell_s, "dwell", False),
                (sweep, "sweep", False),
                (self.dwell_s, "dwell", True),
                (transit, "transit", True),
            ):
                pieces.append(_Piece(t, duration, kind, p, nxt, at_end))
                t += duration
        return pieces

    def sweep_seconds(self) -> float:
        """Simulated seconds of one cycle (every pass swept once, with its dwells and transits)."""
        return self.cycle_s

    def state(self, t_s: float) -> RobotState:
        """Where the robot is ``t_s`` real seconds after the program started."""
        q, qd, row, dwelling, speed = self._at(max(t_s * self.time_scale, 0.0))
        return RobotState(q, qd, RUNNING, row, dwelling, speed)

    def _at(self, prog_s: float):
        if self.hold:
            path = self.paths[0]
            return path.q_deg[0].copy(), np.zeros(6), int(path.rows[0]), True, 0.0
        tau = prog_s % self.cycle_s
        piece = self._pieces[bisect.bisect_right(self._starts, tau) - 1]
        path = self.paths[piece.p]
        into = tau - piece.start_s
        if piece.kind == "dwell":
            k = -1 if piece.at_end else 0
            return path.q_deg[k].copy(), np.zeros(6), int(path.rows[k]), True, 0.0
        if piece.kind == "sweep":
            s, sd = trapezoid(path.length_mm, into, self.speed_mm_s, self.accel_mm_s2)
            q, slope = path.at(s)
            return q, slope * sd, path.nearest_row(s), False, float(sd)
        a, b = path.q_deg[-1], self.paths[piece.to].q_deg[0]
        way = b - a
        length = float(np.max(np.abs(way)))
        if length == 0.0:
            return b.copy(), np.zeros(6), int(self.paths[piece.to].rows[0]), False, 0.0
        s, sd = trapezoid(length, into, self.speed_deg_s, self.accel_deg_s2)
        return a + way * (s / length), way * (sd / length), int(self.paths[piece.to].rows[0]), False, 0.0


@dataclass(frozen=True)
class SweptReadings:
    """Rows along a sweeping robot's passes: joints [deg] (N, 6) at the rows' stamps ``t_s`` (N,)
    [s] and where the robot was ``late_s`` after them (``q_late``: what a drawstring measuring late
    read), line ids and pass ids (N,)."""

    q: np.ndarray
    q_late: np.ndarray
    t_s: np.ndarray
    lines: np.ndarray
    passes: np.ndarray


def swept_rows(robot: SweepRobot, plan_lines, paths: list, hz: float, late_s: float = 0.0) -> SweptReadings:
    """The rows ``hz`` a second along every sweep of ``robot`` (over ``paths``, each pass's line
    the plan's ``plan_lines`` of its first row), as :class:`SweptReadings`."""
    q, q_late, t_s, lines, passes = [], [], [], [], []
    for k, piece in enumerate(p for p in robot._pieces if p.kind == "sweep"):
        t = np.arange(piece.start_s, piece.start_s + piece.duration_s, 1.0 / hz)
        q.append(np.array([robot.state(s).q_deg for s in t]))
        q_late.append(np.array([robot.state(s + late_s).q_deg for s in t]))
        t_s.append(t)
        lines.append(np.full(len(t), plan_lines[paths[piece.p].rows[0]]))
        passes.append(np.full(len(t), k))
    return SweptReadings(*(np.concatenate(a) for a in (q, q_late, t_s, lines, passes)))


def write_swept(world, rows: SweptReadings, rng, path: Path, timed: bool = True) -> None:
    """``rows`` read once at ``world``'s noise into the samples CSV ``path``: lengths and dial where
    the robot was (``rows.q_late``), joints at the stamps; ``timed``: with the ``pass`` and ``t_s``
    columns a sweep session writes."""
    read = world.measure(rows.q_late, rows.lines, rng)
    read = dataclasses.replace(read, q_deg=rows.q + (read.q_deg - rows.q_late))
    read.to_csv(path)
    if timed:
        head, *body = Path(path).read_text().splitlines()
        extra = (f"{a},{p},{t:.6f}" for a, p, t in zip(body, rows.passes, rows.t_s, strict=True))
        Path(path).write_text("\n".join([head + ",pass,t_s", *extra]) + "\n")
