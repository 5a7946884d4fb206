"""Sweep passes along a gauge line: the tool kept on the edge, sliding from one end to the other,
its orientation varied along the way, the instruments streaming as it goes.

A pass is a few waypoints (configurations on the line, in order along it); the robot moves
between them with linear moves (``movel``: the TCP on the straight segment, the orientation
turning uniformly about one axis, slerp), blended at the waypoints, so every row swept lies on the
edge (consecutive segments are collinear). Each segment takes the longer of its length at the TCP
speed limit and its turn at the orientation rate limit (:class:`SweepLimits`); a real controller's
ramps at the two ends of a pass add a fraction of a second.

What a pass promises is scored as a static plan is (``calib.experiment.expected_modes``) on its
rows sampled densely along the swept path: the rows a stream records, not only the waypoints.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from calib import ik
from calib.experiment import MIN_CONDITIONING, centre_solutions, tool_turned


@dataclass(frozen=True)
class SweepLimits:
    """How fast a pass may go so that the instruments follow: ``tcp_mm_s`` the TCP's speed along
    the edge [mm/s] (the dial's tip slides on the edge; the drawstring's cable keeps tension),
    ``turn_deg_s`` the tool's orientation rate [deg/s] (the dial's contact point moves on its tip
    as the tool turns), ``row_hz`` the rate at which the station records rows [Hz]."""

    tcp_mm_s: float = 40.0
    turn_deg_s: float = 20.0
    row_hz: float = 240.0


def rotation_angle(r0: np.ndarray, r1: np.ndarray) -> np.ndarray:
    """The angle [rad] (...) of the turn from orientations ``r0`` to ``r1`` (..., 3, 3)."""
    rel = np.swapaxes(r0, -1, -2) @ r1
    cos = (np.trace(rel, axis1=-2, axis2=-1) - 1.0) / 2.0
    return np.arccos(np.clip(cos, -1.0, 1.0))


def slerp(r0: np.ndarray, r1: np.ndarray, s: np.ndarray) -> np.ndarray:
    """Orientations (n, 3, 3) a fraction ``s`` (n,) of the way from ``r0`` to ``r1`` (3, 3),
    turning uniformly about one axis (what a linear move does)."""
    rel = r0.T @ r1
    angle = float(rotation_angle(r0, r1))
    if angle < 1e-12:
        return np.repeat(r0[None], len(s), axis=0)
    axis = np.array([rel[2, 1] - rel[1, 2], rel[0, 2] - rel[2, 0], rel[1, 0] - rel[0, 1]])
    if np.linalg.norm(axis) < 1e-9:  # a half turn: the axis from the symmetric part
        axis = np.sqrt(np.clip((np.diag(rel) + 1.0) / 2.0, 0.0, None))
    axis = axis / np.linalg.norm(axis)
    k = np.array([[0.0, -axis[2], axis[1]], [axis[2], 0.0, -axis[0]], [-axis[1], axis[0], 0.0]])
    a = np.asarray(s, float)[:, None, None] * angle
    turn = np.eye(3) + np.sin(a) * k + (1.0 - np.cos(a)) * (k @ k)
    return r0 @ turn


def segment_durations(position: np.ndarray, rotation: np.ndarray, limits: SweepLimits) -> np.ndarray:
    """Seconds (K-1,) each linear move between waypoints (TCP ``position`` (K, 3) [mm],
    ``rotation`` (K, 3, 3)) takes within ``limits``."""
    length = np.linalg.norm(np.diff(position, axis=0), axis=1)
    turn = np.degrees(rotation_angle(rotation[:-1], rotation[1:]))
    return np.maximum(length / limits.tcp_mm_s, turn / limits.turn_deg_s)


@dataclass(frozen=True)
class SweptRows:
    """The rows a pass records: configurations ``q`` (N, 6) [rad] at times ``t_s`` (N,) [s] from
    the pass's start, and whether each is ``valid`` (reached, inside the joint limits, away from
    singularities); ``duration_s`` the pass's length in time; ``stray`` (N,) [rad] how far each
    row's joints leave the range its segment's two waypoints span (0: within it)."""

    q: np.ndarray
    t_s: np.ndarray
    valid: np.ndarray
    duration_s: float
    stray: np.ndarray


def swept_rows(
    dh: np.ndarray,
    tool: np.ndarray,
    limits_rad: np.ndarray,
    waypoints: np.ndarray,
    sweep: SweepLimits,
    hz: float | None = None,
) -> SweptRows:
    """The configurations a pass through ``waypoints`` (K, 6) [rad] passes at ``hz`` rows a second
    (default ``sweep.row_hz``): each segment a linear move (TCP straight, orientation slerped)
    within ``sweep``'s limits, solved by the nominal inverse kinematics from the joints
    interpolated between its ends."""
    waypoints = continuous(waypoints, limits_rad)
    position, rotation = ik.tool_frames(dh, waypoints, tool)
    durations = segment_durations(position, rotation, sweep)
    start = np.concatenate([[0.0], np.cumsum(durations)])
    total = float(start[-1])
    t = np.linspace(0.0, total, int(np.ceil(total * (hz or sweep.row_hz))) + 1)  # both ends
    seg = np.clip(np.searchsorted(start, t, side="right") - 1, 0, len(durations) - 1)
    s = np.clip((t - start[seg]) / np.maximum(durations[seg], 1e-12), 0.0, 1.0)
    p = position[seg] + s[:, None] * (position[seg + 1] - position[seg])
    rot = np.empty((len(t), 3, 3))
    for k in range(len(durations)):
        on = seg == k
        rot[on] = slerp(rotation[k], rotation[k + 1], s[on])
    seed = waypoints[seg] + s[:, None] * (waypoints[seg + 1] - waypoints[seg])
    q, err = ik.solve(dh, tool, p, rot, seed, iterations=30, damping=1e-6, tol=1e-6)
    inside = np.all((q >= limits_rad[:, 0]) & (q <= limits_rad[:, 1]), axis=1)
    valid = (err < 1e-3) & inside & (ik.conditioning(dh, q, tool) > MIN_CONDITIONING)
    low = np.minimum(waypoints[seg], waypoints[seg + 1])
    high = np.maximum(waypoints[seg], waypoints[seg + 1])
    stray = np.maximum(np.maximum(low - q, q - high), 0.0).max(axis=1)
    return SweptRows(q, t, valid, total, stray)


def continuous(waypoints: np.ndarray, limits_rad: np.ndarray) -> np.ndarray:
    """Waypoints (K, 6) [rad] with each joint shifted by whole turns to stay within half a turn of
    the waypoint before (the way the arm turns through them, not the long way round), then each
    joint's whole pass by whole turns so that its range is centred nearest the limits' middle."""
    q = np.array(waypoints, float)
    for k in range(1, len(q)):
        q[k] -= 2 * np.pi * np.round((q[k] - q[k - 1]) / (2 * np.pi))
    middle = (q.min(axis=0) + q.max(axis=0)) / 2.0
    return q - 2 * np.pi * np.round((middle - limits_rad.mean(axis=1)) / (2 * np.pi))


def joint_move_s(q0: np.ndarray, q1: np.ndarray, speed_rad_s: float, accel_rad_s2: float) -> float:
    """Seconds a synchronous joint move from ``q0`` to ``q1`` (6,) [rad] takes with every joint
    bound by ``speed_rad_s`` and ``accel_rad_s2`` (trapezoidal profile of the joint that moves
    furthest; triangular where it never reaches the speed)."""
    d = float(np.max(np.abs(np.asarray(q1) - np.asarray(q0))))
    ramp = speed_rad_s**2 / accel_rad_s2
    if d <= ramp:
        return 2.0 * np.sqrt(d / accel_rad_s2)
    return d / speed_rad_s + speed_rad_s / accel_rad_s2


@dataclass(frozen=True)
class PassShape:
    """How a pass is drawn: ``waypoints`` along the edge end to end, each with the tool tilted up to
    ``max_tilt_deg`` from the line's approach and rolled up to ``max_roll_deg`` from the start's.
    Wide turns determine the table best: on the demo's cell 45 / 90 deg leave about half the
    true error of 25 / 60 deg where the rows are noise-free, and less over noise draws on every
    seed tried (``benchmarks/sweep_plan_study.py``)."""

    waypoints: int = 6
    max_tilt_deg: float = 45.0
    max_roll_deg: float = 90.0


def roomiest(q: np.ndarray, valid: np.ndarray, limits_rad: np.ndarray) -> np.ndarray | None:
    """Of configurations ``q`` (n, 6) [rad], the valid one furthest from any joint limit (a pass
    turns the wrist both ways from it); None if none is valid."""
    if not valid.any():
        return None
    room = np.minimum(q - limits_rad[:, 0], limits_rad[:, 1] - q).min(axis=1)
    return q[np.argmax(np.where(valid, room, -np.inf))]


def draw_pass(
    dh: np.ndarray,
    tool: np.ndarray,
    limits_rad: np.ndarray,
    line,
    start: np.ndarray,
    shape: PassShape,
    sweep: SweepLimits,
    rng: np.random.Generator,
    reverse: bool = False,
) -> np.ndarray | None:
    """A random pass along ``line`` (point [mm], unit direction, length [mm], unit approach): its
    waypoints (K, 6) [rad] evenly spaced end to end (``reverse``: the other way), each orientation
    drawn within ``shape`` about ``start``'s and turned from the one before by no more than the
    TCP speed lets the turn rate (``sweep``): the pass runs at one TCP speed. None where no draw of
    ``DRAWS`` fits a waypoint."""
    point, direction, length, approach = line
    ends = (0.5, -0.5) if reverse else (-0.5, 0.5)
    positions = point + np.linspace(*ends, shape.waypoints)[:, None] * length * direction
    most_turn = np.radians(sweep.turn_deg_s * length / (shape.waypoints - 1) / sweep.tcp_mm_s)
    found, before = [], None
    for position in positions:
        turns = np.column_stack(
            [
                np.radians(shape.max_tilt_deg) * np.sqrt(rng.uniform(0, 1, DRAWS)),
                rng.uniform(-np.pi, np.pi, DRAWS),
                np.radians(shape.max_roll_deg) * rng.uniform(-1, 1, DRAWS),
            ]
        )
        at = np.repeat(position[None], DRAWS, axis=0)
        q, valid = tool_turned(dh, tool, limits_rad, start, at, approach, turns)
        if before is not None:
            valid &= rotation_angle(before, ik.tool_frames(dh, q, tool)[1]) <= most_turn
        if not valid.any():
            return None
        found.append(q[np.argmax(valid)])
        before = ik.tool_frames(dh, found[-1][None], tool)[1][0]
    return continuous(np.array(found), limits_rad)


STRAY_DEG = 1.0
"""How far a pass's joints may leave the range of its segment's waypoints [deg]."""
DRAWS = 32
"""Orientations drawn for each waypoint of a pass, the first that fits taken."""


def line_passes(
    dh: np.ndarray,
    tool: np.ndarray,
    limits_rad: np.ndarray,
    line,
    shape: PassShape,
    sweep: SweepLimits,
    rng: np.random.Generator,
    n: int,
    tries: int = 200,
) -> list[np.ndarray]:
    """Up to ``n`` random passes along ``line`` whose every swept row (at 4 rows a second) is valid
    and keeps its joints within ``STRAY_DEG`` of the range its segment's waypoints span (each joint
    turning one way between waypoints: a station locates the robot on a pass by that range), from
    the roomiest configuration at its centre, alternating in direction."""
    start = roomiest(*centre_solutions(dh, tool, limits_rad, line, rng), limits_rad)
    found: list[np.ndarray] = []
    for k in range(tries if start is not None else 0):
        q = draw_pass(dh, tool, limits_rad, line, start, shape, sweep, rng, reverse=bool(k % 2))
        rows = None if q is None else swept_rows(dh, tool, limits_rad, q, sweep, hz=4.0)
        if rows is not None and rows.valid.all() and np.degrees(rows.stray.max()) <= STRAY_DEG:
            found.append(q)
            if len(found) == n:
                break
    return found
