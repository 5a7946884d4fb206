"""The model's discrepancy (``calib.discrepancy``) against a simulated truth: a joint-space error
drawn from the covariance the module assumes is found at its correlation length and the fit
weighted by it (what that gains on real data: ``benchmarks/IPA_UR10.md``); a world of table and
white noise alone keeps its white fit; the whitening is the covariance's, block by block."""

import numpy as np
import pytest

import calib.discrepancy as discrepancy
import configs
from calib.calibrate import CalibrationOptions, calibrate
from calib.discrepancy import Blocks, Discrepancy, joint_kernel
from calib.drawstring import DrawstringFrame, DrawstringLineModel, DrawstringSamples, DrawstringSetup
from calib.kinematics import tcp_position
from calib.position import PositionModel, PositionSamples, rotation_from_vector
from sim_fixtures.world import Robot
from tests.unit.calib.test_terms_recovery import TRACKER_SIGMA_MM, position_set

NOMINAL = Robot.from_file(configs.path("robots/ur10.toml")).dh
PROBE = np.array([0.0, 0.0, 100.0])


def poses_in_one_region(rng: np.random.Generator, n: int) -> np.ndarray:
    """``n`` poses [rad] of one elbow configuration and a narrow band of joint 2 (the IPA dataset's
    series C), dense enough that neighbours lie a few degrees apart."""
    q = rng.uniform(-180, 180, (n, 6))
    q[:, 0], q[:, 1], q[:, 2] = rng.uniform(-60, 60, n), rng.uniform(-150, -90, n), rng.uniform(0, 130, n)
    return np.radians(q)


def correlated_world(length_scale_deg: float, seed: int, n: int = 500) -> tuple[PositionSamples, np.ndarray]:
    """A UR10 with machining errors seen by a tracker (0.02 mm per axis), plus a joint-space error
    of 0.1 mm per axis drawn from ``joint_kernel`` at ``length_scale_deg``: the samples and that
    error (n, 3) [mm]."""
    rng = np.random.default_rng(seed)
    true = NOMINAL + np.column_stack(
        [np.radians(rng.normal(0, 0.15, 6)), rng.normal(0, 0.75, (6, 2)), np.radians(rng.normal(0, 0.15, 6))]
    )
    q = poses_in_one_region(rng, n)
    corr = joint_kernel(q, np.radians(length_scale_deg)) + 1e-9 * np.eye(n)
    error = np.linalg.cholesky(corr) @ rng.normal(0, 0.1, (n, 3))
    rot = rotation_from_vector(np.array([0.1, -0.2, 2.5]))
    p = tcp_position(true, q, PROBE) @ rot.T + [2500.0, -1000.0, 200.0] + error
    return PositionSamples(q, p + rng.normal(0, TRACKER_SIGMA_MM, p.shape)), error


@pytest.mark.parametrize("length_scale_deg", [5.0, 10.0])
def test_a_joint_space_error_is_found_at_its_correlation_length(length_scale_deg):
    samples, _ = correlated_world(length_scale_deg, seed=1)
    model = PositionModel(samples, NOMINAL, PROBE, sigma_mm=TRACKER_SIGMA_MM)
    white = calibrate(model, CalibrationOptions(correlated=False))
    weighted = calibrate(model, CalibrationOptions())
    assert weighted.discrepancy is not None and weighted.discrepancy.length_scale_deg == length_scale_deg
    assert weighted.discrepancy.loglik_gain > discrepancy.MIN_GAIN
    assert not np.allclose(weighted.x, white.x)
    np.testing.assert_array_equal(weighted.scale, white.scale)  # the rows' spread is the white fit's


@pytest.mark.parametrize("seed", [3, 4, 5])
def test_a_world_of_table_and_white_noise_keeps_its_white_fit(seed):
    _, samples = position_set(150, None, seed=seed)
    model = PositionModel(samples, NOMINAL, PROBE, sigma_mm=TRACKER_SIGMA_MM)
    cal = calibrate(model, CalibrationOptions())
    assert cal.discrepancy is None
    np.testing.assert_array_equal(cal.x, calibrate(model, CalibrationOptions(correlated=False)).x)


def elements(n: int, components: int, priors: int):
    """Residual rows and groups of ``n`` sample rows of ``components`` each, then ``priors`` prior
    rows (row -1, group 9)."""
    rows = np.concatenate([np.repeat(np.arange(n), components), np.full(priors, -1)])
    groups = np.concatenate([np.zeros(n * components, int), np.full(priors, 9)])
    return rows, groups


def test_whitening_is_the_inverse_of_noise_plus_discrepancy():
    rng = np.random.default_rng(0)
    n, priors = 40, 5
    q = rng.uniform(-np.pi, np.pi, (n, 6))
    rows, groups = elements(n, 3, priors)
    weights = rng.uniform(0.5, 1.0, rows.size)
    r, jac = rng.normal(size=rows.size), rng.normal(size=(rows.size, 4))
    blocks = Blocks(rows, groups, (0,), q, weights)
    found = Discrepancy(10.0, 3.0, 0.0)
    factors = blocks.factors(found)
    rw, jw = blocks.whiten(factors, weights, r, jac)
    row_weight = weights[: 3 * n].reshape(n, 3).min(axis=1)
    cov = np.diag(1.0 / row_weight**2) + 3.0 * joint_kernel(q, np.radians(10.0))
    inv = np.linalg.inv(cov)
    for c in range(3):
        part = np.arange(c, 3 * n, 3)
        assert rw[part] @ rw[part] == pytest.approx(r[part] @ inv @ r[part], rel=1e-9)
        np.testing.assert_allclose(jw[part].T @ jw[part], jac[part].T @ inv @ jac[part], rtol=1e-9)
    np.testing.assert_array_equal(rw[3 * n :], weights[3 * n :] * r[3 * n :])
    assert blocks.log_det(factors) == pytest.approx(3 * np.linalg.slogdet(cov)[1], rel=1e-9)


def test_many_rows_are_split_into_regions_each_row_once(monkeypatch):
    monkeypatch.setattr(discrepancy, "BLOCK_ROWS", 50)
    rng = np.random.default_rng(1)
    q = rng.uniform(-np.pi, np.pi, (180, 6))
    rows, groups = elements(180, 3, 0)
    blocks = Blocks(rows, groups, (0,), q, np.ones(rows.size))
    assert len(blocks.tables) == 4
    everything = np.sort(np.concatenate([t.ravel() for t in blocks.tables]))
    np.testing.assert_array_equal(everything, np.arange(rows.size))
    assert all(np.all(rows[t] == rows[t][:, :1]) for t in blocks.tables)  # a row's components together


def test_a_wild_reading_among_poses_sharing_an_error_stays_out_of_the_weighted_fit():
    """The weighted fit keeps the white fit's robust weights: a reading 50 mm off (a tracker that
    lost its target for one row) is named as down-weighted, leaves the discrepancy the clean rows
    show as it is, and moves the weighted fit no more than it moves the white one."""
    clean, _ = correlated_world(5.0, seed=2)
    position = clean.position.copy()
    position[17] += [50.0, 0.0, 0.0]
    model = PositionModel(clean, NOMINAL, PROBE, sigma_mm=TRACKER_SIGMA_MM)

    def shift(correlated: bool) -> tuple[float, list]:
        fits = [
            calibrate(
                PositionModel(s, NOMINAL, PROBE, sigma_mm=TRACKER_SIGMA_MM),
                CalibrationOptions(correlated=correlated),
            )
            for s in (clean, PositionSamples(clean.q, position))
        ]
        assert 17 in fits[1].downweighted
        moved = np.linalg.norm(model.predicted_mm(fits[1].x) - model.predicted_mm(fits[0].x), axis=1)
        return float(np.sqrt(np.mean(moved**2))), [f.discrepancy for f in fits]

    white, _ = shift(False)
    weighted, (found_clean, found_wild) = shift(True)
    assert found_clean is not None and found_wild is not None
    assert (found_wild.length_scale_deg, found_wild.ratio) == (
        found_clean.length_scale_deg,
        found_clean.ratio,
    )
    assert weighted <= 1.1 * white


@pytest.mark.parametrize("seed", [1, 2])
def test_the_error_poses_share_is_told_in_mm_at_the_tcp_from_a_tracker_and_from_a_drawstring(seed):
    """What the prediction adds (``tcp_rms_mm``) against the truth, the drawn error's RMS at the TCP
    (0.17-0.18 mm): a tracker sees its three components, a drawstring without gauge lines one, scaled
    to three. Within 20 %: adjacent ratios on the grid change the share ``ratio / (1 + ratio)`` by up
    to 17 %, and the fit takes a few per cent of the residual with it."""
    samples, error = correlated_world(5.0, seed=seed)
    truth = np.sqrt(np.mean(np.sum(error**2, axis=1)))
    tracker = calibrate(
        PositionModel(samples, NOMINAL, PROBE, sigma_mm=TRACKER_SIGMA_MM), CalibrationOptions()
    )
    rot, shift = PositionModel(samples, NOMINAL, PROBE).tracker_from_base(tracker.x)
    anchor = samples.position.mean(axis=0) + [500.0, 300.0, -1200.0]  # below the workspace
    length = np.linalg.norm(samples.position - anchor, axis=1)
    setup = DrawstringSetup(anchor=rot.T @ (anchor - shift) + 5.0, length_offset=3.0)
    rows = DrawstringSamples(samples.q, length, np.full(len(length), np.nan), np.full(len(length), -1))
    frame = DrawstringFrame.from_nominal(rows, setup, NOMINAL, PROBE)
    drawstring = calibrate(DrawstringLineModel(rows, setup, frame, NOMINAL, PROBE), CalibrationOptions())
    for cal in (tracker, drawstring):
        assert cal.discrepancy is not None
        assert abs(cal.discrepancy.tcp_rms_mm - truth) < 0.2 * truth, (cal.discrepancy, truth)
