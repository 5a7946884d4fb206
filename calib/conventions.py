"""Craig's modified D-H (``mdh``) as the standard D-H table the maths computes with.

Modified, row i: ``Rx(alpha_{i-1}) Tx(a_{i-1}) Rz(theta_i + q_i) Tz(d_i)``: row i holds alpha and
a of the link before joint i. Regrouped, with row 1's alpha and a zero (joint 1 in the base frame),

    T = prod_i Rx(alpha_{i-1}) Tx(a_{i-1}) Rz(theta_i + q_i) Tz(d_i)
      = prod_{i<6} [Rz(theta_i + q_i) Tz(d_i) Tx(a_i) Rx(alpha_i)] * Rz(theta_6 + q_6) Tz(d_6),

(``Rx`` and ``Tx`` commute), which is the standard table with row i's theta and d and row i+1's a
and alpha; the standard last row's a and alpha (an offset of the flange after joint 6, which the
modified table has no row for) is the ``flange`` pair. Both tables give the same flange frame
and TCP at every reading. Tables are (6, 4) in ``calib.params.DH_KEYS`` order (theta, d, a, alpha),
in any consistent units. A link's centre of mass moves with its frame: Craig's frame i sits at joint
i, the standard one at the link's far end, ``Tx(a_i) Rx(alpha_i)`` further (``com_from_mdh``).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from calib.kinematics import ALPHA, N_JOINTS, A

LINK = [A, ALPHA]
"""The columns a modified row takes from the link before its joint."""


def dh_from_mdh(mdh: np.ndarray, flange=(0.0, 0.0)) -> np.ndarray:
    """The standard table (6, 4) of a modified one (6, 4) whose row 1 has alpha = a = 0, with the
    ``flange`` (a, alpha) after joint 6."""
    dh = np.array(mdh, float)
    dh[:-1, LINK] = mdh[1:, LINK]
    dh[-1, LINK] = flange
    return dh


def mdh_from_dh(dh: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The modified table (6, 4) (row 1's alpha and a zero) and the flange (a, alpha) of a standard
    one: the inverse of :func:`dh_from_mdh`."""
    mdh = np.array(dh, float)
    mdh[1:, LINK] = dh[:-1, LINK]
    mdh[0, LINK] = 0.0
    return mdh, np.array(dh[-1, LINK], float)


def mdh_name(name: str) -> str:
    """A standard table parameter's name (``J2.a_mm``) as the modified table names it: a and alpha
    of joint i < 6 are row i+1's (``J3.a_mm``), joint 6's the flange's (``flange.a_mm``); other
    names are kept."""
    joint, _, key = name.partition(".")
    if not (joint[:1] == "J" and joint[1:].isdigit() and key.split("_")[0] in ("a", "alpha")):
        return name
    i = int(joint[1:])
    return f"flange.{key}" if i == N_JOINTS else f"J{i + 1}.{key}"


def dh_name(name: str) -> str:
    """The inverse of :func:`mdh_name`."""
    joint, _, key = name.partition(".")
    if key.split("_")[0] not in ("a", "alpha"):
        return name
    if joint == "flange":
        return f"J{N_JOINTS}.{key}"
    if joint[:1] == "J" and joint[1:].isdigit() and int(joint[1:]) > 1:
        return f"J{int(joint[1:]) - 1}.{key}"
    return name


def _link_end(dh: np.ndarray) -> tuple[np.ndarray, tuple[np.ndarray, np.ndarray]]:
    """Each standard row's a (6,) and the cosine and sine of its alpha (6,): the step from a
    modified frame i (at joint i) to the standard frame i (at the link's end), ``Tx(a_i) Rx(alpha_i)``."""
    alpha = dh[:, ALPHA]
    return dh[:, A], (np.cos(alpha), np.sin(alpha))


def com_from_mdh(com_mdh: np.ndarray, dh: np.ndarray) -> np.ndarray:
    """Each link's centre of mass (6, 3) in the standard frames of the table ``dh`` (6, 4) (rad, mm)
    from its place in the modified frames (6, 3) [mm] (Craig's frame i sits at joint i):
    ``Rx(-alpha_i) (c - a_i x)``."""
    a, (c, s) = _link_end(dh)
    x, y, z = np.asarray(com_mdh, float).T
    x = x - a
    return np.column_stack([x, c * y + s * z, -s * y + c * z])


def com_to_mdh(com_dh: np.ndarray, dh: np.ndarray) -> np.ndarray:
    """The inverse of :func:`com_from_mdh`: ``a_i x + Rx(alpha_i) c``."""
    a, (c, s) = _link_end(dh)
    x, y, z = np.asarray(com_dh, float).T
    return np.column_stack([x + a, c * y - s * z, s * y + c * z])


def model_joints(reading_deg, sign, offset_deg) -> np.ndarray:
    """The model's joints [deg] (..., 6) of a controller's readings ``reading_deg`` (..., 6) under
    its joint convention: ``q_model = sign * reading + offset_deg`` (``sign`` (6,) of +-1,
    ``offset_deg`` (6,) [deg]; contract: a robot file's ``[controller]``)."""
    return np.asarray(sign, float) * np.asarray(reading_deg, float) + np.asarray(offset_deg, float)


def controller_joints(q_deg, sign, offset_deg) -> np.ndarray:
    """The controller's readings [deg] (..., 6) of the model's joints ``q_deg`` (..., 6): the
    inverse of :func:`model_joints` (``sign`` is its own inverse)."""
    return np.asarray(sign, float) * (np.asarray(q_deg, float) - np.asarray(offset_deg, float))


SIGN_PATTERNS = np.array(
    [[-1.0 if k >> j & 1 else 1.0 for j in range(N_JOINTS)] for k in range(1, 2**N_JOINTS)]
)
"""The 63 ways to flip some joints' signs (joint 1 first), fewest flips ranked first by the caller."""


@dataclass(frozen=True)
class ConventionMistake:
    """A controller convention that puts settles which matched no target on targets: the corrected
    ``joint_sign`` (6,) and ``joint_offset_deg`` (6,) [deg], the joints whose sign it flips
    (``flipped``, 0-based) or the one it shifts (``shifted``: joint, deg added), the target row
    each settle then lies at (``targets`` (N,), -1: none), and the joints whose sign those settles
    cannot tell (``untold``: flipping them too explains as many)."""

    joint_sign: np.ndarray
    joint_offset_deg: np.ndarray
    flipped: tuple[int, ...]
    shifted: tuple[int, float] | None
    targets: np.ndarray
    untold: tuple[int, ...] = ()


def nearest_targets(q_deg, targets_deg, match_deg: float) -> np.ndarray:
    """The row of ``targets_deg`` (M, 6) each of ``q_deg`` (N, 6) lies at (max |dq| within
    ``match_deg`` [deg]), -1 where none."""
    dist = np.max(np.abs(np.asarray(q_deg, float)[:, None] - np.asarray(targets_deg, float)[None]), axis=2)
    nearest = np.argmin(dist, axis=1)
    return np.where(dist[np.arange(len(nearest)), nearest] <= match_deg, nearest, -1)


def convention_mistake(
    settled_deg, targets_deg, match_deg: float, sign=(1,) * 6, offset_deg=(0.0,) * 6, least: int = 3
) -> ConventionMistake | None:
    """Which mistake in a controller's joint convention (``sign`` (6,), ``offset_deg`` (6,) [deg])
    puts the robot's settles ``settled_deg`` (N, 6) [deg, model joints as read] away from every
    target ``targets_deg`` (M, 6) [deg] (max |dq| over ``match_deg``): some joints' signs flipped
    (the 63 patterns), or one joint's zero off by a constant (a half or whole turn, or any). The
    convention that puts the most settles on targets, at least ``least`` and half of them (fewest
    flips first, signs before offsets); None if none does."""
    readings = controller_joints(settled_deg, sign, offset_deg)
    n = len(readings)
    need = max(least, (n + 1) // 2)
    best = _sign_mistake(readings, targets_deg, match_deg, sign, offset_deg)
    shift = _offset_mistake(readings, targets_deg, match_deg, sign, offset_deg)
    if shift is not None and (best is None or np.sum(shift.targets >= 0) > np.sum(best.targets >= 0)):
        best = shift
    return best if best is not None and np.sum(best.targets >= 0) >= need else None


def _sign_mistake(readings, targets_deg, match_deg, sign, offset_deg) -> ConventionMistake | None:
    """The sign pattern (fewest flips first) that puts the most readings on targets."""
    sign, offset = np.asarray(sign, float), np.asarray(offset_deg, float)
    patterns = sorted(SIGN_PATTERNS, key=lambda f: int(np.sum(f < 0)))
    hits = [
        nearest_targets(model_joints(readings, f * sign, offset), targets_deg, match_deg) for f in patterns
    ]
    counts = {tuple(f): int(np.sum(h >= 0)) for f, h in zip(patterns, hits, strict=True)}
    k = int(np.argmax(list(counts.values())))
    flip = patterns[k]
    if not counts[tuple(flip)]:
        return None
    untold = tuple(
        j
        for j in range(N_JOINTS)
        if flip[j] > 0 and counts[tuple(np.where(np.arange(6) == j, -1.0, flip))] == counts[tuple(flip)]
    )
    flipped = tuple(int(j) for j in np.flatnonzero(flip < 0))
    return ConventionMistake(flip * sign, offset, flipped, None, hits[k], untold)


def _offset_mistake(readings, targets_deg, match_deg, sign, offset_deg) -> ConventionMistake | None:
    """The one joint and constant [deg] whose shift puts the most readings on targets (the
    constant: the median of the shifts at the targets it puts them on, to 0.01 deg)."""
    q = model_joints(readings, sign, offset_deg)
    targets = np.asarray(targets_deg, float)
    best, most = None, 0
    for j in range(N_JOINTS):
        others = np.delete(np.arange(N_JOINTS), j)
        near = np.max(np.abs(q[:, None, others] - targets[None, :, others]), axis=2) <= match_deg
        diff = targets[None, :, j] - q[:, None, j]  # (N, M): the shift that puts reading i on target m
        shifts = np.unique(np.round(diff[near & (np.abs(diff) > match_deg)], 2))
        if not shifts.size:
            continue
        on = near[None] & (np.abs(diff[None] - shifts[:, None, None]) <= match_deg)  # (K, N, M)
        counts = on.any(axis=2).sum(axis=1)
        k = int(np.argmax(counts))
        if counts[k] > most:
            shift = round(float(np.median(diff[on[k]])), 2)
            most, best = int(counts[k]), (j, shift)
    if best is None:
        return None
    j, shift = best
    offset = np.array(offset_deg, float)
    offset[j] += shift
    hits = nearest_targets(model_joints(readings, sign, offset), targets, match_deg)
    return ConventionMistake(np.asarray(sign, float), offset, (), (j, shift), hits)
