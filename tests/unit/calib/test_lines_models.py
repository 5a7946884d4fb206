import numpy as np
import pytest

import configs
from calib.joint_terms import JointTerms, compliance_group, harmonic_group
from calib.lines import LineReference, fit_line, line_residual
from calib.models import DrawstringFrame, DrawstringLineModel, DrawstringSamples, DrawstringSetup
from sim_fixtures.world import JR680_FILE, Robot
from station.formats.tables import load_robot


def test_line_fit_and_residual_of_points_on_a_line(rng):
    u = rng.normal(size=3)
    u /= np.linalg.norm(u)
    pts = np.array([10.0, -20.0, 5.0]) + np.outer(rng.uniform(-300, 300, 30), u)
    ref = fit_line(pts)
    assert abs(abs(ref.direction @ u) - 1) < 1e-12
    r, _, _ = line_residual(ref, np.zeros(4), pts)
    assert np.abs(r).max() < 1e-9


def test_residual_is_perpendicular_distance_for_small_tilts(rng):
    ref = LineReference.from_point_direction([0, 0, 0], [0, 1, 0])
    params = np.array([0.3, -0.2, 1e-3, -2e-3])
    p = rng.uniform(-400, 400, (50, 3))
    r, _, _ = line_residual(ref, params, p)
    point, u = ref.line(params)
    rel = p - point
    perp = np.linalg.norm(rel - np.outer(rel @ u, u), axis=1)
    np.testing.assert_allclose(np.linalg.norm(r, axis=1), perp, rtol=1e-5)


def test_line_residual_derivatives(rng):
    ref = LineReference.from_point_direction(rng.normal(size=3), rng.normal(size=3))
    params, p = rng.normal(size=4) * [1, 1, 0.01, 0.01], rng.normal(size=(6, 3)) * 100
    _, dr_dp, dr_dl = line_residual(ref, params, p)
    h = 1e-6
    for k in range(3):
        d = np.zeros(3)
        d[k] = h
        fd = (line_residual(ref, params, p + d)[0] - line_residual(ref, params, p - d)[0]) / (2 * h)
        np.testing.assert_allclose(dr_dp[:, :, k], fd, atol=1e-6)
    for k in range(4):
        d = np.zeros(4)
        d[k] = h
        fd = (line_residual(ref, params + d, p)[0] - line_residual(ref, params - d, p)[0]) / (2 * h)
        np.testing.assert_allclose(dr_dl[:, :, k], fd, atol=1e-4)


# any masses will do: the test is of derivatives
UR10_LINKS = load_robot(configs.path("robots/ur10.toml")).link_masses()


def _model(rng, n_lines, with_terms=False):
    dh = Robot.from_file(JR680_FILE).dh
    groups = [compliance_group(1), compliance_group(2)] + [
        harmonic_group(j, h) for j in range(6) for h in (1, 2)
    ]
    terms = JointTerms([t for g in groups for t in g.terms], dh, UR10_LINKS) if with_terms else None
    n = 12 * n_lines
    q = np.radians([0, -50, -20, 0, -90, 0] + rng.normal(0, 10, (n, 6)))
    samples = DrawstringSamples(
        q, rng.uniform(900, 1100, n), rng.uniform(-0.3, 0.3, n), np.repeat(np.arange(n_lines), 12)
    )
    setup = DrawstringSetup(
        anchor=np.array([-800.0, 600, -600]),
        length_offset=200.0,
        dial_axis={0: np.array([0, 0, 1.0])},
        rho=2.0,
    )
    frame = DrawstringFrame.from_nominal(samples, setup, dh, np.array([5.0, 0, 10]))
    return DrawstringLineModel(samples, setup, frame, dh, np.array([5.0, 0, 10]), terms)


@pytest.mark.parametrize("with_terms", [False, True])
def test_model_jacobian_matches_finite_differences(rng, with_terms):
    for n_lines in (1, 3):
        model = _model(rng, n_lines, with_terms)
        x = model.x0 + rng.normal(0, 1e-3, model.x0.size)
        _, jac = model.residuals_and_jacobian(x)
        h = 1e-6
        for k in range(x.size):
            d = np.zeros(x.size)
            d[k] = h
            fd = (model.residuals(x + d) - model.residuals(x - d)) / (2 * h)
            np.testing.assert_allclose(
                jac[:, k], fd, atol=1e-4 * max(1.0, np.abs(fd).max()), err_msg=model.names[k]
            )


def test_holding_the_robot_leaves_the_setup_columns_and_zeros_the_robots(rng):
    model = _model(rng, 3, with_terms=True)
    x = model.x0 + rng.normal(0, 1e-3, model.x0.size)
    r, jac = model.residuals_and_jacobian(x)
    held_r, held_jac = model.holding_robot().residuals_and_jacobian(x)
    np.testing.assert_array_equal(held_r, r)
    np.testing.assert_array_equal(held_jac[:, model.setup_mask], jac[:, model.setup_mask])
    assert not held_jac[:, ~model.setup_mask].any() and jac[:, ~model.setup_mask].any()


def test_single_line_holds_the_anchor_rotation_about_it(rng):
    assert "anchor.about_line_mm" in _model(rng, 1).gauges()
    assert "anchor.about_line_mm" not in _model(rng, 3).gauges()


def test_each_rows_line_noise_is_what_its_dial_reading_says(rng):
    """Line 0 states its dial axis: a row the dial read sits on the edge to ``sigma_line`` once its
    reading is taken off, an unread row to ``sigma_contact`` along the axis. Lines 1 and 2 state
    none: the dial gated each row, and its reading is the offset's length in a direction across the
    edge no file states (``|dial_mm|`` on either component, a bound); an unread row carries
    ``sigma_contact`` on both. A line no dial read at all is dial-less."""
    model = _model(rng, 3)
    dial = model.samples.dial.copy()
    dial[[0, 12]] = np.nan  # the first rows of lines 0 and 1
    dial[24:] = np.nan  # line 2
    s = model.samples
    model = model.with_samples(DrawstringSamples(s.q, s.length, dial, s.line))
    st = model.setup_values
    line, contact = st.sigma_line, np.hypot(st.sigma_line, st.sigma_contact)
    np.testing.assert_array_equal(model.line_sigma(0)[0], [contact, line])
    np.testing.assert_array_equal(model.line_sigma(0)[1:], line)
    gated = np.hypot(line, np.abs(dial[13:24]))
    np.testing.assert_allclose(model.line_sigma(1)[1:], np.column_stack([gated, gated]), rtol=1e-12)
    np.testing.assert_array_equal(model.line_sigma(1)[0], [contact, contact])
    np.testing.assert_array_equal(model.line_sigma(2), contact)
    assert [model.dial_mode(lid) for lid in (0, 1, 2)] == ["axis", "gated", "none"]
