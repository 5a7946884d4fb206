"""The shared error's local Gaussian process (``calib.shared_error``): with every row a neighbour
it is the dense textbook posterior under ``calib.discrepancy.joint_kernel``, also where poses are
read again and again; the neighbours are the nearest rows of the other folds, by the scan and by
the k-d tree alike."""

import numpy as np
import pytest

import calib.shared_error as shared_error
from calib.discrepancy import joint_kernel


def test_the_local_solve_is_the_dense_gaussian_process_with_the_discrepancys_kernel():
    """With every row a neighbour, the posterior is the textbook one under ``joint_kernel``."""
    rng = np.random.default_rng(3)
    q, queries = rng.uniform(-0.3, 0.3, (30, 6)), rng.uniform(-0.3, 0.3, (7, 6))
    values = rng.normal(0, 0.1, (30, 3))
    local, textbook = local_and_textbook(q, queries, values, 0.1, 0.02, 0.003)
    np.testing.assert_allclose(local[0], textbook[0], atol=1e-10)
    np.testing.assert_allclose(local[1], textbook[1], atol=1e-10)


def local_and_textbook(q, queries, values, length, shared, noise):
    """``local_posterior`` at ``queries`` (M, 6) with every one of the rows ``q`` (N, 6) a
    neighbour, and the dense textbook posterior under ``joint_kernel``: (mean, variance) each."""
    m, n = len(queries), len(q)
    points, at = shared_error.embedding(q), shared_error.embedding(queries)
    index = shared_error.neighbours(at, points, n)
    distances = shared_error.local_distances(at, points, index)
    local = shared_error.local_posterior(distances, values[index], length, shared, noise)
    both = joint_kernel(np.vstack([queries, q]), length)
    cov, cross = shared * both[m:, m:] + noise * np.eye(n), shared * both[:m, m:]
    variance = shared - np.sum(cross * np.linalg.solve(cov, cross.T).T, axis=1)
    return local, (cross @ np.linalg.solve(cov, values), variance)


def test_poses_read_again_and_again_leave_the_local_solve_the_textbook_one():
    """A session reads each pose several times (five captures at one target): the neighbours'
    kernel is singular, only a small noise keeps the covariance positive definite, and the bordered
    Cholesky (``whitened``) must still give the dense posterior."""
    rng = np.random.default_rng(5)
    q = np.repeat(rng.uniform(-0.3, 0.3, (6, 6)), 5, axis=0)  # 30 rows, 6 distinct poses
    queries = rng.uniform(-0.3, 0.3, (7, 6))
    values = rng.normal(0, 0.1, (30, 3))
    local, textbook = local_and_textbook(q, queries, values, 0.5, 0.02, 1e-7)
    np.testing.assert_allclose(local[0], textbook[0], rtol=1e-6, atol=1e-9)
    np.testing.assert_allclose(local[1], textbook[1], atol=1e-9)


def test_the_neighbours_are_the_nearest_rows_of_the_other_folds():
    rng = np.random.default_rng(4)
    points, fold = rng.normal(size=(200, 6)), np.arange(200) % 5
    index = shared_error.neighbours(points[:50], points, 12, fold, fold[:50])
    for i in range(50):
        d2 = np.sum((points - points[i]) ** 2, axis=1)
        d2[fold == fold[i]] = np.inf
        assert set(index[i]) == set(np.argsort(d2)[:12])


@pytest.mark.parametrize("folded", [False, True])
def test_the_k_d_tree_finds_the_neighbours_the_scan_finds(folded, monkeypatch):
    """Above ``SCAN_PAIRS`` the search takes a k-d tree (100,000 rows: 40 s and 10 GB by the scan);
    the same neighbours (distinct distances here), with and without folds."""
    rng = np.random.default_rng(6)
    points, fold = shared_error.embedding(rng.uniform(-3, 3, (3000, 6))), np.arange(3000) % 5
    queries = points[::7]
    folds = (fold, fold[::7]) if folded else ()
    scan = shared_error.neighbours(queries, points, 40, *folds)
    monkeypatch.setattr(shared_error, "SCAN_PAIRS", 0)
    tree = shared_error.neighbours(queries, points, 40, *folds)
    assert tree.shape == scan.shape == (queries.shape[0], 40)
    assert all(set(a) == set(b) for a, b in zip(tree, scan, strict=True))
    if folded:
        assert np.all(fold[tree] != fold[::7, None])
