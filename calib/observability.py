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

from calib.kinematics import N_DH

INDICES = ("O1", "O2", "O3", "O4", "O5")


def configuration_information(
    jac: np.ndarray, rows: np.ndarray, n_rows: int, table: np.ndarray
) -> np.ndarray:
    """Per-configuration information matrices ``M_i = J_i^T J_i`` of the column-normalised Jacobian.

    Parameters
    ----------
    jac : ndarray, shape (m, n)
        Whitened Jacobian of the fitted unknowns.
    rows : ndarray of int, shape (m,)
        Configuration of each residual; rows < 0 (prior rows) are ignored.
    n_rows : int
        Number of configurations.
    table : ndarray of bool, shape (n,)
        Which columns are table parameters; they come first in the result.

    Returns
    -------
    ndarray, shape (n_rows, n, n)
        ``M_i`` with columns reordered table first, each column scaled by its norm over all rows.
    """
    order = np.concatenate([np.flatnonzero(table), np.flatnonzero(~table)])
    jac = jac[:, order]
    scaled = jac / np.maximum(np.linalg.norm(jac[rows >= 0], axis=0), 1e-300)
    info = np.zeros((n_rows, jac.shape[1], jac.shape[1]))
    for r in range(n_rows):
        block = scaled[rows == r]
        info[r] = block.T @ block
    return info


def singular_values(info: np.ndarray, n_table: int) -> np.ndarray:
    """Singular values of the table columns with the setup unknowns projected out: the roots of the
    eigenvalues of the Schur complement ``M_tt - M_ts M_ss^+ M_st``.

    Parameters
    ----------
    info : ndarray, shape (n, n)
        A subset's summed information matrix, table columns first.
    n_table : int
        Number of table columns.

    Returns
    -------
    ndarray, shape (n_table,)
        Singular values, descending, >= 0.
    """
    m = info[:n_table, :n_table]
    cross, setup = info[:n_table, n_table:], info[n_table:, n_table:]
    if setup.size:
        try:
            m = m - cross @ np.linalg.solve(setup, cross.T)
        except np.linalg.LinAlgError:
            m = m - cross @ np.linalg.pinv(setup) @ cross.T
    return np.sqrt(np.clip(np.linalg.eigvalsh(m)[::-1], 0.0, None))


def indices(sv: np.ndarray, n_configurations: int) -> dict[str, float]:
    """The five observability indices (module docstring).

    Parameters
    ----------
    sv : ndarray, shape (k,)
        Singular values, descending.
    n_configurations : int
        Size N of the subset (O1 divides by sqrt(N)).

    Returns
    -------
    dict of str to float
        ``O1`` .. ``O5``; all 0 when the smallest singular value is 0.
    """
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
    info: np.ndarray, n_table: int, sizes, rng: np.random.Generator, index: str = "O1", repeats: int = 5
) -> np.ndarray:
    """Mean index of random subsets by size (the paper's Fig. 5a).

    Parameters
    ----------
    info : ndarray, shape (N0, n, n)
        Per-configuration information (``configuration_information``).
    n_table : int
        Number of table columns.
    sizes : sequence of int
        Subset sizes, each <= N0.
    rng : numpy.random.Generator
        Draws the subsets.
    index : str
        One of ``INDICES``.
    repeats : int
        Subsets averaged per size.

    Returns
    -------
    ndarray, shape (len(sizes),)
        Mean index per size.
    """
    n = info.shape[0]
    out = []
    for size in sizes:
        vals = [
            indices(singular_values(info[rng.choice(n, size, replace=False)].sum(0), n_table), size)[index]
            for _ in range(repeats)
        ]
        out.append(np.mean(vals))
    return np.array(out)


def flattening_size(sizes: np.ndarray, curve: np.ndarray, fraction: float = 0.95) -> int:
    """Where an index curve flattens.

    Parameters
    ----------
    sizes : ndarray of int, shape (k,)
        Subset sizes, ascending.
    curve : ndarray, shape (k,)
        Index per size (``index_curve``).
    fraction : float
        Share of the curve's last value to reach.

    Returns
    -------
    int
        The smallest size whose index reaches ``fraction`` of the last value.
    """
    return int(sizes[np.argmax(curve >= fraction * curve[-1])])


@dataclass
class Selection:
    """Chosen configuration ``rows`` (sorted), the index value and its trace over the annealing."""

    rows: np.ndarray
    value: float
    trace: np.ndarray


def anneal(
    info: np.ndarray,
    n_table: int,
    n_select: int,
    groups: np.ndarray,
    rng: np.random.Generator,
    *,
    index: str = "O1",
    min_per_group: int = 4,
    iterations: int = 3000,
) -> Selection:
    """Choose configurations maximising an index by simulated annealing with swap moves.

    The temperature falls geometrically from 5 % of the start value to 1e-3 of that; a swap that
    would leave a group (gauge line) with fewer than ``min_per_group`` is not tried.

    Parameters
    ----------
    info : ndarray, shape (N0, n, n)
        Per-configuration information (``configuration_information``).
    n_table : int
        Number of table columns.
    n_select : int
        How many to choose, < N0.
    groups : ndarray of int, shape (N0,)
        Gauge line of each configuration.
    rng : numpy.random.Generator
        Drives the start and the moves.
    index : str
        One of ``INDICES``.
    min_per_group : int
        Configurations kept on every line (fewer where a line has fewer).
    iterations : int
        Swap trials.

    Returns
    -------
    Selection
        The best subset seen, its index value and the best value after each trial.
    """
    n = info.shape[0]
    chosen = _initial(groups, n_select, min_per_group, rng)
    total = info[chosen].sum(0)
    value = indices(singular_values(total, n_table), n_select)[index]
    best, best_value = chosen.copy(), value
    temp0 = 0.05 * max(abs(value), 1e-12)
    trace = np.empty(iterations)
    inside = np.zeros(n, bool)
    inside[chosen] = True
    for it in range(iterations):
        temp = temp0 * (1e-3 ** (it / iterations))
        out_pos = rng.integers(n_select)
        new = rng.integers(n)
        while inside[new]:
            new = rng.integers(n)
        old = chosen[out_pos]
        if groups[new] != groups[old] and np.sum(groups[chosen] == groups[old]) <= min_per_group:
            trace[it] = best_value
            continue
        trial = total - info[old] + info[new]
        trial_value = indices(singular_values(trial, n_table), n_select)[index]
        if trial_value >= value or rng.random() < np.exp((trial_value - value) / temp):
            chosen[out_pos], total, value = new, trial, trial_value
            inside[old], inside[new] = False, True
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
    n_table: int = N_DH,
) -> MCSResult:
    """Measurement configuration selection over the configurations of a model.

    Parameters
    ----------
    jac : ndarray, shape (m, n)
        Whitened Jacobian at the setup fit.
    rows : ndarray of int, shape (m,)
        Configuration of each residual (< 0: prior rows).
    free : ndarray of bool, shape (n,)
        The fitted unknowns; the first ``n_table`` entries of the vector are the table's.
    line : ndarray of int, shape (N0,)
        Gauge line of each configuration.
    rng : numpy.random.Generator
        Drives the index curve and the annealing.
    n_select : int, optional
        How many to choose; default where the index curve flattens (``flattening_size``).
    index : str
        One of ``INDICES``.
    n_table : int
        Number of table parameters at the head of the vector.

    Returns
    -------
    MCSResult
        The selection (every configuration when N reaches N0), N, and the index curve.
    """
    n0 = line.size
    table = np.flatnonzero(free) < n_table
    info = configuration_information(jac[:, free], rows, n0, table)
    n_tab = int(table.sum())
    sizes = np.unique(np.linspace(max(n_tab, 8), n0, 12).astype(int))
    curve = index_curve(info, n_tab, sizes, rng, index)
    n = n_select or flattening_size(sizes, curve)
    if n >= n0:
        everything = Selection(
            np.arange(n0), indices(singular_values(info.sum(0), n_tab), n0)[index], np.array([])
        )
        return MCSResult(everything, n0, sizes, curve)
    return MCSResult(anneal(info, n_tab, n, line, rng, index=index), n, sizes, curve)
