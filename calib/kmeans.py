"""k-means clustering, label for label what ``scipy.cluster.vq.kmeans2(data, k, minit="++",
rng=rng)`` returns, in numpy alone: ``scipy.cluster`` pulls in ``scipy.spatial`` and
``scipy.special``, about 0.1 s of a ``station calibrate`` that needs k-means only for its
regions of joint space (``region_folds``: cross-validation's folds, the discrepancy's blocks).

The same arithmetic in the same order as scipy 1.17's ``_kpp``, ``_vq.vq`` and
``_vq.update_cluster_means``, so the same floating-point results and the same random draws: a
k-means++ start (one ``rng.integers`` for the first centre, one ``rng.uniform`` per further one,
drawn against the cumulated squared distances), then a fixed 10 Lloyd iterations (kmeans2 never
stops early), an empty cluster keeping its previous centre. From 5 features on scipy takes the
products of rows and centres from BLAS (``dgemm``); numpy's ``matmul`` gives the same bits for 2
or more centres with the wheels this project installs (numpy's OpenBLAS 0.3.31, scipy's 0.3.30;
``tests/unit/calib/test_kmeans.py`` compares the products, and labels that only this rounding
decides).
"""

from __future__ import annotations

import numpy as np

ITERATIONS = 10
"""Lloyd iterations: kmeans2's default ``iter``, all run."""
_BLAS_FEATURES = 5
"""From this many features on, scipy's ``vq`` computes the distances through BLAS."""


def kmeans_labels(data: np.ndarray, k: int, rng: np.random.Generator) -> np.ndarray:
    """The cluster (0..k-1) of each row of ``data`` (N, d) by k-means with a k-means++ start
    drawn from ``rng``; the labels of ``kmeans2(data, k, minit="++", rng=rng)``, and ``rng``
    advanced as far. A cluster may come out empty (no label names it)."""
    data = np.ascontiguousarray(data, dtype=float)
    centres = _kpp(data, k, rng)
    for _ in range(ITERATIONS):
        label = _nearest(data, centres)
        centres = _means(data, label, centres)
    return label


def _kpp(data: np.ndarray, k: int, rng: np.random.Generator) -> np.ndarray:
    """The k-means++ start: a random row, then each further centre a row drawn with probability
    proportional to its squared distance from the nearest centre so far."""
    centres = np.empty((k, data.shape[1]))
    for i in range(k):
        if i == 0:
            row = int(rng.integers(data.shape[0]))
        else:
            d2 = _sum_of_squares(centres[:i, None, :] - data[None, :, :]).min(axis=0)
            row = int(np.searchsorted((d2 / d2.sum()).cumsum(), rng.uniform()))
        centres[i] = data[row]
    return centres


def _nearest(data: np.ndarray, centres: np.ndarray) -> np.ndarray:
    """The index of each row's nearest centre (the first of equals)."""
    if data.shape[1] < _BLAS_FEATURES:
        d2 = _sum_of_squares(centres[None, :, :] - data[:, None, :])
    else:  # |x|^2 + |c|^2 - 2 x.c, the product through BLAS as scipy's
        cross = -2.0 * (data @ centres.T)
        d2 = (cross + _sum_of_squares(data)[:, None]) + _sum_of_squares(centres)[None, :]
    return np.argmin(d2, axis=1)


def _means(data: np.ndarray, label: np.ndarray, previous: np.ndarray) -> np.ndarray:
    """Each cluster's mean (rows summed in order); an empty cluster keeps its ``previous`` centre."""
    k = len(previous)
    count = np.bincount(label, minlength=k)
    sums = np.column_stack([np.bincount(label, weights=col, minlength=k) for col in data.T])
    return np.where(count[:, None] > 0, sums / np.maximum(count, 1)[:, None], previous)


def _sum_of_squares(v: np.ndarray) -> np.ndarray:
    """Sum of squares over the last axis, added feature by feature from zero (as scipy's loops)."""
    total = np.zeros(v.shape[:-1])
    for j in range(v.shape[-1]):
        total += v[..., j] * v[..., j]
    return total


REGION_JOINTS = 3
"""The joints whose angles define the regions of joint space (the arm's: where the wrist is)."""


def region_folds(q: np.ndarray, k: int) -> list[np.ndarray]:
    """Rows grouped into ``k`` regions of joint space (fewer if a cluster comes out empty).

    k-means (k-means++ start, fixed seed: the same rows give the same folds; ``calib.kmeans``,
    scipy's ``kmeans2`` label for label) on the cosine and sine of the first ``REGION_JOINTS``
    joint angles, each column scaled to unit variance.

    Parameters
    ----------
    q : ndarray, shape (N, 6)
        Joint readings [rad].
    k : int
        Number of regions.

    Returns
    -------
    list of ndarray of int
        Ascending row indices of each region; together every row exactly once (one region, all
        rows, where the poses of joints 1-3 are all alike).
    """
    angles = q[:, :REGION_JOINTS]
    f = np.column_stack([np.cos(angles), np.sin(angles)])
    f = (f - f.mean(axis=0)) / np.maximum(f.std(axis=0), 1e-9)
    k = min(k, len(np.unique(f.round(9), axis=0)))  # no more regions than distinct poses
    if k < 2:
        return [np.arange(len(q))]
    label = kmeans_labels(f, k, np.random.default_rng(0))
    return [np.flatnonzero(label == c) for c in range(k) if np.any(label == c)]
