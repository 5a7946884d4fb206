"""Measurement configuration selection (MCS): observability indices and simulated annealing.

The indices are computed from the singular values ``s_1 >= ... >= s_m`` of the column-scaled
Jacobian of the identified table parameters with the setup unknowns (anchor, offset, lines)
projected out, over the ``N`` configurations of a subset:

    O1 = (s_1 ... s_m)^(1/m) / sqrt(N)     O2 = s_m / s_1     O3 = s_m
    O4 = s_m^2 / s_1                       O5 = 1 / sum(1 / s_i)

All five are maximised. A subset's information matrix is the sum of its configurations'
``M_i = J_i^T J_i`` (each configuration owns several residual rows), and projecting the setup
unknowns out is the Schur complement ``M_tt - M_ts M_ss^+ M_st``, whose eigenvalues are ``s_i^2``.
Swapping one configuration is then an O(n^2) update, which makes annealing over hundreds of
candidates cheap.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

INDICES = ("O1", "O2", "O3", "O4", "O5")


def configuration_information(jac: np.ndarray, rows: np.ndarray, n_rows: int) -> np.ndarray:
    """Per-configuration information matrices (n_rows, n, n) of the column-normalised ``jac``
    (m, n); ``rows`` (m,) maps each residual to its configuration (rows < 0 are ignored)."""
    scaled = jac / np.maximum(np.linalg.norm(jac[rows >= 0], axis=0), 1e-300)
    info = np.zeros((n_rows, jac.shape[1], jac.shape[1]))
    for r in range(n_rows):
        block = scaled[rows == r]
        info[r] = block.T @ block
    return info


def singular_values(info: np.ndarray, table: np.ndarray) -> np.ndarray:
    """Singular values of the table columns with the other columns projected out, from a summed
    information matrix ``info`` (n, n) and the boolean ``table`` mask (n,)."""
    t, s = np.flatnonzero(table), np.flatnonzero(~table)
    m = info[np.ix_(t, t)]
    if s.size:
        m = m - info[np.ix_(t, s)] @ np.linalg.pinv(info[np.ix_(s, s)]) @ info[np.ix_(s, t)]
    return np.sqrt(np.clip(np.linalg.eigvalsh(m)[::-1], 0.0, None))


def indices(sv: np.ndarray, n_configurations: int) -> dict[str, float]:
    """The five observability indices of singular values ``sv`` for a subset of N configurations."""
    if sv[-1] <= 0:
        return dict.fromkeys(INDICES, 0.0)
    return {
        "O1": float(np.exp(np.mean(np.log(sv))) / np.sqrt(n_configurations)),
        "O2": float(sv[-1] / sv[0]),
        "O3": float(sv[-1]),
        "O4": float(sv[-1] ** 2 / sv[0]),
        "O5": float(1.0 / np.sum(1.0 / sv)),
    }


def index_curve(
    info: np.ndarray, table: np.ndarray, sizes, rng: np.random.Generator, index: str = "O1", repeats: int = 5
) -> np.ndarray:
    """Mean ``index`` of random subsets of each size in ``sizes`` (the paper's Fig. 5a)."""
    n = info.shape[0]
    out = []
    for size in sizes:
        vals = [
            indices(singular_values(info[rng.choice(n, size, replace=False)].sum(0), table), size)[index]
            for _ in range(repeats)
        ]
        out.append(np.mean(vals))
    return np.array(out)


def flattening_size(sizes: np.ndarray, curve: np.ndarray, fraction: float = 0.95) -> int:
    """The smallest size whose index reaches ``fraction`` of the curve's final value."""
    return int(sizes[np.argmax(curve >= fraction * curve[-1])])


@dataclass
class Selection:
    """Chosen configuration ``rows`` (sorted), the index value and its trace over the annealing."""

    rows: np.ndarray
    value: float
    trace: np.ndarray


def anneal(
    info: np.ndarray,
    table: np.ndarray,
    n_select: int,
    groups: np.ndarray,
    rng: np.random.Generator,
    *,
    index: str = "O1",
    min_per_group: int = 4,
    iterations: int = 3000,
) -> Selection:
    """Choose ``n_select`` of the configurations maximising ``index`` by simulated annealing with
    swap moves, keeping at least ``min_per_group`` configurations of every group (gauge line)."""
    n = info.shape[0]
    chosen = _initial(groups, n_select, min_per_group, rng)
    total = info[chosen].sum(0)
    value = indices(singular_values(total, table), n_select)[index]
    best, best_value = chosen.copy(), value
    temp0 = 0.05 * max(abs(value), 1e-12)
    trace = np.empty(iterations)
    for it in range(iterations):
        temp = temp0 * (1e-3 ** (it / iterations))
        out_pos = rng.integers(n_select)
        candidates = np.setdiff1d(np.arange(n), chosen, assume_unique=True)
        new = candidates[rng.integers(candidates.size)]
        old = chosen[out_pos]
        if groups[new] != groups[old] and np.sum(groups[chosen] == groups[old]) <= min_per_group:
            trace[it] = best_value
            continue
        trial = total - info[old] + info[new]
        trial_value = indices(singular_values(trial, table), n_select)[index]
        if trial_value >= value or rng.random() < np.exp((trial_value - value) / temp):
            chosen[out_pos], total, value = new, trial, trial_value
            if value > best_value:
                best, best_value = chosen.copy(), value
        trace[it] = best_value
    return Selection(np.sort(best), float(best_value), trace)


def _initial(groups: np.ndarray, n_select: int, min_per_group: int, rng) -> np.ndarray:
    """A random subset holding ``min_per_group`` of every group (fewer if a group is smaller)."""
    seed = [
        rng.choice(np.flatnonzero(groups == g), min(min_per_group, np.sum(groups == g)), replace=False)
        for g in np.unique(groups)
    ]
    chosen = np.concatenate(seed) if seed else np.array([], int)
    rest = rng.permutation(np.setdiff1d(np.arange(groups.size), chosen))
    return np.concatenate([chosen, rest[: n_select - chosen.size]]).astype(int)


@dataclass
class MCSResult:
    """Selected configurations, the size N (given or where the index flattens) and the curve."""

    selection: Selection
    n_select: int
    sizes: np.ndarray
    curve: np.ndarray


def select_configurations(
    jac: np.ndarray,
    rows: np.ndarray,
    free: np.ndarray,
    line: np.ndarray,
    rng: np.random.Generator,
    *,
    n_select: int | None = None,
    index: str = "O1",
    n_table: int = 24,
) -> MCSResult:
    """MCS over the configurations of a model: ``jac`` (m, n) whitened Jacobian at the setup fit,
    ``rows`` (m,) configuration of each residual, ``free`` (n,) fitted unknowns (the first
    ``n_table`` are the table's), ``line`` (N0,) each configuration's gauge line."""
    n0 = line.size
    info = configuration_information(jac[:, free], rows, n0)
    table = np.flatnonzero(free) < n_table
    start = max(int(table.sum()), 8)
    sizes = np.unique(np.linspace(start, n0, 12).astype(int))
    curve = index_curve(info, table, sizes, rng, index)
    n = n_select or flattening_size(sizes, curve)
    return MCSResult(anneal(info, table, min(n, n0), line, rng, index=index), n, sizes, curve)
