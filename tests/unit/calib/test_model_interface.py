"""What the station asks of a measurement model, answered by both kinds against a noise-free truth:
the contract's row errors, the setup estimate, hold-out rows, the next measurement to advise."""

from pathlib import Path

import numpy as np
import pytest
import tomllib

from calib.drawstring import DrawstringSetup, least_aligned_direction
from calib.experiment import design_model
from calib.kinematics import tcp_position
from calib.params import dh_from_degrees
from calib.position import PositionModel, PositionSamples, rotation_from_vector

ROOT = Path(__file__).resolve().parents[3]


def nominal(robot: str) -> np.ndarray:
    with open(ROOT / f"configs/robots/{robot}.toml", "rb") as f:
        joints = tomllib.load(f)["joints"]
    return dh_from_degrees(np.array([[j["theta_deg"], j["d_mm"], j["a_mm"], j["alpha_deg"]] for j in joints]))


@pytest.mark.parametrize("k", [1, 2, 3])
def test_the_least_aligned_direction(rng, k):
    directions = rng.normal(size=(k, 3))
    directions /= np.linalg.norm(directions, axis=1)[:, None]
    s = least_aligned_direction(directions)
    assert np.linalg.norm(s) == pytest.approx(1.0)
    if k < 3:
        np.testing.assert_allclose(directions @ s, 0.0, atol=1e-12)
    else:  # no unit vector has a smaller sum of squared alignments
        other = rng.normal(size=(500, 3))
        other /= np.linalg.norm(other, axis=1)[:, None]
        assert np.sum((directions @ s) ** 2) <= np.sum((other @ directions.T) ** 2, axis=1).min()


@pytest.fixture(scope="module")
def drawstring():
    """Drawstring readings the nominal JR680 gives from a known anchor, rows on two line ids."""
    dh, tool = nominal("hsr_jr680"), np.zeros(3)
    rng = np.random.default_rng(0)
    q = np.radians(rng.uniform(-40, 40, (40, 6)) + [0, -30, 20, 0, -60, 0])
    setup = DrawstringSetup(anchor=np.array([-800.0, 600.0, -600.0]), length_offset=200.0)
    return design_model(dh, tool, setup, q, np.repeat([0, 1], 20))


def test_a_drawstring_model_answers_the_station(drawstring):
    model = drawstring
    assert model.kind == "drawstring"
    np.testing.assert_allclose(model.row_error_mm(model.x0), 0.0, atol=1e-9)
    estimate = model.setup_estimate(model.x0)
    np.testing.assert_allclose(estimate.anchor_mm, [-800.0, 600.0, -600.0])
    assert estimate.length_offset_mm == 200.0 and [ln.id for ln in estimate.lines] == [0, 1]
    np.testing.assert_array_equal(model.placement_ids(), np.repeat([0, 1], 20))
    np.testing.assert_array_equal(model.tcp_in_flange(model.x0), np.zeros(3))
    advice = model.measurement_advice(model.x0)
    assert advice.cover == "its own 2 lines" and "add a line placement along" in advice.next_measurement
    held_out = model.with_samples(model.samples.subset(np.arange(5, 15)))
    assert held_out.kind == "drawstring" and held_out.row_error_mm(model.x0).shape == (10,)
    x = model.x0.copy()
    x[model.names.index("anchor.x_mm")] += 1.0  # every row's residual moves; the row order is kept
    sigma = model.residuals(x)[0] / model.row_error_mm(x)[0]
    np.testing.assert_allclose(model.row_residuals(x)[:, 0], sigma * model.row_error_mm(x))


def test_a_position_model_answers_the_station():
    dh, probe = nominal("ur10"), np.array([0.0, 0.0, 100.0])
    q = np.random.default_rng(1).uniform(-np.pi, np.pi, (30, 6))
    rot, shift = rotation_from_vector(np.array([0.1, -0.2, 2.5])), np.array([2500.0, -1000.0, 200.0])
    model = PositionModel(PositionSamples(q, tcp_position(dh, q, probe) @ rot.T + shift), dh, probe)
    assert model.kind == "position"
    np.testing.assert_allclose(model.row_error_mm(model.x0), 0.0, atol=1e-6)
    estimate = model.setup_estimate(model.x0)
    np.testing.assert_allclose(estimate.tracker_from_base.rotation, rot, atol=1e-9)
    np.testing.assert_allclose(estimate.tracker_from_base.translation_mm, shift, atol=1e-6)
    np.testing.assert_array_equal(estimate.probe_mm, probe)
    np.testing.assert_array_equal(model.placement_ids(), np.zeros(30))
    np.testing.assert_array_equal(model.tcp_in_flange(model.x0), probe)
    advice = model.measurement_advice(model.x0)
    assert advice.cover == "its 30 poses" and "more configurations" in advice.next_measurement
    assert "turn the tool" not in advice.next_measurement  # poses in every orientation
    held_out = model.with_samples(model.samples.subset(np.arange(10)))
    assert held_out.row_error_mm(model.x0).shape == (10,)
    x = model.x0.copy()
    x[model.names.index("J2.a_mm")] += 1.0
    np.testing.assert_allclose(
        np.linalg.norm(model.row_residuals(x), axis=1) * model.sigma, model.row_error_mm(x), rtol=1e-9
    )


def test_poses_that_keep_one_tool_orientation_are_told_to_turn_it():
    """An ISO 9283 cube keeps the tool at one orientation: a shift of the probe along the tool's axis
    is then a shift of the tracker, which the advice names (poses in every orientation do not get it)."""
    from calib import ik

    dh, probe = nominal("ur10"), np.array([0.0, 0.0, 100.0])
    corners = np.array(np.meshgrid(*[[-150.0, 0.0, 150.0]] * 3)).reshape(3, -1).T
    seed = np.radians([0.0, -90.0, 90.0, -90.0, -90.0, 0.0])
    start = ik.tool_frames(dh, seed[None], probe)
    rotation = np.repeat(start[1], len(corners), axis=0)
    q, err = ik.solve(dh, probe, start[0] + corners, rotation, np.repeat(seed[None], len(corners), 0))
    assert np.max(err) < 1e-6
    model = PositionModel(PositionSamples(q, tcp_position(dh, q, probe)), dh, probe)
    advice = model.measurement_advice(model.x0).next_measurement
    assert advice.startswith("turn the tool between poses (its axis stays within 0.0 deg of one direction")
    # the truth it names: the probe's axial column lies in the tracker translations' span
    _, jac = model.residuals_and_jacobian(model.x0)
    shift = jac[:, [model.names.index(f"tracker.{c}_mm") for c in "xyz"]]
    axial = jac[:, model.names.index("probe.z_mm")]
    left = axial - shift @ np.linalg.lstsq(shift, axial, rcond=None)[0]
    assert np.linalg.norm(left) < 1e-6 * np.linalg.norm(axial)
