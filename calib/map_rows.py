"""What a calibration's rows observe of the error its table leaves (the residual map's data,
``calib.residual_map``): each row ``i`` observes ``H_i e(q_i)`` plus noise, ``e(q)`` the TCP's
error [mm, base frame] (where the robot truly is minus where the fitted model puts it) and ``H_i``
(m_i x 3) the row's unit observation directions at the solution, those of the measurement model's
own derivative by the TCP:

- a tracker's row observes its whole error (``H_i = I``): measured minus modelled position, turned
  into the base frame;
- a drawstring row observes it along the cable (the unit vector from the anchor to the TCP): the
  reading minus the model's length;
- a row on a gauge line observes it across the fitted line (two unit directions perpendicular to
  it): the TCP sits on the edge, so the model's TCP (moved by the dial's reading along its axis)
  lies ``-e`` across it. Only where the row's stated noise across the line is at most
  ``LINE_NOISE_RATIO`` times the drawstring's: a line whose dial did not state its axis bounds a
  row's offset by the dial's whole reading, tenths of a millimetre, which no map learns from.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

LINE_NOISE_RATIO = 2.0
"""A gauge-line row's observations are used where their stated noise is at most this many times
the drawstring's."""


@dataclass(frozen=True)
class Observations:
    """K scalar observations of the error of N rows.

    Attributes
    ----------
    q : ndarray, shape (N, 6)
        The rows' joint readings [rad].
    row : ndarray, shape (K,)
        The row each observation is of.
    direction : ndarray, shape (K, 3)
        Its unit direction (base frame): it observes ``direction . e(q[row])``.
    value_mm : ndarray, shape (K,)
        What it observed [mm] (measured minus modelled, along ``direction``).
    positions : bool
        Every row observes its whole error, in order (x, y, z) (``of_positions``).
    """

    q: np.ndarray
    row: np.ndarray
    direction: np.ndarray
    value_mm: np.ndarray
    positions: bool = False

    @classmethod
    def of_positions(cls, q: np.ndarray, error_mm: np.ndarray) -> Observations:
        """A position instrument's rows ``q`` (N, 6) [rad] with residual vectors ``error_mm`` (N, 3)
        [mm, base frame]."""
        n = q.shape[0]
        direction = np.tile(np.eye(3), (n, 1))
        return cls(q, np.repeat(np.arange(n), 3), direction, np.asarray(error_mm, float).ravel(), True)


def model_observations(model, x: np.ndarray) -> Observations:
    """The observations of a measurement model's rows at its solution ``x`` (module docstring): a
    ``PositionModel``'s or a ``DrawstringLineModel``'s."""
    if model.kind == "position":
        rot, _ = model.tracker_from_base(x)
        error = (model.samples.position - model.predicted_mm(x)) @ rot
        return Observations.of_positions(model.samples.q, error)
    return drawstring_observations(model, x)


def drawstring_observations(model, x: np.ndarray) -> Observations:
    """A ``DrawstringLineModel``'s rows at ``x``: along the cable, then across each gauge line."""
    samples, setup = model.samples, model.setup_values
    tcp = model.tcp(x)
    cable = tcp - model.anchor(x)
    rows, direction = [np.arange(len(samples))], [cable / np.linalg.norm(cable, axis=1)[:, None]]
    value = [model.row_error_mm(x)]
    for lid in model.line_ids:
        on = np.flatnonzero(samples.line == lid)
        kept = np.all(model.line_sigma(lid) <= LINE_NOISE_RATIO * setup.sigma_length, axis=1)
        on = on[kept]
        point, along = model.line(x, lid)
        axis = setup.dial_axis_of(lid)
        shift = 0.0 if axis is None else np.nan_to_num(samples.dial[on])[:, None] * np.asarray(axis, float)
        across = np.linalg.svd(along[None, :])[2][1:]  # (2, 3): orthonormal, perpendicular to the line
        offset = (tcp[on] - shift - point) @ across.T
        rows.append(np.repeat(on, 2))
        direction.append(np.tile(across, (on.size, 1)))
        value.append(-offset.ravel())
    return Observations(samples.q, np.concatenate(rows), np.concatenate(direction), np.concatenate(value))
