"""The error neighbouring poses share (the residual map's second stage, ``calib.residual_map``):
``calib.discrepancy`` finds that a real arm's residual changes smoothly with the joints (poses a few
degrees apart share it); here it is predicted by Gaussian-process regression of the rows' residual
vectors (base frame, mm; each component independent, one kernel) over joints 1-3 (the chord
distance ``2 sin(dq / 2)`` per joint, as ``discrepancy``) with the squared-exponential kernel::

    cov(e(q), e(q')) = shared * exp(-d(q, q')^2 / (2 l^2)),   plus ``noise`` on each row,

``shared + noise`` the rows' mean square per component. Local: each pose from its ``NEIGHBOURS``
nearest rows (the chord distance of joints 1-3 is the Euclidean distance of their cosines and
sines), so 12,000 rows cost one batch of small solves, not a 12,000 x 12,000 one. The length and
the shared share are those of least error on ``FOLDS`` interleaved folds (row ``i`` in fold
``i mod FOLDS``: a pose predicted from poses measured around it, which is what the map is for), the
variances scaled so the folds' standardised errors average one. Rows that observe projections of
the error (a drawstring's, a dial's) take the same kernel through their observation operator
(``ObservedShared``).

Near measured poses the prediction's variance tightens; far from them the mean falls back to zero
(the table alone) and the variance to the rows' own mean square.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from calib.angle_errors import FOLDS, MIN_GAIN, clear_gain
from calib.blocks import each_block, halved

MAP_JOINTS = 3
"""The map's kernel reads joints 1-3 (those that carry the arm)."""
LENGTH_SCALES_DEG = (2.0, 3.0, 5.0, 7.0, 10.0, 15.0, 25.0)
"""Correlation lengths tried [deg of joints 1-3] (``calib.discrepancy``'s grid)."""
SHARED_FRACTIONS = (0.5, 0.75, 0.9, 0.97)
"""Shares of the rows' mean square tried for the shared error (ratios 1, 3, 9, 32 to the noise)."""
NEIGHBOURS = 40
"""Rows each prediction is computed from (a position instrument's: three components each)."""
OBSERVED_NEIGHBOURS = 60
"""Observations each prediction is computed from where rows observe projections of the error."""
CV_ROWS = 2000
"""At most this many rows (evenly spaced) are predicted in the cross-validation."""
POSTERIOR_ROWS = 256
"""Queries per block of the posteriors' solves (``calib.blocks``: two threads)."""
CHUNK = 1024
"""Query poses per block of the neighbour search (memory: CHUNK x rows distances)."""
SCAN_PAIRS = 20_000_000
"""Above this many query-point pairs the neighbour search takes a k-d tree, not every distance."""


@dataclass(frozen=True)
class SharedError:
    """The error neighbouring poses share, as a local Gaussian process over joints 1-3.

    Attributes
    ----------
    q : ndarray, shape (N, 6)
        The rows' joint readings [rad].
    error_mm : ndarray, shape (N, 3)
        Their residuals, measured minus the table's TCP, base frame [mm].
    length_scale_deg : float
        Correlation length over joints 1-3 [deg].
    shared_mm2, noise_mm2 : float
        Variance per component [mm^2] of the shared error and of what no neighbour shares.
    cv_rmse_mm, table_cv_rmse_mm : float
        3-D RMS error [mm] of the rows predicted from the other folds, with the map and the table
        alone.
    """

    q: np.ndarray
    error_mm: np.ndarray
    length_scale_deg: float
    shared_mm2: float
    noise_mm2: float
    cv_rmse_mm: float
    table_cv_rmse_mm: float

    @property
    def explained(self) -> float:
        """Share of the cross-validated mean square error it takes out."""
        return 1.0 - (self.cv_rmse_mm / self.table_cv_rmse_mm) ** 2

    def predict(self, q: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """The shared error's posterior mean (M, 3) [mm, base frame] at the poses ``q`` (M, 6)
        [rad], and the variance per component (M,) [mm^2] of what is left there after it: the
        posterior variance plus what no neighbour shares (``noise_mm2``, the instrument's noise
        included). Far from the rows: mean 0 and the table's own mean square."""
        points = embedding(self.q)
        queries = embedding(np.asarray(q, float))
        index = neighbours(queries, points, NEIGHBOURS)
        distances = local_distances(queries, points, index)
        length = np.radians(self.length_scale_deg)
        mean, variance = local_posterior(
            distances, self.error_mm[index], length, self.shared_mm2, self.noise_mm2
        )
        return mean, variance + self.noise_mm2


@dataclass(frozen=True)
class ObservedShared:
    """The shared error (``SharedError``'s kernel, one Gaussian process per base-frame component)
    learnt from observations of its projections (``calib.map_rows``): observation ``k`` of the pose
    ``q[k]`` reads ``direction[k] . e(q[k])`` plus noise, so two observations covary by the kernel
    times the dot product of their directions (the Gaussian process with a linear observation
    operator; a tracker's rows are the case of the three axes).

    Attributes
    ----------
    q : ndarray, shape (K, 6)
        The pose of each observation [rad].
    direction : ndarray, shape (K, 3)
        Its unit direction, base frame.
    value_mm : ndarray, shape (K,)
        What it observed of the error the angle errors leave [mm].
    length_scale_deg, shared_mm2, noise_mm2, cv_rmse_mm, table_cv_rmse_mm : float
        As ``SharedError``'s (the fold errors over the held-out observations, as three components
        of their mean square).
    """

    q: np.ndarray
    direction: np.ndarray
    value_mm: np.ndarray
    length_scale_deg: float
    shared_mm2: float
    noise_mm2: float
    cv_rmse_mm: float
    table_cv_rmse_mm: float

    def predict(self, q: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """``SharedError.predict``: the posterior mean (M, 3) [mm, base frame] at the poses ``q``
        (M, 6) [rad], and the variance per component (M,) [mm^2] of what is left there (the mean
        of the three components' posterior variances, plus ``noise_mm2``)."""
        points = embedding(self.q)
        queries = embedding(np.asarray(q, float))
        index = neighbours(queries, points, OBSERVED_NEIGHBOURS)
        distances = local_distances(queries, points, index)
        near = self.direction[index]
        dots = np.matmul(near, near.transpose(0, 2, 1))
        length = np.radians(self.length_scale_deg)
        mean, variance = observed_posterior(
            distances, dots, near, self.value_mm[index], length, self.shared_mm2, self.noise_mm2
        )
        return mean, np.mean(variance, axis=1) + self.noise_mm2


def embedding(q: np.ndarray) -> np.ndarray:
    """Cosines and sines (N, 2 MAP_JOINTS) of joints 1-3 of ``q`` (N, 6) [rad]: their Euclidean
    distances are the chord distances [rad] of ``calib.discrepancy.joint_distance2``."""
    z = q[:, :MAP_JOINTS]
    return np.hstack([np.cos(z), np.sin(z)])


def distance2(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Squared Euclidean distances (M, N) between the rows of ``a`` (M, d) and ``b`` (N, d)."""
    d2 = np.sum(a**2, axis=1)[:, None] + np.sum(b**2, axis=1)[None, :] - 2.0 * a @ b.T
    return np.maximum(d2, 0.0)


def neighbours(queries: np.ndarray, points: np.ndarray, k: int, fold=None, query_fold=None) -> np.ndarray:
    """Indices (M, k') of the ``k`` nearest ``points`` (N, d) to each of ``queries`` (M, d),
    ``k' = min(k, N)``; with ``fold`` (N,) and ``query_fold`` (M,), only points of another fold.

    Every distance (``CHUNK`` queries at a time) where there are at most ``SCAN_PAIRS`` of them,
    else a k-d tree (per fold of the queries, of the other folds' points): on 100,000 rows the
    scan took 40 s and 10 GB. Both exact; among points at the same distance either may pick
    another, and the order of the k' is not the same."""
    k = min(k, points.shape[0] - (0 if fold is None else int(np.bincount(fold).max())))
    if queries.shape[0] * points.shape[0] > SCAN_PAIRS:
        return tree_neighbours(queries, points, k, fold, query_fold)
    out = np.empty((queries.shape[0], k), int)
    for start in range(0, queries.shape[0], CHUNK):
        block = slice(start, start + CHUNK)
        d2 = distance2(queries[block], points)
        if fold is not None:
            d2[query_fold[block, None] == fold[None, :]] = np.inf
        out[block] = np.argpartition(d2, k - 1, axis=1)[:, :k]
    return out


def tree_neighbours(queries: np.ndarray, points: np.ndarray, k: int, fold=None, query_fold=None):
    """``neighbours`` by scipy's k-d tree (imported here: the small searches of a default ``station
    calibrate`` need no scipy, issue 26), ``k`` at most the points outside each query's fold."""
    from scipy.spatial import cKDTree

    out = np.empty((queries.shape[0], k), int)
    if fold is None:
        fold, query_fold = np.zeros(points.shape[0], int), np.full(queries.shape[0], -1)
    for f in np.unique(query_fold):
        asking, others = query_fold == f, np.flatnonzero(fold != f)
        tree = cKDTree(points[others], balanced_tree=False, compact_nodes=False)
        out[asking] = others[tree.query(queries[asking], k)[1].reshape(-1, k)]
    return out


def local_distances(queries: np.ndarray, points: np.ndarray, index: np.ndarray) -> tuple[np.ndarray, ...]:
    """Squared distances among each query's neighbours ``index`` (M, k) -> (M, k, k), and from the
    query to them (M, k), of embedded poses ``queries`` (M, d) and ``points`` (N, d)."""
    near = points[index]
    norm = np.sum(near**2, axis=2)
    among = norm[:, :, None] + norm[:, None, :] - 2.0 * np.matmul(near, near.transpose(0, 2, 1))
    cross = np.sum((near - queries[:, None, :]) ** 2, axis=2)
    return np.maximum(among, 0.0), cross


def local_posterior(
    distances: tuple[np.ndarray, np.ndarray],
    values: np.ndarray,
    length_rad: float,
    shared: float,
    noise: float,
) -> tuple[np.ndarray, np.ndarray]:
    """Gaussian-process posterior at each query from its k neighbours.

    Parameters
    ----------
    distances : tuple of ndarray, shapes (M, k, k), (M, k)
        ``local_distances`` of the queries' neighbours [rad^2].
    values : ndarray, shape (M, k, c)
        The neighbours' values [mm], each component independent under the one kernel.
    length_rad, shared, noise : float
        Correlation length [rad], shared and noise variance per component [mm^2].

    Returns
    -------
    mean : ndarray, shape (M, c)
    variance : ndarray, shape (M,)
        Of the shared error (without the noise) per component [mm^2].
    """
    among, to_query = distances
    mean, variance = np.empty((values.shape[0], values.shape[2])), np.empty(values.shape[0])

    def block(s: int, e: int) -> None:
        def shared_covariance(out: np.ndarray) -> None:
            kernel(among[s:e], length_rad, out)
            out *= shared

        cross = shared * kernel(to_query[s:e], length_rad)
        y = whitened(shared_covariance, noise, np.concatenate([values[s:e], cross[:, :, None]], axis=2))
        mean[s:e] = np.einsum("mk,mkc->mc", y[:, :, -1], y[:, :, :-1])
        variance[s:e] = shared - np.einsum("mk,mk->m", y[:, :, -1], y[:, :, -1])

    each_block(len(mean), halved(len(mean), POSTERIOR_ROWS), block)
    return mean, np.maximum(variance, 0.0)


def kernel(distances: np.ndarray, length_rad: float, out: np.ndarray | None = None) -> np.ndarray:
    """The squared-exponential correlations ``exp(-d / (2 l^2))`` of squared ``distances`` [rad^2]
    at ``length_rad`` [rad], into ``out`` (default a new array) without temporaries (a search's grid
    of lengths over (M, k, k) arrays: they cost as much as the exponentials)."""
    out = np.divide(distances, -2.0 * length_rad**2, out=out)
    return np.exp(out, out=out)


def whitened(shared_covariance, noise: float, rhs: np.ndarray) -> np.ndarray:
    """``L^-1 rhs`` (M, k, r) for ``L`` the lower Cholesky factor of each query's covariance, the
    positive semi-definite part ``shared_covariance(out)`` writes into ``out`` (M, k, k) plus
    ``noise`` > 0 on the diagonal, ``rhs`` (M, k, r): the last r rows of the factor of the bordered
    matrix ``[[cov, rhs], [rhs^T, d I]]``, ``d`` above ``|L^-1 rhs|^2`` (numpy has no batched
    triangular solve; a Cholesky of k + r rows costs about half of an LU solve of k)."""
    m, k, r = rhs.shape
    bordered = np.empty((m, k + r, k + r))
    shared_covariance(bordered[:, :k, :k])
    diagonal = bordered.reshape(m, -1)[:, :: k + r + 1]  # a view of each matrix's diagonal
    diagonal[:, :k] += noise
    bordered[:, :k, k:] = 0.0
    bordered[:, k:, :k] = rhs.transpose(0, 2, 1)
    bordered[:, k:, k:] = 0.0
    # |L^-1 rhs|^2 <= |rhs|^2 / noise: the Schur complement d I - (L^-1 rhs)^T L^-1 rhs stays positive
    diagonal[:, k:] = (1.0 + 2.0 * np.einsum("mkr,mkr->m", rhs, rhs) / noise)[:, None]
    return np.linalg.cholesky(bordered)[:, k:, :k].transpose(0, 2, 1)


def observed_posterior(
    distances: tuple[np.ndarray, np.ndarray],
    dots: np.ndarray,
    facing: np.ndarray,
    values: np.ndarray,
    length_rad: float,
    shared: float,
    noise: float,
) -> tuple[np.ndarray, np.ndarray]:
    """Gaussian-process posterior at each query from its k neighbouring observations of projections.

    Two observations covary by the squared-exponential of their poses' ``distances``
    (``local_distances`` [rad^2]) at ``length_rad`` [rad] times the dot product of their unit
    directions; an observation and a direction asked about at the query by the kernel times their
    dot product.

    Parameters
    ----------
    distances : tuple of ndarray, shapes (M, k, k), (M, k)
        ``local_distances`` of the queries' neighbouring observations [rad^2].
    dots : ndarray, shape (M, k, k)
        The dot products of the neighbours' directions among themselves.
    facing : ndarray, shape (M, k, c)
        Their dot products with the c unit directions asked about at each query (the base frame's
        axes: the directions themselves; an observation's own, (M, k, 1)).
    values : ndarray, shape (M, k)
        What the neighbours observed [mm].
    length_rad, shared, noise : float
        Correlation length [rad], shared and noise variance [mm^2].

    Returns
    -------
    mean : ndarray, shape (M, c)
        Of the error along each direction asked about [mm].
    variance : ndarray, shape (M, c)
        Of the shared error along it, without the noise [mm^2].
    """
    among, to_query = distances
    mean, variance = np.empty(facing.shape[::2]), np.empty(facing.shape[::2])

    def block(s: int, e: int) -> None:
        def shared_covariance(out: np.ndarray) -> None:  # built where it is factorised: no (M, k, k) kept
            kernel(among[s:e], length_rad, out)
            out *= dots[s:e]
            out *= shared

        cross = kernel(to_query[s:e], length_rad)[:, :, None] * facing[s:e]
        y = whitened(shared_covariance, noise, np.concatenate([values[s:e, :, None], shared * cross], axis=2))
        mean[s:e] = np.einsum("mkc,mk->mc", y[:, :, 1:], y[:, :, 0])
        variance[s:e] = shared - np.einsum("mkc,mkc->mc", y[:, :, 1:], y[:, :, 1:])

    each_block(len(mean), halved(len(mean), POSTERIOR_ROWS), block)
    return mean, np.maximum(variance, 0.0)


def rms3(error: np.ndarray) -> float:
    """3-D RMS [mm] of error vectors (N, 3); of observations (N, 1), three components of their mean
    square."""
    return float(np.sqrt(3.0 * np.mean(error**2)))


class Folds:
    """The rows (at most ``CV_ROWS``, evenly spaced) predicted from the rows of the other ``FOLDS``
    interleaved folds (row ``i`` in fold ``i mod FOLDS``), their neighbours found once.

    Parameters
    ----------
    q : ndarray, shape (N, 6)
        The rows' joint readings [rad].
    error_mm : ndarray, shape (N, 3)
        Their residuals [mm].
    """

    def __init__(self, q: np.ndarray, error_mm: np.ndarray):
        n = q.shape[0]
        fold = np.arange(n) % FOLDS
        self.rows = np.unique(np.linspace(0, n - 1, min(n, CV_ROWS)).astype(int))
        points = embedding(q)
        index = neighbours(points[self.rows], points, NEIGHBOURS, fold, fold[self.rows])
        self.distances, self.values = local_distances(points[self.rows], points, index), error_mm[index]
        self.error = error_mm[self.rows]
        self.row = np.arange(self.rows.size)
        """The held-out row of each of ``error``'s entries."""
        self.total = float(np.mean(error_mm**2))
        """The rows' mean square per component [mm^2]."""

    def predict(self, length_deg: float, share: float) -> tuple[np.ndarray, np.ndarray]:
        """Posterior mean (M, 3) [mm] and variance (M,) [mm^2] of the rows, with the shared error
        ``share`` of the rows' mean square at the correlation length ``length_deg`` [deg]."""
        shared, noise = share * self.total, (1.0 - share) * self.total
        return local_posterior(self.distances, self.values, np.radians(length_deg), shared, noise)


class ObservedFolds:
    """``Folds`` of observations (``calib.map_rows.Observations``): the observations of at most
    ``CV_ROWS`` rows (evenly spaced) predicted from the observations of the other folds' rows, each
    row's at once (its observations' directions asked about together, padded to the most a row has).

    Parameters
    ----------
    rows : Observations
        The rows and what they observe.
    value_mm : ndarray, shape (K,)
        What is left to predict of each observation [mm].
    """

    def __init__(self, rows, value_mm: np.ndarray):
        n = rows.q.shape[0]
        picked = np.unique(np.linspace(0, n - 1, min(n, CV_ROWS)).astype(int))
        asked = np.flatnonzero(np.isin(rows.row, picked))
        at, slot = row_slots(np.searchsorted(picked, rows.row[asked]), picked.size)
        asked_directions = np.zeros((picked.size, slot.max() + 1, 3))
        asked_directions[at, slot] = rows.direction[asked]
        self.held = (at, slot)
        points = embedding(rows.q[rows.row])
        queries = embedding(rows.q[picked])
        index = neighbours(queries, points, OBSERVED_NEIGHBOURS, rows.row % FOLDS, picked % FOLDS)
        self.distances = local_distances(queries, points, index)
        directions = rows.direction[index]
        self.dots = np.matmul(directions, directions.transpose(0, 2, 1))
        self.facing = np.einsum("mkc,msc->mks", directions, asked_directions)
        self.posteriors = {}
        self.values = value_mm[index]
        self.error = value_mm[asked, None]
        self.row = at
        """The held-out row of each of ``error``'s entries."""
        self.total = float(np.mean(value_mm**2))
        """The observations' mean square [mm^2]."""

    def predict(self, length_deg: float, share: float) -> tuple[np.ndarray, np.ndarray]:
        """``Folds.predict`` of the held-out observations: mean (M, 1) [mm], variance (M,) [mm^2]
        (kept per grid point: the search's best is asked for again)."""
        if (length_deg, share) in self.posteriors:
            return self.posteriors[length_deg, share]
        shared, noise = share * self.total, (1.0 - share) * self.total
        mean, variance = observed_posterior(
            self.distances, self.dots, self.facing, self.values, np.radians(length_deg), shared, noise
        )
        self.posteriors[length_deg, share] = mean[self.held][:, None], variance[self.held]
        return self.posteriors[length_deg, share]


def row_slots(at: np.ndarray, m: int) -> tuple[np.ndarray, np.ndarray]:
    """For observations of rows ``at`` (K,) (indices below ``m``): ``at`` and each one's place
    among its row's observations (K,), in their order."""
    counts = np.bincount(at, minlength=m)
    order = np.argsort(at, kind="stable")
    slot = np.empty(at.size, int)
    slot[order] = np.arange(at.size) - np.repeat(np.cumsum(counts) - counts, counts)
    return at, slot


def search(folds: Folds | ObservedFolds) -> dict[tuple[float, float], float]:
    """Cross-validated 3-D RMS error [mm] per (length [deg], shared fraction) the search visits:
    coordinate descent over the grid (the length at the middling share, the share at that length,
    the length again; 14 of its 28 points)."""
    scores = {}

    def score(length, share):
        if (length, share) not in scores:
            scores[length, share] = rms3(folds.error - folds.predict(length, share)[0])
        return scores[length, share]

    length = min(LENGTH_SCALES_DEG, key=lambda v: score(v, SHARED_FRACTIONS[2]))
    share = min(SHARED_FRACTIONS, key=lambda v: score(length, v))
    min(LENGTH_SCALES_DEG, key=lambda v: score(v, share))
    return scores


def variance_scale(folds: Folds | ObservedFolds, length_deg: float, share: float) -> float:
    """The factor on both variances that makes the folds' standardised errors (error minus mean,
    squared, over the posterior variance plus the noise, per component) average one: the kernel's
    amplitude as the held-out rows show it (it leaves the mean as it is)."""
    mean, variance = folds.predict(length_deg, share)
    return float(np.mean((folds.error - mean) ** 2 / (variance + (1.0 - share) * folds.total)[:, None]))


def best_kernel(folds: Folds | ObservedFolds) -> tuple[float, ...] | None:
    """The grid point of least cross-validated error: length [deg], shared and noise variance
    [mm^2] (scaled by ``variance_scale``), its fold error and the table's [mm]; None where it does
    not cut the table's fold error by ``MIN_GAIN`` and by a ``clear_gain``."""
    (length, share), best = min(search(folds).items(), key=lambda item: item[1])
    table = rms3(folds.error)
    mean = folds.predict(length, share)[0]
    gain = np.sum(folds.error**2 - (folds.error - mean) ** 2, axis=1)
    if best > (1.0 - MIN_GAIN) * table or not clear_gain(gain, folds.row):
        return None
    scale = variance_scale(folds, length, share) * folds.total
    return length, share * scale, (1 - share) * scale, best, table


def fit_shared(q: np.ndarray, error_mm: np.ndarray) -> SharedError | None:
    """The shared error of the rows ``q`` (N, 6) [rad] with residuals ``error_mm`` (N, 3) [mm,
    measured minus the table's TCP, base frame] (``best_kernel``); None where it does not cut the
    table's cross-validated error by ``MIN_GAIN`` (or too few rows to have neighbours in every
    fold)."""
    if q.shape[0] < 2 * FOLDS:
        return None
    found = best_kernel(Folds(q, error_mm))
    return None if found is None else SharedError(q, error_mm, *found)


def fit_observed_shared(rows, value_mm: np.ndarray) -> ObservedShared | None:
    """``fit_shared`` of observations: ``rows`` (``calib.map_rows.Observations``) with what is left
    of each observation ``value_mm`` (K,) [mm]."""
    if rows.q.shape[0] < 2 * FOLDS:
        return None
    found = best_kernel(ObservedFolds(rows, value_mm))
    return None if found is None else ObservedShared(rows.q[rows.row], rows.direction, value_mm, *found)
