"""The accuracy matrix (``benchmarks/accuracy_matrix.py``) against its committed baseline: every
simulated cell times every setup a user may write, true workspace error and the 95 % bound's
coverage. A cell worse beyond its seeds' spread fails; the baseline moves only in a commit that
says why (``python benchmarks/accuracy_matrix.py --write-baseline``)."""

import json

import pytest

from benchmarks import accuracy_matrix as matrix

pytestmark = pytest.mark.guard


@pytest.fixture(scope="module")
def baseline() -> dict:
    return json.loads(matrix.BASELINE.read_text())


@pytest.fixture(scope="module")
def results() -> dict:
    return matrix.run(matrix.SEEDS)


def test_the_baseline_holds_every_cell_and_setup_at_the_guards_seeds(baseline):
    assert {c: set(v) for c, v in baseline.items()} == {c: set(matrix.VARIANTS) for c in matrix.CELLS}
    assert all(len(runs) == matrix.SEEDS for v in baseline.values() for runs in v.values())


def test_no_cell_is_worse_than_its_baseline(results, baseline):
    found = matrix.regressions(results, baseline)
    assert not found, "\n".join(found) + "\n" + matrix.table(results)


def test_the_comparison_fails_a_cell_made_worse_or_less_honest(baseline):
    """The comparison itself: the baseline passes against itself; one cell's errors moved up by
    twice its allowance, or one seed pushed outside its bound, is named."""
    assert matrix.regressions(baseline, baseline) == []
    cell, setup = "ur10", "gated, 3 lines free"
    was = matrix.summary(baseline[cell][setup])
    allowance = max(was["spread_mm"], matrix.SPREAD_FLOOR * was["mean_true_mm"])
    worse = json.loads(json.dumps(baseline))
    for r in worse[cell][setup]:
        r["true_mm"] += 2 * allowance
    found = matrix.regressions(worse, baseline)
    assert {f.split(":")[0] for f in found} == {f"{cell} / {setup}"}
    assert "true workspace error" in found[0]
    outside = json.loads(json.dumps(baseline))
    run = next(r for r in outside[cell][setup] if r["true_mm"] <= r["bound95_mm"])
    run["bound95_mm"] = 0.99 * run["true_mm"]
    assert "inside the 95 % bound" in " ".join(matrix.regressions(outside, baseline))
