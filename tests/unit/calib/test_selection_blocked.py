"""``--model auto``'s rule against a simulated truth: blocked folds are regions of joint space; the
compliances, a prior group, are kept where the joints yield, left with the reason where the data
cannot determine them or their value is not a joint's; a harmonic must be determined and earn its
gain; the nominal table's error on the same folds is there to compare."""

import numpy as np
import pytest

import configs
from calib.calibrate import CalibrationOptions
from calib.joint_terms import JointTerms, Term, compliance_group, harmonic_group
from calib.kmeans import region_folds
from calib.position import PositionModel
from calib.selection import FOLDS, blocked_folds, implausible, not_harmful, select_terms
from sim_fixtures.world import JointError, Robot
from tests.unit.calib.test_terms_recovery import TRACKER_SIGMA_MM, UR10_LINKS, position_set

NOMINAL = Robot.from_file(configs.path("robots/ur10.toml")).dh


def selection_of(compliance: dict[int, float], seed: int = 5, n: int = 150):
    """``select_terms`` as ``--model auto`` runs it on a UR10 tracker set whose joints ``compliance``
    (0-based joint: urad / (N m)) yield under gravity."""
    terms = JointTerms([Term(j, "compliance_urad_per_Nm") for j in compliance], NOMINAL, UR10_LINKS)
    error = JointError(terms, np.array(list(compliance.values()))) if compliance else None
    _, samples = position_set(n, error, seed=seed)
    model = PositionModel(samples, NOMINAL, np.array([0.0, 0.0, 100.0]), sigma_mm=TRACKER_SIGMA_MM)
    folds, scheme = blocked_folds(samples.q)
    prior = ([compliance_group(1), compliance_group(2)],)
    harmonics = [harmonic_group(j, h) for j in range(6) for h in (1, 2)]
    pool = JointTerms((), NOMINAL, UR10_LINKS)
    options = CalibrationOptions()
    return select_terms(model, harmonics, pool, options, folds=folds, prior=prior, scheme=scheme), model


def test_regions_partition_the_rows_and_lie_apart_in_joint_space():
    q = np.radians(np.random.default_rng(0).uniform(-180, 180, (300, 6)))
    folds = region_folds(q, FOLDS)
    assert len(folds) == 5
    np.testing.assert_array_equal(np.sort(np.concatenate(folds)), np.arange(300))
    assert all(
        np.array_equal(a, b) for a, b in zip(folds, region_folds(q, FOLDS), strict=True)
    )  # same rows, same folds
    # a left-out region lies farther from the rows it is predicted from than an interleaved fold does
    f = np.column_stack([np.cos(q[:, :3]), np.sin(q[:, :3])])

    def gap(rows):
        rest = np.setdiff1d(np.arange(300), rows)
        return np.mean(np.min(np.linalg.norm(f[rows, None] - f[None, rest], axis=2), axis=1))

    interleaved = np.mean([gap(np.arange(k, 300, 5)) for k in range(5)])
    assert np.mean([gap(rows) for rows in folds]) > interleaved


@pytest.mark.parametrize("seed", [5, 6])
def test_the_compliances_are_kept_where_the_joints_yield(seed):
    selection, model = selection_of({1: 15.0, 2: 10.0}, seed)
    assert [g.label for g in selection.groups] == ["J2 compliance", "J3 compliance"]
    kept = [s for s in selection.table if s.kept]
    assert kept[1].label == "J2 compliance + J3 compliance" and kept[1].gain > 0
    cal = selection.calibration
    for name, truth in (("J2.compliance_urad_per_Nm", 15.0), ("J3.compliance_urad_per_Nm", 10.0)):
        k = cal.names.index(name)
        assert abs(cal.x[k] - truth) < 3 * cal.sigma[k]
    assert selection.nominal_rmse_mm > 5 * selection.rmse_mm  # the machining errors, not calibrated


def test_nothing_is_kept_where_nothing_yields():
    selection, _ = selection_of({})
    assert selection.groups == ()
    left = [s for s in selection.table if s.reason]
    assert len(left) == 1 and left[0].reason.startswith("not determined by the rows")


def test_a_compliance_softer_than_any_joint_is_left_with_its_value():
    """A J2 'compliance' of 60 urad/(N m) (stiffness 1.7e4 N m/rad) is no joint the prior allows:
    left as a compliance, named with its value (what else explains the rows is the harmonics')."""
    selection, _ = selection_of({1: 60.0, 2: 10.0})
    assert "J2 compliance" not in [g.label for g in selection.groups]
    (left,) = [s for s in selection.table if s.label == "J2 compliance"]
    assert "softer than the prior allows" in left.reason and left.reason.startswith("6")


def test_the_plausibility_and_harm_tests():
    assert implausible(10.0, 2.0) is None and implausible(-3.0, 2.0) is None
    assert "against gravity" in implausible(-7.0, 2.0)
    base = np.random.default_rng(1).normal(0, 1, 400)
    assert not_harmful(base * 0.99, base) and not not_harmful(base * 1.3, base)


def test_no_more_regions_than_distinct_poses():
    q = np.zeros((30, 6))
    q[:10, 1] = 1.0
    assert sorted(len(f) for f in region_folds(q, FOLDS)) == [10, 20]
    assert [len(f) for f in region_folds(np.zeros((30, 6)), FOLDS)] == [30]
