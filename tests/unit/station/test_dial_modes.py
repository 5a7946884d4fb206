"""The three ways a gauge line's rows are held to its edge, against the simulated truth: the dial's
axis stated, the dial gating captures without an axis (the paper's procedure: the operator brings
the tool onto the edge until the dial reads about zero), and no dial at all."""

import dataclasses

import numpy as np
import pytest

import configs
from calib.kinematics import dh_table, tcp_position
from calib.metrics import aligned_errors
from sim_fixtures.scenario import setup_dict
from sim_fixtures.world import Noise, World
from station.commands.calibrate import summary
from station.formats.samples import Samples
from station.formats.tables import SetupFile, load_robot
from station.jobs import calibration

SEEDS = range(6)
PAPER_PLACEMENT_MM = 0.01
"""The operator leaves the tool within this of the edge, the dial reading it (about zero)."""


def _setups(world, rng) -> dict[str, SetupFile]:
    stated = SetupFile.model_validate(setup_dict(world, rng))
    no_axis = stated.model_copy(update={"lines": []})
    return {"axis": stated, "gated": no_axis, "none": no_axis.model_copy(update={"dial": None})}


def _true_rmse(world, x) -> float:
    q = world.random_configurations(1000, np.random.default_rng(7))
    p = tcp_position(dh_table(x), np.radians(q), np.zeros(3))
    return float(np.sqrt(np.mean(aligned_errors(p, world.true_tcp_mm(q)) ** 2)))


@pytest.fixture(scope="module")
def sessions():
    """Per seed and mode: (true workspace error [mm], reported 95 % bound [mm], report), the same
    samples calibrated with each setup (dial readings dropped for ``none``)."""
    robot = load_robot(configs.path("robots/hsr_jr680.toml"))
    out = {mode: [] for mode in ("axis", "gated", "none")}
    for seed in SEEDS:
        world = World.create(seed, n_lines=3, noise=Noise(placement_mm=PAPER_PLACEMENT_MM))
        rng = np.random.default_rng(seed + 1000)
        s = world.sample_set(45, rng, 0.0, 5)
        for mode, setup in _setups(world, rng).items():
            dial = np.full(len(s.line), np.nan) if mode == "none" else s.dial_mm
            samples = Samples(f"seed {seed}", "drawstring", s.q_deg, s.length_mm, dial, s.line)
            outcome = calibration.calibrate_samples(samples, robot, setup)
            bound = outcome.report.workspace.predicted_rmse_95_mm
            out[mode].append((_true_rmse(world, outcome.calibration.x), bound, outcome.report))
    return out


def test_a_dial_that_gates_without_an_axis_keeps_the_accuracy_of_a_stated_axis(sessions):
    """The readings (within 0.01 mm) bound each row's offset: its line noise grows from
    ``line_sigma_mm`` 0.01 mm to at most hypot(0.01, 0.01) = 1.41 times that, so the true error
    may grow as much, not to the contact-by-eye 0.2 mm's (4x worse on these seeds when gated rows
    were held to ``contact_sigma_mm``)."""
    true = {mode: np.mean([t for t, _, _ in runs]) for mode, runs in sessions.items()}
    assert true["gated"] <= np.sqrt(2) * true["axis"], true
    assert true["gated"] < 0.5 * true["none"], true


@pytest.mark.parametrize("mode", ["axis", "gated", "none"])
def test_each_modes_95_percent_bound_holds_its_true_error(sessions, mode):
    """A bound that holds in 95 % of cells misses two or more of six 3.3 % of the time."""
    inside = [t <= b for t, b, _ in sessions[mode]]
    assert sum(inside) >= len(inside) - 1, sessions[mode]


def test_the_report_and_the_summary_say_how_each_line_was_held(sessions):
    for mode, said in (
        ("axis", "dial axis stated"),
        ("gated", "dial gated, no dial_axis"),
        ("none", "no dial (contact_sigma_mm)"),
    ):
        report = sessions[mode][0][2]
        assert [line["dial"] for line in report.as_json()["lines"]] == [mode] * 3
        assert f"gauge lines 0, 1, 2: {said}" in summary(report)
    gated = sessions["gated"][0][2]
    assert gated.fit_check.dial_mode is None and "dial-less" not in summary(gated)


def test_a_gated_line_with_rows_the_dial_missed_is_a_lost_channel():
    world = World.create(0, n_lines=1, noise=Noise(placement_mm=PAPER_PLACEMENT_MM))
    rng = np.random.default_rng(1000)
    s = world.sample_set(60, rng, 0.0, 5)
    dial = s.dial_mm.copy()
    dial[::3] = np.nan
    setup = _setups(world, rng)["gated"]
    samples = Samples("gaps", "drawstring", s.q_deg, s.length_mm, dial, s.line)
    report = calibration.calibrate_samples(
        samples, load_robot(configs.path("robots/hsr_jr680.toml")), setup
    ).report
    assert any(
        w.startswith("the dial read other rows of the line, but no dial reading") for w in report.warnings
    )
    assert report.line_dial == {0: "gated"}
    assert dataclasses.asdict(report.fit_check)["dial_mode"] is not None
