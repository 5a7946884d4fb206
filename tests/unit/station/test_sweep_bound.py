"""A sweep's rows read in passes (columns ``pass`` and ``t_s``): the predicted workspace bound
counts what a pass's rows share, against the simulated truth."""

import dataclasses

import numpy as np
import pytest

import configs
from calib.drawstring import TIMING_NAME
from calib.kinematics import dh_table, tcp_position
from calib.metrics import aligned_errors
from sim_fixtures.scenario import setup_dict
from sim_fixtures.world import World
from station.formats.samples import Samples, load_samples
from station.formats.tables import SetupFile, load_robot
from station.jobs import calibration

ROWS_PER_LINE, PASSES_PER_LINE = 240, 2
SHARED_MM, CORRELATION_ROWS = 0.1, 30  # an error along each pass five times the drawstring's noise


def _true_rmse(world, x) -> float:
    q = world.random_configurations(1000, np.random.default_rng(7))
    p = tcp_position(dh_table(x), np.radians(q), np.zeros(3))
    return float(np.sqrt(np.mean(aligned_errors(p, world.true_tcp_mm(q)) ** 2)))


def _shared_error(rng, passes: np.ndarray) -> np.ndarray:
    """An AR(1) error [mm] (N,) of ``SHARED_MM`` along each pass's rows in order."""
    phi = np.exp(-1.0 / CORRELATION_ROWS)
    e = np.zeros(passes.size)
    for p in np.unique(passes):
        rows = np.flatnonzero(passes == p)
        walk = np.empty(rows.size)
        walk[0] = rng.normal()
        for k in range(1, rows.size):
            walk[k] = phi * walk[k - 1] + np.sqrt(1.0 - phi**2) * rng.normal()
        e[rows] = SHARED_MM * walk
    return e


@pytest.fixture(scope="module")
def sweep():
    """The simulated cell's rows cut into passes, a shared error along each: the world, the setup,
    and the rows with and without their passes."""
    world = World.create(0)
    rng = np.random.default_rng([0, 37])
    setup = SetupFile.model_validate(setup_dict(world, rng))
    s = world.sample_set(ROWS_PER_LINE, rng)
    rank = np.concatenate([np.flatnonzero(s.line == i) for i in np.unique(s.line)])
    order = np.empty(len(s), int)
    order[rank] = np.arange(len(s))
    passes = s.line * PASSES_PER_LINE + (order % ROWS_PER_LINE) * PASSES_PER_LINE // ROWS_PER_LINE
    t_s = order / 60.0
    length = s.length_mm + _shared_error(rng, passes)  # a pass's rows are in time order
    white = Samples("sweep.csv", "drawstring", s.q_deg, length, s.dial_mm, s.line)
    return world, setup, white, dataclasses.replace(white, sweep_pass=passes, t_s=t_s)


def _calibrate(samples, setup):
    robot = load_robot(configs.path("robots/hsr_jr680.toml"))
    return calibration.calibrate_samples(samples, robot, setup, terms="geometric")


def test_a_sweeps_bound_counts_what_its_passes_share(sweep):
    world, setup, white, swept = sweep
    as_white, as_swept = _calibrate(white, setup), _calibrate(swept, setup)
    # the passes change what the fit states, not the fit: rows that jump between poses are no path,
    # so the drawstring's timing (an unknown of swept rows) stays at its start and the rest is the
    # same to the solver's last digits (one more column in its products)
    timing = as_swept.model.names.index(TIMING_NAME)
    assert as_swept.calibration.x[timing] == 0.0
    np.testing.assert_allclose(as_white.calibration.x, np.delete(as_swept.calibration.x, timing), rtol=1e-9)
    true = _true_rmse(world, as_swept.calibration.x)
    bound_white = as_white.report.workspace.predicted_rmse_95_mm
    bound_swept = as_swept.report.workspace.predicted_rmse_95_mm
    assert bound_white < true <= bound_swept
    assert bound_swept < 3.0 * true  # honest, not absurdly loose


def test_a_sweeps_columns_are_read(tmp_path):
    path = tmp_path / "samples.csv"
    q = "10,-60,40,0,30,0"
    path.write_text(
        f"pass,t_s,line,q1_deg,q2_deg,q3_deg,q4_deg,q5_deg,q6_deg,length_mm\n1,0.5,0,{q},700\n,0.6,0,{q},701\n"
    )
    samples = load_samples(path)
    np.testing.assert_array_equal(samples.sweep_pass, [1, -1])
    np.testing.assert_array_equal(samples.t_s, [0.5, 0.6])
    path.write_text(f"t_s,line,q1_deg,q2_deg,q3_deg,q4_deg,q5_deg,q6_deg,length_mm\n0.5,0,{q},700\n")
    assert load_samples(path).sweep_pass is None  # a static session's rows: no pass
