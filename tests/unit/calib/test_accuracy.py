"""The workspace-accuracy maths against direct simulation: draw table errors, run the forward
kinematics, re-fit the base, and compare with what the closed forms predict."""

import numpy as np
import pytest

import configs
from calib.accuracy import (
    robot_covariance,
    workspace_error_modes,
    workspace_rmse_bound,
)
from calib.kinematics import N_DH, tcp_position
from calib.metrics import aligned_errors
from calib.params import dh_from_degrees
from station.formats.tables import load_robot


def _jr680():
    robot = load_robot(configs.path("robots/hsr_jr680.toml"))
    limits = np.radians(robot.limits_deg())
    q = np.random.default_rng(0).uniform(limits[:, 0], limits[:, 1], (300, 6))
    return dh_from_degrees(robot.table_deg()), np.asarray(robot.tool_mm), q


def test_modes_sum_to_the_simulated_mean_square_error(rng):
    dh, tool, q = _jr680()
    # Small errors (0.006 deg, 0.05 mm), so the field is linear in them.
    sigma = np.array([1e-4 if k % 4 in (0, 3) else 0.05 for k in range(N_DH)])
    cov = np.diag(sigma**2)
    modes = workspace_error_modes(dh, tool, q, cov)
    p = tcp_position(dh, q, tool)
    tables = dh + (sigma * rng.normal(size=(400, N_DH))).reshape(400, 6, 4)
    draws = [np.mean(aligned_errors(tcp_position(t, q, tool), p) ** 2) for t in tables]
    # Monte Carlo mean of 400 draws: its own standard error is std/sqrt(400).
    assert abs(np.mean(draws) - modes.sum()) < 4 * np.std(draws) / np.sqrt(len(draws))


def test_bound_is_the_quantile_of_the_mode_sum(rng):
    for modes in (np.array([1.0]), np.array([0.7, 0.4, 0.2, 0.06, 0.03]), rng.exponential(size=N_DH) ** 3):
        z = rng.normal(size=(100_000, modes.size))
        rms = np.sqrt(z**2 @ modes)
        for p in (0.5, 0.95):
            # Welch-Satterthwaite matches the first two moments; the quantiles agree to a few percent.
            assert workspace_rmse_bound(modes, p) == pytest.approx(np.quantile(rms, p), rel=0.03)


def test_an_exactly_redundant_held_parameter_adds_nothing_to_the_combination(rng):
    a = rng.normal(size=(50, 3))
    cov_free = np.linalg.inv(a.T @ a)
    jac_held = a[:, :1]  # the held parameter acts exactly like free parameter 0
    robot = np.arange(N_DH)
    sensitivity = -cov_free @ (a.T @ jac_held)
    cov = robot_covariance(cov_free, sensitivity, np.array([0, 1, 2]), np.array([5]), np.array([2.0]), robot)
    together = np.zeros(N_DH)
    together[[0, 5]] = 1.0
    assert together @ cov @ together == pytest.approx(cov_free[0, 0], rel=1e-9)
    assert cov[5, 5] == 4.0  # alone, it may be off by its full tolerance
