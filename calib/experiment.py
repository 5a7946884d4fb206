"""Experiment design before measuring: candidate configurations along a gauge line and what a set
of them promises.

Candidates: evenly spaced TCP positions along the edge, each with the tool tilted at random from
the line's approach direction and rolled at random, solved by the nominal inverse kinematics from
a start found by restarts at the line's centre; a candidate is kept when the solver reaches it,
within the joint limits and away from singularities.

Promise: the calibration's expected covariance with the instruments' stated noise (no readings
needed, the Jacobian at the nominal robot decides), pushed to the workspace as in ``accuracy``.
"""

from __future__ import annotations

import numpy as np

from calib import ik
from calib.accuracy import workspace_error_modes
from calib.calibrate import CalibrationOptions, covariance, prepare
from calib.kinematics import dh_table, tcp_position
from calib.models import DrawstringFrame, DrawstringLineModel, DrawstringSamples, DrawstringSetup

MIN_CONDITIONING = 0.04
"""Inverse condition number of the scaled geometric Jacobian below which a pose counts as near a
singularity (on the JR680: within about 10 deg of the wrist's, q5 = -90): there a millimetre of
tool correction turns the wrist by degrees, and joint noise moves the tool a lot."""


def line_candidates(
    dh: np.ndarray,
    tool: np.ndarray,
    limits: np.ndarray,
    line: tuple[np.ndarray, np.ndarray, float, np.ndarray],
    n: int,
    rng: np.random.Generator,
    max_tilt_deg: float = 25.0,
    max_roll_deg: float = 60.0,
    restarts: int = 64,
) -> tuple[np.ndarray, np.ndarray]:
    """Configurations (n, 6) [rad] touching ``line`` = (point [mm], unit direction, usable length
    [mm], unit tool approach) at ``n`` evenly spaced points, and the mask of those reached within
    the joint ``limits`` (6, 2) [rad] away from singularities. The tool is tilted up to
    ``max_tilt_deg`` from the approach and rolled up to ``max_roll_deg`` from the start pose: the
    best-conditioned of ``restarts`` solutions at the line's centre."""
    point, direction, length, approach = line
    centre_rot = _orientation(approach, _perpendiculars(approach)[0])
    seeds = rng.uniform(limits[:, 0], limits[:, 1], (restarts, 6))
    q, err = ik.solve(
        dh, tool, np.repeat(point[None], restarts, 0), np.repeat(centre_rot[None], restarts, 0), seeds
    )
    q = _wrap_into(q, limits)
    valid = _valid(dh, tool, limits, q, err)
    if not valid.any():
        return np.zeros((n, 6)), np.zeros(n, bool)
    start = q[np.argmax(np.where(valid, ik.conditioning(dh, q, tool), -1.0))]
    positions = point + np.linspace(-0.5, 0.5, n)[:, None] * length * direction
    tilt = np.radians(max_tilt_deg) * np.sqrt(rng.uniform(0, 1, n))
    azimuth = rng.uniform(-np.pi, np.pi, n)
    u, v = _perpendiculars(approach)
    z = np.cos(tilt)[:, None] * approach + np.sin(tilt)[:, None] * (
        np.cos(azimuth)[:, None] * u + np.sin(azimuth)[:, None] * v
    )
    x_start = ik.tool_frames(dh, start[None], tool)[1][0, :, 0]
    roll = np.radians(max_roll_deg) * rng.uniform(-1, 1, n)
    rotations = np.stack([_rolled(_orientation(zi, x_start), r) for zi, r in zip(z, roll, strict=True)])
    q, err = ik.solve(dh, tool, positions, rotations, np.repeat(start[None], n, 0))
    q = _wrap_into(q, limits)
    return q, _valid(dh, tool, limits, q, err)


def design_model(
    dh: np.ndarray, tool: np.ndarray, setup: DrawstringSetup, q: np.ndarray, line: np.ndarray
) -> DrawstringLineModel:
    """The measurement model of configurations ``q`` (N, 6) [rad] on gauge ``line`` ids (N,), with
    the readings the nominal robot would give: an experiment before it is run."""
    p = tcp_position(dh, q, tool)
    length = np.linalg.norm(p - setup.anchor, axis=1) - setup.length_offset
    samples = DrawstringSamples(q, length, np.zeros(len(q)), np.asarray(line))
    frame = DrawstringFrame.from_nominal(samples, setup, dh, tool)
    return DrawstringLineModel(samples, setup, frame, dh, tool)


def expected_modes(model: DrawstringLineModel, workspace_q: np.ndarray) -> np.ndarray:
    """Workspace error modes [mm^2] (``accuracy.workspace_error_modes``) that a calibration on
    ``model``'s configurations promises, with its identified parameters and the stated noise."""
    prep = prepare(model, CalibrationOptions(loss="linear"))
    _, table_cov = covariance(prep.prior, prep.before.x, prep.free)
    return workspace_error_modes(dh_table(prep.before.x), model.tool, workspace_q, table_cov)


def _valid(dh, tool, limits, q, err, tol: float = 1e-3) -> np.ndarray:
    inside = np.all((q >= limits[:, 0]) & (q <= limits[:, 1]), axis=1)
    return (err < tol) & inside & (ik.conditioning(dh, q, tool) > MIN_CONDITIONING)


def _wrap_into(q: np.ndarray, limits: np.ndarray) -> np.ndarray:
    """Each angle shifted by whole turns to the value nearest the middle of its limits."""
    mid = limits.mean(axis=1)
    return q - 2 * np.pi * np.round((q - mid) / (2 * np.pi))


def _orientation(z: np.ndarray, x_hint: np.ndarray) -> np.ndarray:
    """Rotation (3, 3) with z axis ``z`` and x axis ``x_hint`` made perpendicular to it."""
    x = x_hint - (x_hint @ z) * z
    x /= np.linalg.norm(x)
    return np.column_stack([x, np.cross(z, x), z])


def _rolled(rotation: np.ndarray, angle: float) -> np.ndarray:
    """``rotation`` turned by ``angle`` [rad] about its own z axis."""
    c, s = np.cos(angle), np.sin(angle)
    return rotation @ np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


def _perpendiculars(axis: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    u = np.cross(axis, np.eye(3)[np.argmin(np.abs(axis))])
    u /= np.linalg.norm(u)
    return u, np.cross(axis, u)
