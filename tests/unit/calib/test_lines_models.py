import numpy as np
import pytest

import configs
from calib import lm
from calib.calibrate import WithPrior
from calib.drawstring import DrawstringFrame, DrawstringLineModel, DrawstringSamples, DrawstringSetup
from calib.joint_terms import JointTerms, compliance_group, harmonic_group
from calib.lines import LineReference, fit_line, line_residual
from calib.params import DH_NAMES
from calib.uncertainty import covariance
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


def test_the_jacobian_is_the_einsums_then_the_whitening_to_the_last_digit(rng):
    """What planning's choices turn on: the chain rule through the TCP in blocks of rows is, bit for
    bit, an einsum over the TCP's coordinates whitened afterwards (the drawstring rows divided by
    their noise, the line rows multiplied by their weights)."""
    model = _model(rng, 3, with_terms=True)
    x = model.x0 + rng.normal(0, 1e-3, model.x0.size)
    _, jac = model.residuals_and_jacobian(x)
    p, dp = model._robot_jacobian(x)  # (3, N, 24 + K)
    robot = ~model.setup_mask
    rel = p - model.anchor(x)
    u = rel / np.linalg.norm(rel, axis=1)[:, None]
    n = len(model.samples)
    expected = np.einsum("nk,knj->nj", u, dp) / model.setup_values.sigma_length
    np.testing.assert_array_equal(jac[:n][:, robot], expected)
    at = n
    for lid in model.line_ids:
        rows, (w_line, shift) = model._on_line[lid], model._line_weights[lid]
        _, dr_dp, _ = line_residual(model.frame.lines[lid], x[model._line_cols[lid]], p[rows] - shift)
        expected = w_line[:, :, None] * np.einsum("nik,knj->nij", dr_dp, dp[:, rows])
        got = jac[at : at + 2 * rows.size][:, robot]
        np.testing.assert_array_equal(got, expected.reshape(-1, robot.sum()))
        at += 2 * rows.size


def test_by_axes_is_the_same_model_to_the_rounding_and_stays_so(rng):
    model = _model(rng, 3, with_terms=True)
    fast = model.by_axes()
    x = model.x0 + rng.normal(0, 1e-3, model.x0.size)
    (r, jac), (r_fast, jac_fast) = model.residuals_and_jacobian(x), fast.residuals_and_jacobian(x)
    np.testing.assert_allclose(r_fast, r, rtol=0, atol=1e-9)
    np.testing.assert_allclose(jac_fast, jac, rtol=0, atol=1e-9 * np.abs(jac).max())
    assert not np.array_equal(jac_fast, jac)  # the other composition: its own last digits
    rows = model.samples.subset(np.arange(0, 36, 2))
    for derived in (fast.with_samples(rows), fast.with_terms(JointTerms()), fast.holding_robot()):
        assert derived._by_axes
    assert not model.with_samples(rows)._by_axes
    assert fast.holding_robot().with_samples(rows)._robot_held  # a subset of the setup fit's rows
    assert not fast.with_samples(rows)._robot_held


def _sandwich(prior, x, free, w, noise):
    """The covariance's sandwich from the weighted copy of the whole Jacobian."""
    _, jac = prior.residuals_and_jacobian(x)
    jac = jac * w[:, None]
    a = jac[:, free]
    gain = np.linalg.pinv(a.T @ a) @ a.T
    spread = gain * w * noise
    return spread @ spread.T


def test_the_covariance_in_blocks_of_rows_is_the_sandwich(rng, monkeypatch):
    """On rows that fit one block, the whole-array sandwich to the last digit (planning's promise
    as it was); in blocks of 10 rows, the same to the rounding of its inverse."""
    model = _model(rng, 3, with_terms=True)
    prior = WithPrior(model, model.x0)
    x = model.x0 + rng.normal(0, 1e-4, model.x0.size)
    free = model.setup_mask.copy()
    free[[1, 5, 6, 9]] = True
    free[np.flatnonzero(np.isin(model.names, list(model.gauges())))] = False
    w, noise = rng.uniform(0.5, 1.0, prior.groups.size), rng.uniform(0.8, 1.2, prior.groups.size)
    expected = _sandwich(prior, x, free, w, noise)
    np.testing.assert_array_equal(covariance(prior, x, free, w, noise)[0], expected)
    monkeypatch.setattr(lm, "NORMAL_ROWS", 10)
    rounding = 1e-15 * np.linalg.cond(expected)  # the inverse's rounding grows with its condition
    np.testing.assert_allclose(
        covariance(prior, x, free, w, noise)[0], expected, rtol=0, atol=rounding * np.abs(expected).max()
    )


def test_the_prior_rows_go_into_the_models_jacobian_bit_for_bit_as_appended(rng):
    """``WithPrior`` fills the prior's rows into room the model's Jacobian leaves (no copy of a
    million rows'): the same residuals and Jacobian, to the last digit, as appended to a copy."""

    class Plain:  # the model without its tall Jacobian: the copy's path
        def __init__(self, model):
            self.model = model

        def __getattr__(self, name):
            if name == "residuals_and_tall_jacobian":
                raise AttributeError(name)
            return getattr(self.model, name)

    model = _model(rng, 3, with_terms=True)
    x = model.x0 + rng.normal(0, 1e-4, model.x0.size)
    tall, copied = WithPrior(model, model.x0), WithPrior(Plain(model), model.x0)
    (r, jac), (r_copy, jac_copy) = tall.residuals_and_jacobian(x), copied.residuals_and_jacobian(x)
    np.testing.assert_array_equal(r, r_copy)
    np.testing.assert_array_equal(jac, jac_copy)
    assert jac.shape == (tall.rows.size, x.size) and jac[len(model.rows) :].any()
    np.testing.assert_array_equal(tall.residuals_and_jacobian(x, False)[0], r)


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


def test_the_gauges_at_a_table_with_the_tcp_on_joint_6s_axis_hold_its_turn(rng):
    """J6's theta is a gauge where the TCP lies on joint 6's axis: not at the start (the model's
    TCP 5 mm along the flange's x), at a table whose J6's a is -5 mm."""
    model = _model(rng, 3)
    x = model.x0.copy()
    assert "J6.theta_deg" not in model.gauges() and "J6.theta_deg" not in model.gauges(x)
    x[DH_NAMES.index("J6.a_mm")] -= 5.0
    assert "J6.theta_deg" in model.gauges(x)
