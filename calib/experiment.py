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
from calib.calibrate import CalibrationOptions, fit_setup
from calib.drawstring import DrawstringFrame, DrawstringLineModel, DrawstringSamples, DrawstringSetup
from calib.kinematics import dh_table, tcp_position
from calib.uncertainty import covariance, row_noise

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
    """Candidate configurations touching a gauge line at evenly spaced points.

    The start pose is the best-conditioned of ``restarts`` IK solutions at the line's centre; each
    candidate's tool is tilted up to ``max_tilt_deg`` from the approach and rolled up to
    ``max_roll_deg`` from the start pose, and solved from the start pose.

    Parameters
    ----------
    dh : ndarray, shape (6, 4)
        Nominal D-H table, internal units.
    tool : ndarray, shape (3,)
        TCP in the flange frame [mm].
    limits : ndarray, shape (6, 2)
        Joint limits [rad].
    line : tuple
        ``(point [mm] (3,), unit direction (3,), usable length [mm], unit tool approach (3,))``.
    n : int
        Number of candidates.
    rng : numpy.random.Generator
        Draws restarts, tilts and rolls.
    max_tilt_deg, max_roll_deg : float
        Largest tilt and roll [deg].
    restarts : int
        IK starts at the line's centre.

    Returns
    -------
    q : ndarray, shape (n, 6)
        Configurations [rad], wrapped towards the middle of the limits (zeros if the centre is out
        of reach).
    valid : ndarray of bool, shape (n,)
        Reached (IK error < 1e-3 mm), inside the limits and conditioning > ``MIN_CONDITIONING``.
    """
    point, direction, length, approach = line
    q, valid = centre_solutions(dh, tool, limits, line, rng, restarts)
    if not valid.any():
        return np.zeros((n, 6)), np.zeros(n, bool)
    start = q[np.argmax(np.where(valid, ik.conditioning(dh, q, tool), -1.0))]
    positions = point + np.linspace(-0.5, 0.5, n)[:, None] * length * direction
    tilt = np.radians(max_tilt_deg) * np.sqrt(rng.uniform(0, 1, n))
    azimuth = rng.uniform(-np.pi, np.pi, n)
    roll = np.radians(max_roll_deg) * rng.uniform(-1, 1, n)
    return tool_turned(dh, tool, limits, start, positions, approach, np.column_stack([tilt, azimuth, roll]))


def centre_solutions(
    dh: np.ndarray, tool: np.ndarray, limits: np.ndarray, line, rng: np.random.Generator, restarts: int = 64
) -> tuple[np.ndarray, np.ndarray]:
    """Configurations (restarts, 6) [rad] putting the TCP on ``line``'s centre with the tool along
    its approach, from ``restarts`` random starts, wrapped towards the limits' middle, and which
    (restarts,) are valid (as :func:`line_candidates`'s)."""
    point, _, _, approach = line
    centre_rot = _orientation(approach, _perpendiculars(approach)[0])
    seeds = rng.uniform(limits[:, 0], limits[:, 1], (restarts, 6))
    q, err = ik.solve(
        dh, tool, np.repeat(point[None], restarts, 0), np.repeat(centre_rot[None], restarts, 0), seeds
    )
    q = _wrap_into(q, limits)
    return q, _valid(dh, tool, limits, q, err)


REACHED_MM = 1e-9
"""Pose error [mm, scaled] at which a turned tool's Newton search stops: reached to far below
``_valid``'s 1e-3 mm, and each waypoint no longer runs all 60 steps after it is there."""


def tool_turned(
    dh: np.ndarray,
    tool: np.ndarray,
    limits: np.ndarray,
    start: np.ndarray,
    positions: np.ndarray,
    approach: np.ndarray,
    turns: np.ndarray,
) -> tuple[np.ndarray, np.ndarray]:
    """Configurations (n, 6) [rad] with the TCP at ``positions`` (n, 3) [mm], the tool tilted from
    ``approach`` and rolled from ``start``'s (6,) [rad] orientation by ``turns`` (n, 3): tilt,
    its azimuth about the approach, roll [rad]; solved from ``start``, wrapped, and which are
    valid."""
    tilt, azimuth, roll = turns.T
    u, v = _perpendiculars(approach)
    z = np.cos(tilt)[:, None] * approach + np.sin(tilt)[:, None] * (
        np.cos(azimuth)[:, None] * u + np.sin(azimuth)[:, None] * v
    )
    x_start = ik.tool_frames(dh, start[None], tool)[1][0, :, 0]
    rotations = np.stack([_rolled(_orientation(zi, x_start), r) for zi, r in zip(z, roll, strict=True)])
    seeds = np.repeat(start[None], len(positions), 0)
    q, err = ik.solve(dh, tool, positions, rotations, seeds, tol=REACHED_MM)
    q = _wrap_into(q, limits)
    return q, _valid(dh, tool, limits, q, err)


def design_model(
    dh: np.ndarray, tool: np.ndarray, setup: DrawstringSetup, q: np.ndarray, line: np.ndarray
) -> DrawstringLineModel:
    """The measurement model of a planned experiment, before it is run.

    Parameters
    ----------
    dh : ndarray, shape (6, 4)
        Nominal D-H table, internal units.
    tool : ndarray, shape (3,)
        TCP in the flange frame [mm].
    setup : DrawstringSetup
        Anchor, offset, noise and dial axes.
    q : ndarray, shape (N, 6)
        Planned configurations [rad].
    line : ndarray of int, shape (N,)
        Gauge line of each.

    Returns
    -------
    DrawstringLineModel
        With the readings the nominal robot would give (dial 0).
    """
    p = tcp_position(dh, q, tool)
    length = np.linalg.norm(p - setup.anchor, axis=1) - setup.length_offset
    samples = DrawstringSamples(q, length, np.zeros(len(q)), np.asarray(line))
    frame = DrawstringFrame.from_nominal(samples, setup, dh, tool)
    return DrawstringLineModel(samples, setup, frame, dh, tool)


def expected_modes(model: DrawstringLineModel, workspace_q: np.ndarray, readings: int = 1) -> np.ndarray:
    """What a calibration on a model's configurations promises over the workspace, from the stated
    noise and the parameters it would identify.

    Parameters
    ----------
    model : DrawstringLineModel
        The planned experiment (``design_model``).
    workspace_q : ndarray, shape (K, 6)
        Configurations the promise is averaged over [rad].
    readings : int
        Readings of every instrument averaged per capture: each row's noise is the stated noise
        over ``sqrt(readings)`` (what was known before measuring, the priors, stays).

    Returns
    -------
    ndarray, shape (r,)
        Workspace error mode variances [mm^2] (``accuracy.workspace_error_modes``).
    """
    prep = fit_setup(model, CalibrationOptions(loss="linear"))
    noise = row_noise(prep.prior, np.full(prep.prior.groups.max() + 1, 1.0 / np.sqrt(readings)))
    _, robot_cov = covariance(prep.prior, prep.before.x, prep.free, noise=noise)
    x = prep.before.x
    return workspace_error_modes(dh_table(x), model.tcp_in_flange(x), workspace_q, robot_cov, model.terms)


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
