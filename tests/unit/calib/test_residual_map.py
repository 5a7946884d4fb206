"""The residual map (``calib.residual_map``) against a simulated truth: a UR10 whose joints 2 and 3
have a cyclic error of 17 cycles a turn and whose TCP sags with its reach (``sim_fixtures.
unmodelled``), calibrated from a tracker; near the poses measured the map takes the error the table
leaves down toward the tracker's noise and bounds it; far from them it falls back to the table; a
cell of table and white noise keeps it off. The local solve is the dense Gaussian process's."""

import numpy as np
import pytest

import calib.residual_map as residual_map
import configs
from calib.calibrate import CalibrationOptions, calibrate
from calib.discrepancy import joint_kernel
from calib.position import PositionModel, PositionSamples
from calib.residual_map import fit_map, rms3
from sim_fixtures.unmodelled import UR10_LIKE, TrackerCell, Unmodelled
from sim_fixtures.world import Robot

NOMINAL = Robot.from_file(configs.path("robots/ur10.toml")).dh
CHI2_3_95 = 7.8147  # 95 % quantile of chi-square, 3 degrees of freedom
SIGMA_MM = 0.02  # the tracker's noise per axis
NOISE_3D_MM = np.sqrt(3) * SIGMA_MM  # its 3-D RMS


def work_region(rng: np.random.Generator, n: int) -> np.ndarray:
    """``n`` poses [rad] where a program works: joints 1-3 within 40, 30 and 40 deg (a few degrees
    apart), the wrist anywhere."""
    q = rng.uniform(-180, 180, (n, 6))
    q[:, 0], q[:, 1], q[:, 2] = rng.uniform(-20, 20, n), rng.uniform(-120, -90, n), rng.uniform(40, 80, n)
    return np.radians(q)


def calibrated(cell: TrackerCell, q: np.ndarray, rng: np.random.Generator, options=None):
    """The calibration (default: the default) of the cell's tracker readings at ``q``: the model,
    its solution and the rows' residuals (N, 3) [mm, base frame]."""
    model = PositionModel(PositionSamples(q, cell.measure(q, rng)), NOMINAL, cell.probe_mm, sigma_mm=SIGMA_MM)
    x = calibrate(model, options or CalibrationOptions()).x
    rot, _ = model.tracker_from_base(x)
    return model, x, (model.samples.position - model.predicted_mm(x)) @ rot


def true_error(cell: TrackerCell, model: PositionModel, x: np.ndarray, q: np.ndarray) -> np.ndarray:
    """Where the probe truly is minus where the calibrated table puts it (N, 3) [mm, base frame]."""
    at = model.with_samples(PositionSamples(q, cell.true_point_mm(q)))
    rot, _ = at.tracker_from_base(x)
    return (at.samples.position - at.predicted_mm(x)) @ rot


@pytest.fixture(scope="module", params=[0, 1])
def mapped(request):
    """A cell with ``UR10_LIKE`` error: 150 poses over the whole workspace and 500 in the work
    region, calibrated; its map; 300 poses within about a degree of the region's measured ones."""
    rng = np.random.default_rng(request.param)
    cell = TrackerCell.create(NOMINAL, UR10_LIKE, seed=request.param, sigma_mm=SIGMA_MM)
    q = np.vstack([np.radians(rng.uniform(-180, 180, (150, 6))), work_region(rng, 500)])
    model, x, residuals = calibrated(cell, q, rng)
    near = q[150 + rng.integers(0, 500, 300)]
    near[:, :3] += np.radians(rng.normal(0, 1.0, (300, 3)))
    near[:, 3:] = np.radians(rng.uniform(-180, 180, (300, 3)))
    return cell, model, x, fit_map(q, residuals), near


def test_near_measured_poses_the_map_takes_the_error_toward_the_tracker_noise(mapped):
    """The table leaves ~0.2 mm that no table expresses; the map's prediction leaves at most twice
    the tracker's 3-D noise (the issue's goal: what neighbours do not share, through the wrist's
    lever, stays)."""
    cell, model, x, found, near = mapped
    error = true_error(cell, model, x, near)
    assert found is not None
    assert rms3(error) > 4 * NOISE_3D_MM  # the unmodelled error is there, well above the noise
    mean, _ = found.predict(near)
    assert rms3(error - mean) <= 2 * NOISE_3D_MM, (rms3(error), rms3(error - mean))


def test_the_true_error_lies_inside_the_maps_95_percent_bound(mapped):
    """At >= 95 % of the poses near the measured ones, the truth minus the map's prediction lies
    inside the 95 % bound of its variance (chi-square, three components)."""
    cell, model, x, found, near = mapped
    mean, variance = found.predict(near)
    left2 = np.sum((true_error(cell, model, x, near) - mean) ** 2, axis=1)
    assert np.mean(left2 <= CHI2_3_95 * variance) >= 0.95


def test_far_from_measured_poses_the_map_falls_back_to_the_table(mapped):
    """Poses at least 8 correlation lengths from every measured one: no prediction, and the table's
    own mean square (shared plus unshared) as the variance."""
    _, model, _, found, _ = mapped
    candidates = np.radians(np.random.default_rng(6).uniform(-180, 180, (2000, 6)))
    d2 = residual_map.distance2(residual_map.embedding(candidates), residual_map.embedding(model.samples.q))
    far = candidates[np.min(d2, axis=1) > (8 * np.radians(found.length_scale_deg)) ** 2]
    assert len(far) >= 20
    mean, variance = found.predict(far)
    np.testing.assert_allclose(mean, 0.0, atol=1e-9)
    np.testing.assert_allclose(variance, found.shared_mm2 + found.noise_mm2, rtol=1e-9)


def test_cells_of_table_and_white_noise_keep_the_map_off():
    """20 seeds of a cell without unmodelled error (poses as above, fewer): the map stays off in at
    least 19. The white fit's residuals: such a cell keeps its white fit under the default
    (``test_discrepancy``), which is the same fit at a tenth of the cost."""
    on = 0
    for seed in range(20):
        rng = np.random.default_rng(100 + seed)
        cell = TrackerCell.create(NOMINAL, Unmodelled(), seed=100 + seed, sigma_mm=SIGMA_MM)
        q = np.vstack([np.radians(rng.uniform(-180, 180, (100, 6))), work_region(rng, 400)])
        _, _, residuals = calibrated(cell, q, rng, CalibrationOptions(correlated=False))
        on += fit_map(q, residuals) is not None
    assert on <= 1


def test_the_local_solve_is_the_dense_gaussian_process_with_the_discrepancys_kernel():
    """With every row a neighbour, the posterior is the textbook one under ``joint_kernel``."""
    rng = np.random.default_rng(3)
    q, queries = rng.uniform(-0.3, 0.3, (30, 6)), rng.uniform(-0.3, 0.3, (7, 6))
    values = rng.normal(0, 0.1, (30, 3))
    length, shared, noise = 0.1, 0.02, 0.003
    points, at = residual_map.embedding(q), residual_map.embedding(queries)
    index = residual_map.neighbours(at, points, 30)
    distances = residual_map.local_distances(at, points, index)
    mean, variance = residual_map.local_posterior(distances, values[index], length, shared, noise)
    both = joint_kernel(np.vstack([queries, q]), length)
    cov, cross = shared * both[7:, 7:] + noise * np.eye(30), shared * both[:7, 7:]
    np.testing.assert_allclose(mean, cross @ np.linalg.solve(cov, values), atol=1e-10)
    np.testing.assert_allclose(
        variance, shared - np.sum(cross * np.linalg.solve(cov, cross.T).T, axis=1), atol=1e-10
    )


def test_the_neighbours_are_the_nearest_rows_of_the_other_folds():
    rng = np.random.default_rng(4)
    points, fold = rng.normal(size=(200, 6)), np.arange(200) % 5
    index = residual_map.neighbours(points[:50], points, 12, fold, fold[:50])
    for i in range(50):
        d2 = np.sum((points - points[i]) ** 2, axis=1)
        d2[fold == fold[i]] = np.inf
        assert set(index[i]) == set(np.argsort(d2)[:12])


def test_too_few_rows_give_no_map():
    rng = np.random.default_rng(5)
    assert fit_map(rng.normal(size=(2 * residual_map.FOLDS - 1, 6)), rng.normal(size=(9, 3))) is None
