"""Rows that share their errors: a sweep's rows along a pass.

A sweep reads tens of rows a second while the tool slides along a gauge edge; what disturbs one row
(the timing's residue, the tool's unmodelled error, the contact across the edge) changes slowly
along the pass, so neighbouring rows share it, across instruments too (one timing error moves the
drawstring's and the dial's model alike). Least squares that takes them as independent states a
covariance several times too small.

The swept rows' part of the covariance is therefore estimated from the residuals themselves,
cluster-robust: each pass's rows in time order are cut into ``BATCHES_PER_PASS`` consecutive
blocks ``c`` (every residual of a row in its row's block), long beside the correlation length, and
each block counts by how far deleting it moves the fit (the delete-a-block jackknife, CR3)::

    g_c = A_c^T e_c,     C_swept = sum_c (N - N_c)^-1 g_c g_c^T (N - N_c)^-1

with ``A = W J`` the weighted Jacobian of the free unknowns, ``e`` the weighted residuals, ``N =
A^T A`` and ``N_c = A_c^T A_c``. Without the deletion (``N^-1 g_c``, CR0) the blocks' residuals are
those the fit already bent towards, and on the demo's sweeps the bound stayed below the true error;
the deletion restores what the fit absorbed of each block. Rows of no pass keep the white model.
"""

from __future__ import annotations

import numpy as np

BATCHES_PER_PASS = 8
"""Consecutive blocks a pass's rows are cut into (a pass of the demo: 400-1,000 rows at 60 Hz, so
blocks of 1-2 s, beside a correlation of about 1 s)."""


def pass_blocks(passes: np.ndarray, t_s: np.ndarray, batches: int = BATCHES_PER_PASS) -> np.ndarray:
    """Each row's block (module docstring): ``batches`` consecutive runs of equal count per pass.

    Parameters
    ----------
    passes : ndarray of int, shape (N,)
        Sweep pass of each row; -1 for a row of no pass (a static pose).
    t_s : ndarray, shape (N,)
        When each row was read [s]: orders a pass's rows.
    batches : int
        Blocks per pass (fewer where a pass has fewer rows).

    Returns
    -------
    ndarray of int, shape (N,)
        Block id (``pass index * batches + block``), -1 for rows of no pass.
    """
    blocks = np.full(passes.shape, -1)
    swept = np.flatnonzero(passes >= 0)
    if swept.size == 0:
        return blocks
    order = swept[np.lexsort((t_s[swept], passes[swept]))]
    index = np.unique(passes[order], return_inverse=True)[1].ravel()
    starts = np.flatnonzero(np.r_[True, index[1:] != index[:-1]])
    sizes = np.diff(np.r_[starts, order.size])
    rank = np.arange(order.size) - np.repeat(starts, sizes)
    per = np.minimum(batches, sizes)[index]
    blocks[order] = index * batches + rank * per // sizes[index]
    return blocks


def block_covariance(
    jac: np.ndarray, free: np.ndarray, w: np.ndarray, residuals: np.ndarray, blocks: np.ndarray
) -> np.ndarray:
    """The swept rows' covariance of the free unknowns, cluster-robust by blocks (CR3, module
    docstring).

    Parameters
    ----------
    jac : ndarray, shape (m, n)
        Jacobian of the whitened residuals.
    free : ndarray of int, shape (k,)
        Columns of the free unknowns.
    w : ndarray, shape (m,)
        The fit's robust weights.
    residuals : ndarray, shape (m,)
        Whitened residuals at the solution.
    blocks : ndarray of int, shape (m,)
        Each residual's block (``pass_blocks`` of its row); -1 for residuals of no block.

    Returns
    -------
    ndarray, shape (k, k)
        Internal units; zero without blocks.
    """
    normal = np.zeros((free.size, free.size))
    for rows in np.array_split(np.arange(len(w)), max(1, len(w) // 20_000)):
        a = jac[np.ix_(rows, free)] * w[rows, None]
        normal += a.T @ a
    cov = np.zeros_like(normal)
    order = np.argsort(blocks, kind="stable")
    ids, starts = np.unique(blocks[order], return_index=True)
    for rows in np.split(order, starts[1:])[int(ids[0] < 0) :]:
        a = jac[np.ix_(rows, free)] * w[rows, None]
        moved = np.linalg.lstsq(normal - a.T @ a, a.T @ (w[rows] * residuals[rows]), rcond=None)[0]
        cov += np.outer(moved, moved)
    return cov
