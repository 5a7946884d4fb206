"""Poses near a robot program's own: gauge-line contacts a few degrees from where the program works,
so that the residual map (``calib.residual_map``) is learnt where the robot will be used.

Nearness is the map's own: the chord distance ``2 sin(dq / 2)`` of joints 1-3 (those that carry the
arm; ``calib.shared_error.embedding``), shown in degrees. A contact near a program pose is found by
inverse kinematics from that pose: its TCP moved to the nearest point of the gauge line (and a little
along it), the tool turned as little as it takes to meet the edge within the line's tilt allowance.
"""

from __future__ import annotations

import numpy as np

from calib import ik
from calib.experiment import _valid, _wrap_into
from calib.shared_error import distance2, embedding, neighbours

NEAR_DEG = 5.0
"""A contact counts as near a program pose within this chord distance of joints 1-3 [deg]."""
NEAR_POSES = 60
"""Near contacts a plan adds by default."""
ALONG_MM = 60.0
"""Contacts are tried up to this far either way along the line from a program pose's nearest point [mm]."""
TRIES = 4
"""Contacts tried per program pose and gauge line (the first at the nearest point)."""
SITES = 200
"""At most this many of a program's poses, spread over joints 1-3 (``spread``), seed contacts."""
MAX_TILT_DEG = 25.0
"""The tool may meet the edge this far from the line's approach (as ``calib.experiment``)."""


def chord_deg(q: np.ndarray, program_q: np.ndarray) -> np.ndarray:
    """Chord distance of joints 1-3 [deg] (N,) from each configuration ``q`` (N, 6) [rad] to the
    nearest of the program's ``program_q`` (P, 6) [rad]."""
    points, queries = embedding(program_q), embedding(q)
    nearest = neighbours(queries, points, 1)[:, 0]
    return np.degrees(np.linalg.norm(queries - points[nearest], axis=1))


def covered(q: np.ndarray, program_q: np.ndarray, near_deg: float = NEAR_DEG) -> np.ndarray:
    """Which program poses ``program_q`` (P, 6) [rad] have a configuration of ``q`` (N, 6) [rad]
    within ``near_deg`` [deg] (chord distance of joints 1-3) (P,)."""
    return chord_deg(program_q, q) <= near_deg


def toward_cone(z: np.ndarray, axis: np.ndarray, max_tilt_deg: float) -> np.ndarray:
    """The unit directions (N, 3) nearest ``z`` (N, 3) within ``max_tilt_deg`` [deg] of the unit
    ``axis`` (3,): ``z`` itself inside the cone, else the cone's edge towards it."""
    cos = z @ axis
    side = z - cos[:, None] * axis
    norm = np.linalg.norm(side, axis=1)
    fallback = np.cross(axis, np.eye(3)[np.argmin(np.abs(axis))])
    side = np.where(
        norm[:, None] > 1e-9, side / np.maximum(norm, 1e-12)[:, None], fallback / np.linalg.norm(fallback)
    )
    tilt = np.radians(max_tilt_deg)
    edge = np.cos(tilt) * axis + np.sin(tilt) * side
    return np.where((cos >= np.cos(tilt))[:, None], z, edge)


def turned(rotation: np.ndarray, z: np.ndarray) -> np.ndarray:
    """The rotations (N, 3, 3) ``rotation`` (N, 3, 3) turned by the least rotation that takes their
    z axis onto the unit ``z`` (N, 3) (Rodrigues)."""
    z0 = rotation[:, :, 2]
    axis = np.cross(z0, z)
    sin = np.linalg.norm(axis, axis=1)
    cos = np.sum(z0 * z, axis=1)
    k = axis / np.maximum(sin, 1e-12)[:, None]
    cross = np.zeros((len(z), 3, 3))
    cross[:, 0, 1], cross[:, 0, 2], cross[:, 1, 2] = -k[:, 2], k[:, 1], -k[:, 0]
    cross -= cross.transpose(0, 2, 1)
    turn = np.eye(3) + sin[:, None, None] * cross + (1.0 - cos)[:, None, None] * (cross @ cross)
    return turn @ rotation


def line_contacts(
    dh: np.ndarray,
    tool: np.ndarray,
    limits: np.ndarray,
    line: tuple[np.ndarray, np.ndarray, float, np.ndarray],
    program_q: np.ndarray,
    rng: np.random.Generator,
    tries: int = TRIES,
) -> tuple[np.ndarray, np.ndarray]:
    """Configurations (P * tries, 6) [rad] touching a gauge line near the program's poses
    ``program_q`` (P, 6) [rad], each solved from its pose, and which of them (P * tries,) are
    reached inside the limits away from singularities. ``dh``, ``tool``, ``limits`` and ``line`` as
    ``calib.experiment.line_candidates``'s; per pose ``tries`` contacts: the line's nearest point to
    its TCP, then points up to ``ALONG_MM`` either way of it (drawn from ``rng``)."""
    point, direction, length, approach = line
    seeds = np.repeat(program_q, tries, axis=0)
    tcp, rotation = ik.tool_frames(dh, seeds, tool)
    along = np.clip((tcp - point) @ direction, -length / 2, length / 2)
    moved = rng.uniform(-ALONG_MM, ALONG_MM, len(seeds)) * (np.arange(len(seeds)) % tries > 0)
    along = np.clip(along + moved, -length / 2, length / 2)
    rotation = turned(rotation, toward_cone(rotation[:, :, 2], approach, MAX_TILT_DEG))
    q, err = ik.solve(dh, tool, point + along[:, None] * direction, rotation, seeds)
    q = _wrap_into(q, limits)
    return q, _valid(dh, tool, limits, q, err)


def spread(q: np.ndarray, n: int, start=(0,)) -> np.ndarray:
    """Indices of ``n`` of the configurations ``q`` (N, 6) [rad] spread over joints 1-3: those of
    ``start``, then each the farthest from those chosen (all of them where ``n >= N``)."""
    if n >= len(q):
        return np.arange(len(q))
    points = embedding(q)
    chosen = list(start)[:n]
    gap = distance2(points[chosen], points).min(axis=0)
    while len(chosen) < n:
        chosen.append(int(np.argmax(gap)))
        gap = np.minimum(gap, distance2(points[chosen[-1] : chosen[-1] + 1], points)[0])
    return np.sort(np.array(chosen, int))


def choose(q: np.ndarray, program_q: np.ndarray, n: int, near_deg: float = NEAR_DEG) -> np.ndarray:
    """Indices of ``n`` contacts of ``q`` (N, 6) [rad] for the program's poses ``program_q`` (P, 6)
    [rad]: first, greedily, the contact near (``near_deg``, joints 1-3) the most program poses no
    chosen one is near, until every pose any contact is near has one; then the rest ``spread``."""
    near = np.degrees(np.sqrt(distance2(embedding(q), embedding(program_q)))) <= near_deg
    chosen, open_ = [], np.ones(len(program_q), bool)
    while len(chosen) < n:
        gain = near[:, open_].sum(axis=1)
        best = int(np.argmax(gain))
        if gain[best] == 0:
            break
        chosen.append(best)
        open_ &= ~near[best]
    return spread(q, n, chosen or (0,))
