"""calib.kmeans gives scipy's kmeans2 labels exactly (the blocked folds, and every figure computed
on them, rest on those labels), while a calibration no longer imports scipy.cluster."""

import subprocess
import sys
import warnings

import numpy as np
import pytest
from scipy.cluster.vq import kmeans2

from calib.kmeans import kmeans_labels, region_folds
from calib.selection import FOLDS


def scipy_labels(data, k, seed):
    """kmeans2's labels and the generator after it; whether it warned of an empty cluster."""
    rng = np.random.default_rng(seed)
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        _, label = kmeans2(data, k, minit="++", rng=rng)
    return label, rng, any("empty" in str(w.message) for w in caught)


def ours(data, k, seed):
    rng = np.random.default_rng(seed)
    return kmeans_labels(data, k, rng), rng


@pytest.mark.parametrize("seed", range(12))
@pytest.mark.parametrize("features", [2, 6])  # scipy: plain loops below 5 features, BLAS from 5 on
def test_labels_and_draws_are_scipys(seed, features):
    g = np.random.default_rng(seed)
    n, k = int(g.integers(20, 300)), int(g.integers(2, 8))
    centres = g.normal(size=(k + 1, features)) * 3
    data = centres[g.integers(k + 1, size=n)] + g.normal(size=(n, features))
    if seed % 3 == 0:
        data = np.round(data, 1)  # ties between distances
    want, want_rng, _ = scipy_labels(data, k, seed + 100)
    got, got_rng = ours(data, k, seed + 100)
    np.testing.assert_array_equal(got, want)
    assert got_rng.uniform() == want_rng.uniform()  # the same number of draws


def test_an_emptied_cluster_and_rounding_ties_as_scipys():
    # seven points on a line, the 3-means++ start drawn by seed 67877: with 6 features (scipy's
    # |x|^2 + |c|^2 - 2 x.c through BLAS) a point's two distances round alike and a cluster empties
    # (it keeps its centre); with 2 (plain loops) none does: both followed to the last bit
    line = np.array([0.32, 0.51, 0.02, 0.27, -0.0, -0.05, 0.04])
    for features, emptied in ((6, True), (2, False)):
        data = np.column_stack([line, np.zeros((7, features - 1))])
        want, _, warned = scipy_labels(data, 3, 67877)
        assert warned is emptied and len(np.unique(want)) == (2 if emptied else 3)
        np.testing.assert_array_equal(ours(data, 3, 67877)[0], want)


def test_the_products_are_scipys_blas_products():
    # scipy's vq: -2 x.c by dgemm (from 5 features on); ours by numpy's matmul: the same bits
    from scipy.linalg.blas import dgemm

    g = np.random.default_rng(0)
    for _ in range(300):
        n, features, k = int(g.integers(2, 2000)), int(g.integers(5, 10)), int(g.integers(2, 9))
        data, centres = g.normal(size=(n, features)) * g.exponential(), g.normal(size=(k, features))
        np.testing.assert_array_equal(-2.0 * (data @ centres.T), dgemm(-2.0, centres.T, data.T, trans_a=1).T)


def test_region_folds_of_a_session_are_kmeans2s():
    rng = np.random.default_rng(5)
    q = np.concatenate([rng.normal(c, 0.05, size=(70, 6)) for c in (-1.0, 0.0, 0.8)])
    angles = q[:, :3]
    f = np.column_stack([np.cos(angles), np.sin(angles)])
    f = (f - f.mean(axis=0)) / f.std(axis=0)
    _, label = kmeans2(f, 5, minit="++", rng=np.random.default_rng(0))
    want = [np.flatnonzero(label == c) for c in range(5) if np.any(label == c)]
    got = region_folds(q, FOLDS)
    assert len(got) == len(want) and all(np.array_equal(a, b) for a, b in zip(got, want, strict=True))


def test_the_selection_imports_no_scipy_cluster():
    code = "import sys, calib.selection; print('scipy.cluster' in sys.modules)"
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert out.stdout.strip() == "False"
