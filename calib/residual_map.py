"""The residual map: the error a calibrated table leaves, predicted at any pose from the
calibration's own rows, with its uncertainty. Two stages, each used only where it cuts the error of
rows predicted from the other folds by ``MIN_GAIN`` and by more than those rows' scatter could by
chance (``calib.angle_errors.clear_gain``; a cell of table and white noise keeps the table;
``fit_map`` returns None):

1. **Joint angle errors** (``calib.angle_errors``): joints 1-3 turning by a smooth function of their
   own angle (a gear's cyclic error, many cycles a turn), seen through the Jacobian; learnt wherever
   a joint stood, whatever the others did.
2. **The shared error** of what they leave (``SharedError``): ``calib.discrepancy`` finds that a
   real arm's residual changes smoothly with the joints (poses a few degrees apart share it); here
   it is predicted by Gaussian-process regression of the rows' residual vectors (base frame, mm;
   each component independent, one kernel) over joints 1-3 (the chord distance ``2 sin(dq / 2)``
   per joint, as ``discrepancy``) with the squared-exponential kernel::

       cov(e(q), e(q')) = shared * exp(-d(q, q')^2 / (2 l^2)),   plus ``noise`` on each row,

   ``shared + noise`` the rows' mean square per component. Local: each pose from its
   ``NEIGHBOURS`` nearest rows (the chord distance of joints 1-3 is the Euclidean distance of their
   cosines and sines), so 12,000 rows cost one batch of small solves, not a 12,000 x 12,000 one.
   The length and the shared share are those of least error on ``FOLDS`` interleaved folds (row
   ``i`` in fold ``i mod FOLDS``: a pose predicted from poses measured around it, which is what the
   map is for), the variances scaled so the folds' standardised errors average one.

Near measured poses the prediction's variance tightens; far from them the mean falls back to zero
(the table alone) and the variance to the rows' own mean square.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from calib.angle_errors import (
    DESIGN_ROWS,
    AngleErrors,
    clear_gain,
    features,
    fit_angle_errors_in_blocks,
    joint_jacobian,
    observed_features,
)
from calib.blocks import each_block, halved
from calib.compliance import compliance_response
from calib.kinematics import N_DH, THETA, tcp_jacobian, tcp_position
from calib.map_rows import Observations

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
FOLDS = 5
"""Interleaved cross-validation folds."""
CV_ROWS = 2000
"""At most this many rows (evenly spaced) are predicted in the cross-validation."""
POSTERIOR_ROWS = 256
"""Queries per block of the posteriors' solves (``calib.blocks``: two threads)."""
MIN_GAIN = 0.05
"""Cut of the cross-validated RMS error against the table alone the map must bring to be used."""
TOOL = 3
"""The TCP's coordinates in the flange frame, after the table's N_DH unknowns in ``absorbed``."""
ABSORBED = N_DH + TOOL + 6
"""``ResidualMap.absorbed``'s rows: the table's unknowns, the TCP's, the base frame's turn and shift."""
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


@dataclass(frozen=True)
class ResidualMap:
    """What a calibrated table leaves, predicted at any pose: joints 1-3's angle errors
    (``calib.angle_errors``), then the error neighbouring poses share of what they leave
    (``SharedError``); either may be off (None).

    Attributes
    ----------
    dh : ndarray, shape (6, 4)
        The calibrated table (rad, mm), for the Jacobian at a pose.
    tool_mm : ndarray, shape (3,)
        The TCP in the flange frame [mm].
    angles : AngleErrors or None
    shared : SharedError or None
    cv_rmse_mm, table_cv_rmse_mm : float
        3-D RMS error [mm] of the rows predicted from the other folds, with the map (the last stage
        on) and with the table alone.
    absorbed : ndarray, shape (ABSORBED [+ 2], F), or None
        What the table (rad, mm) and the TCP in the flange [mm] took of the angle errors per
        coefficient, where they were fitted beside it (``calib.absorbed_angles``): added back, less
        the rigid move of the base frame (rad, mm) it makes of the calibration's rows (a frame the
        lines and the anchor fitted with the table alone stay in); then the compliances of joints 2
        and 3 fitted with them (``calib.compliance``, rad per m; a map stored without them has none).
    absorbed_offset : ndarray, shape like ``absorbed``'s rows, or None
        As ``absorbed``, the change at no angle error: least squares' table where the calibration's
        robust weights (rows the angle errors made large) or its weighing left it, added with the
        angle errors.
    """

    dh: np.ndarray
    tool_mm: np.ndarray
    angles: AngleErrors | None
    shared: SharedError | ObservedShared | None
    cv_rmse_mm: float
    table_cv_rmse_mm: float
    absorbed: np.ndarray | None = None
    absorbed_offset: np.ndarray | None = None

    @property
    def explained(self) -> float:
        """Share of the table's cross-validated mean square error the map takes out."""
        return 1.0 - (self.cv_rmse_mm / self.table_cv_rmse_mm) ** 2

    def predict(self, q: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """The predicted error (M, 3) [mm, base frame] at readings ``q`` (M, 6) [rad], and the
        variance per component (M,) [mm^2] of what is left there after it (the angle errors'
        posterior variance, plus the shared error's posterior and unshared variance, or without
        it what the angle errors leave on the folds)."""
        q = np.asarray(q, float)
        mean, variance = np.zeros((q.shape[0], 3)), np.zeros(q.shape[0])
        if self.angles is not None:
            a, offset = self.angle_features(q)
            mean, variance = self.angles.of_features(a, self.absorbed is not None)
            mean = mean + offset
        if self.shared is None:
            return mean, variance + (self.angles.rest_mm2 if self.angles is not None else 0.0)
        shared_mean, shared_variance = self.shared.predict(q)
        return mean + shared_mean, variance + shared_variance

    def angle_features(self, q: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """The TCP's response (M, 3, F) [mm/rad] to the angle errors' coefficients at readings ``q``
        (M, 6) [rad], with what the table took of them added back (``absorbed``), and the TCP's
        move (M, 3) [mm] of ``absorbed_offset`` (zero without it)."""
        if self.absorbed is None:
            return features(q, joint_jacobian(self.dh, q, self.tool_mm)), np.zeros((q.shape[0], 3))
        p, jac = tcp_jacobian(self.dh, q, self.tool_mm)
        joints = jac[:, :, [4 * j + THETA for j in range(MAP_JOINTS)]]
        response = table_response(self.dh, q, p, jac)
        if self.absorbed.shape[0] > ABSORBED:  # the compliances beside the table
            response = np.concatenate([response, compliance_response(self.dh, q, self.tool_mm, jac)], axis=2)
        offset = np.zeros(self.absorbed.shape[0]) if self.absorbed_offset is None else self.absorbed_offset
        return features(q, joints) + response @ self.absorbed, response @ offset


def table_response(dh: np.ndarray, q: np.ndarray, tcp_mm: np.ndarray, jacobian: np.ndarray) -> np.ndarray:
    """The TCP's move (M, 3, ABSORBED) [mm per rad or mm] per unit of the table's unknowns (their
    ``jacobian`` (M, 3, N_DH) at readings ``q`` (M, 6) [rad]), of the TCP's flange-frame
    coordinates (the flange's axes), and of a small turn [rad] and shift [mm] of the base frame
    (the TCP ``tcp_mm`` (M, 3) turned about the origin, moved)."""
    zero = tcp_position(dh, q, np.zeros(TOOL))
    flange = np.stack([tcp_position(dh, q, axis) - zero for axis in np.eye(TOOL)], axis=2)
    return np.concatenate([jacobian[:, :, :N_DH], flange, frame_response(tcp_mm)], axis=2)


def frame_response(tcp_mm: np.ndarray) -> np.ndarray:
    """The move (M, 3, 6) [mm per rad, mm per mm] of points ``tcp_mm`` (M, 3) per small turn of the
    frame about its axes (``omega x p``) and per shift along them."""
    turn = np.cross(np.eye(3)[None, :, :], tcp_mm[:, None, :]).transpose(0, 2, 1)
    return np.concatenate([turn, np.broadcast_to(np.eye(3), (len(tcp_mm), 3, 3))], axis=2)


def fit_map(q: np.ndarray, error_mm: np.ndarray, dh: np.ndarray, tool_mm: np.ndarray) -> ResidualMap | None:
    """The residual map of a position instrument's rows ``q`` (N, 6) [rad] with residuals
    ``error_mm`` (N, 3) [mm, measured minus the table's TCP, base frame] (``fit_rows_map``)."""
    return fit_rows_map(Observations.of_positions(q, error_mm), dh, tool_mm)


def fit_rows_map(rows: Observations, dh: np.ndarray, tool_mm: np.ndarray) -> ResidualMap | None:
    """The residual map of what ``rows`` observe (``calib.map_rows``) of the table ``dh`` (6, 4)
    (rad, mm) with the TCP ``tool_mm`` (3,) [mm]: the angle errors where they cut the folds' error
    by their ``MIN_GAIN``, then the shared error of what is left where it cuts that by
    ``MIN_GAIN``; None where neither does (or too few rows, or the rows fit exactly). A position
    instrument's rows take the shared error's three independent components (``SharedError``),
    other rows the observation operator (``ObservedShared``)."""
    if rows.q.shape[0] < 2 * FOLDS or not np.any(rows.value_mm):
        return None
    design = observation_design(rows, joint_jacobian(dh, rows.q, tool_mm))
    angles = fit_angle_errors_in_blocks(design, rows.value_mm, rows.row)
    left = rows.value_mm.copy()
    for at, a in design() if angles is not None else ():
        left[at] -= a @ angles.weights
    if rows.positions:
        shared = fit_shared(rows.q, left.reshape(-1, 3))
    else:
        shared = fit_observed_shared(rows, left)
    if angles is None and shared is None:
        return None
    table = rms3(rows.value_mm[:, None])
    best = shared.cv_rmse_mm if shared is not None else float(np.sqrt(3.0 * angles.rest_mm2))
    return ResidualMap(np.asarray(dh, float), np.asarray(tool_mm, float), angles, shared, best, table)


def observation_design(rows: Observations, jacobian: np.ndarray):
    """``design()``: the responses of ``rows``' observations to the angle errors' coefficients
    (``features`` of a position instrument's rows, ``observed_features`` of others') with the joint
    Jacobian (N, 3, 3) [mm/rad] of each row, yielded ``DESIGN_ROWS`` at a time as (slice of the
    observations, responses (k, F)) (``calib.angle_errors.Folds``)."""

    def design():
        if rows.positions:  # three observations a row, in order: the row's features
            step = DESIGN_ROWS // 3
            for s in range(0, rows.q.shape[0], step):
                a = features(rows.q[s : s + step], jacobian[s : s + step])
                yield slice(3 * s, 3 * (s + a.shape[0])), a.reshape(3 * a.shape[0], -1)
            return
        for s in range(0, rows.row.size, DESIGN_ROWS):
            at = slice(s, s + DESIGN_ROWS)
            yield at, observed_features(rows.q[rows.row[at]], jacobian[rows.row[at]], rows.direction[at])

    return design


def map_arrays(found: ResidualMap) -> dict[str, np.ndarray]:
    """The map as named arrays (what a file stores beside the corrected table): the table and TCP,
    the fold errors, the angle errors' kernel, coefficients and covariance, the shared error's
    kernel and its rows (joints 1-3 only, all its kernel reads, and their residuals)."""
    out = {
        "dh": found.dh,
        "tool_mm": found.tool_mm,
        "cv_rmse_mm": np.array([found.cv_rmse_mm, found.table_cv_rmse_mm]),
    }
    if found.angles is not None:
        a = found.angles
        out["angle_kernel"] = np.array([a.length_deg, a.sigma_deg, a.rest_mm2])
        out["angle_weights"], out["angle_covariance"] = a.weights, a.covariance
    if found.absorbed is not None:
        out["angle_absorbed"] = found.absorbed
    if found.absorbed_offset is not None:
        out["angle_absorbed_offset"] = found.absorbed_offset
    if found.shared is not None:
        s = found.shared
        out["shared_kernel"] = np.array(
            [s.length_scale_deg, s.shared_mm2, s.noise_mm2, s.cv_rmse_mm, s.table_cv_rmse_mm]
        )
        if isinstance(s, ObservedShared):
            out["observed_q"], out["observed_direction"] = s.q[:, :MAP_JOINTS], s.direction
            out["observed_value_mm"] = s.value_mm
        else:
            out["shared_q"], out["shared_error_mm"] = s.q[:, :MAP_JOINTS], s.error_mm
    return out


def map_from_arrays(arrays: dict[str, np.ndarray]) -> ResidualMap:
    """The map ``map_arrays`` wrote (the shared rows' wrist joints read as 0: the kernel ignores
    them)."""
    angles = shared = None
    if "angle_kernel" in arrays:
        length, sigma, rest = (float(v) for v in arrays["angle_kernel"])
        angles = AngleErrors(length, sigma, arrays["angle_weights"], arrays["angle_covariance"], rest)
    if "shared_kernel" in arrays:
        kernel = (float(v) for v in arrays["shared_kernel"])
        if "observed_q" in arrays:
            q = whole_readings(arrays["observed_q"])
            shared = ObservedShared(q, arrays["observed_direction"], arrays["observed_value_mm"], *kernel)
        else:
            shared = SharedError(whole_readings(arrays["shared_q"]), arrays["shared_error_mm"], *kernel)
    cv, table = (float(v) for v in arrays["cv_rmse_mm"])
    absorbed, offset = (arrays.get(key) for key in ("angle_absorbed", "angle_absorbed_offset"))
    return ResidualMap(arrays["dh"], arrays["tool_mm"], angles, shared, cv, table, absorbed, offset)


def whole_readings(q: np.ndarray) -> np.ndarray:
    """Readings (N, 6) [rad] of joints 1-3's ``q`` (N, 3), the wrist's read as 0 (the kernel ignores
    them)."""
    return np.hstack([q, np.zeros((q.shape[0], 6 - MAP_JOINTS))])


def left_share(found: ResidualMap, q: np.ndarray) -> np.ndarray:
    """Share (N,) of the error the table alone leaves that is left with the map at readings ``q``
    (N, 6) [rad]: the map's variance there over the table's mean square per component on the
    folds, at most 1 (near the rows the map learnt from: the instrument's noise and what neighbours
    do not share; far from them: 1, the table's)."""
    table_mm2 = found.table_cv_rmse_mm**2 / 3.0
    return np.minimum(found.predict(q)[1] / table_mm2, 1.0)


MAPPED_PASSES = 2
"""Newton steps of ``mapped_readings`` (the map changes by micrometres over the step)."""


def mapped_readings(found: ResidualMap, q: np.ndarray) -> np.ndarray:
    """Readings (N, 6) [rad] at which the table alone puts the TCP where the table plus the map's
    prediction put it at readings ``q`` (N, 6) [rad]: ``q`` moved by the least joint motion that
    carries the table's TCP by the prediction (the TCP's Jacobian by the six joints, its
    pseudo-inverse). What a measurement model of the table alone takes to judge table + map."""
    q = np.asarray(q, float)
    target = tcp_position(found.dh, q, found.tool_mm) + found.predict(q)[0]
    out = q.copy()
    for _ in range(MAPPED_PASSES):
        p, jac = tcp_jacobian(found.dh, out, found.tool_mm)
        joints = jac[:, :, [4 * j + THETA for j in range(6)]]
        out += np.einsum("njc,nc->nj", np.linalg.pinv(joints), target - p)
    return out
