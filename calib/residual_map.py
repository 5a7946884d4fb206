"""The residual map: the error a calibrated table leaves, predicted at any pose from the
calibration's own rows, with its uncertainty. Two stages, each used only where it cuts the error of
rows predicted from the other folds by ``MIN_GAIN`` and by more than those rows' scatter could by
chance (``calib.angle_errors.clear_gain``; a cell of table and white noise keeps the table;
``fit_map`` returns None):

1. **Joint angle errors** (``calib.angle_errors``): joints 1-3 turning by a smooth function of their
   own angle (a gear's cyclic error, many cycles a turn), seen through the Jacobian; learnt wherever
   a joint stood, whatever the others did.
2. **The shared error** of what they leave (``calib.shared_error``): a local Gaussian process over
   joints 1-3 of the residual vectors, poses a few degrees apart sharing their error.

Near measured poses the prediction's variance tightens; far from them the mean falls back to zero
(the table alone) and the variance to the rows' own mean square.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from calib.angle_errors import (
    DESIGN_ROWS,
    FOLDS,
    AngleErrors,
    features,
    fit_angle_errors_in_blocks,
    joint_jacobian,
    observed_features,
)
from calib.compliance import compliance_response
from calib.kinematics import N_DH, THETA, tcp_jacobian, tcp_position
from calib.map_rows import Observations
from calib.shared_error import MAP_JOINTS, ObservedShared, SharedError, fit_observed_shared, fit_shared, rms3

TOOL = 3
"""The TCP's coordinates in the flange frame, after the table's N_DH unknowns in ``absorbed``."""
ABSORBED = N_DH + TOOL + 6
"""``ResidualMap.absorbed``'s rows: the table's unknowns, the TCP's, the base frame's turn and shift."""


@dataclass(frozen=True)
class ResidualMap:
    """What a calibrated table leaves, predicted at any pose: joints 1-3's angle errors
    (``calib.angle_errors``), then the error neighbouring poses share of what they leave
    (``SharedError``); either may be off (None).

    Attributes
    ----------
    dh : ndarray, shape (6, 4)
        The calibrated table (rad, mm), for the Jacobian at a pose.
    tool_mm : ndarray, shape (3,)
        The TCP in the flange frame [mm].
    angles : AngleErrors or None
    shared : SharedError or None
    cv_rmse_mm, table_cv_rmse_mm : float
        3-D RMS error [mm] of the rows predicted from the other folds, with the map (the last stage
        on) and with the table alone.
    absorbed : ndarray, shape (ABSORBED [+ 2], F), or None
        What the table (rad, mm) and the TCP in the flange [mm] took of the angle errors per
        coefficient, where they were fitted beside it (``calib.absorbed_angles``): added back, less
        the rigid move of the base frame (rad, mm) it makes of the calibration's rows (a frame the
        lines and the anchor fitted with the table alone stay in); then the compliances of joints 2
        and 3 fitted with them (``calib.compliance``, rad per m; a map stored without them has none).
    absorbed_offset : ndarray, shape like ``absorbed``'s rows, or None
        As ``absorbed``, the change at no angle error: least squares' table where the calibration's
        robust weights (rows the angle errors made large) or its weighing left it, added with the
        angle errors.
    """

    dh: np.ndarray
    tool_mm: np.ndarray
    angles: AngleErrors | None
    shared: SharedError | ObservedShared | None
    cv_rmse_mm: float
    table_cv_rmse_mm: float
    absorbed: np.ndarray | None = None
    absorbed_offset: np.ndarray | None = None

    @property
    def explained(self) -> float:
        """Share of the table's cross-validated mean square error the map takes out."""
        return 1.0 - (self.cv_rmse_mm / self.table_cv_rmse_mm) ** 2

    def predict(self, q: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """The predicted error (M, 3) [mm, base frame] at readings ``q`` (M, 6) [rad], and the
        variance per component (M,) [mm^2] of what is left there after it (the angle errors'
        posterior variance, plus the shared error's posterior and unshared variance, or without
        it what the angle errors leave on the folds)."""
        q = np.asarray(q, float)
        mean, variance = np.zeros((q.shape[0], 3)), np.zeros(q.shape[0])
        if self.angles is not None:
            a, offset = self.angle_features(q)
            mean, variance = self.angles.of_features(a, self.absorbed is not None)
            mean = mean + offset
        if self.shared is None:
            return mean, variance + (self.angles.rest_mm2 if self.angles is not None else 0.0)
        shared_mean, shared_variance = self.shared.predict(q)
        return mean + shared_mean, variance + shared_variance

    def angle_features(self, q: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """The TCP's response (M, 3, F) [mm/rad] to the angle errors' coefficients at readings ``q``
        (M, 6) [rad], with what the table took of them added back (``absorbed``), and the TCP's
        move (M, 3) [mm] of ``absorbed_offset`` (zero without it)."""
        if self.absorbed is None:
            return features(q, joint_jacobian(self.dh, q, self.tool_mm)), np.zeros((q.shape[0], 3))
        p, jac = tcp_jacobian(self.dh, q, self.tool_mm)
        joints = jac[:, :, [4 * j + THETA for j in range(MAP_JOINTS)]]
        response = table_response(self.dh, q, p, jac)
        if self.absorbed.shape[0] > ABSORBED:  # the compliances beside the table
            response = np.concatenate([response, compliance_response(self.dh, q, self.tool_mm, jac)], axis=2)
        offset = np.zeros(self.absorbed.shape[0]) if self.absorbed_offset is None else self.absorbed_offset
        return features(q, joints) + response @ self.absorbed, response @ offset


def table_response(dh: np.ndarray, q: np.ndarray, tcp_mm: np.ndarray, jacobian: np.ndarray) -> np.ndarray:
    """The TCP's move (M, 3, ABSORBED) [mm per rad or mm] per unit of the table's unknowns (their
    ``jacobian`` (M, 3, N_DH) at readings ``q`` (M, 6) [rad]), of the TCP's flange-frame
    coordinates (the flange's axes), and of a small turn [rad] and shift [mm] of the base frame
    (the TCP ``tcp_mm`` (M, 3) turned about the origin, moved)."""
    zero = tcp_position(dh, q, np.zeros(TOOL))
    flange = np.stack([tcp_position(dh, q, axis) - zero for axis in np.eye(TOOL)], axis=2)
    return np.concatenate([jacobian[:, :, :N_DH], flange, frame_response(tcp_mm)], axis=2)


def frame_response(tcp_mm: np.ndarray) -> np.ndarray:
    """The move (M, 3, 6) [mm per rad, mm per mm] of points ``tcp_mm`` (M, 3) per small turn of the
    frame about its axes (``omega x p``) and per shift along them."""
    turn = np.cross(np.eye(3)[None, :, :], tcp_mm[:, None, :]).transpose(0, 2, 1)
    return np.concatenate([turn, np.broadcast_to(np.eye(3), (len(tcp_mm), 3, 3))], axis=2)


def fit_map(q: np.ndarray, error_mm: np.ndarray, dh: np.ndarray, tool_mm: np.ndarray) -> ResidualMap | None:
    """The residual map of a position instrument's rows ``q`` (N, 6) [rad] with residuals
    ``error_mm`` (N, 3) [mm, measured minus the table's TCP, base frame] (``fit_rows_map``)."""
    return fit_rows_map(Observations.of_positions(q, error_mm), dh, tool_mm)


def fit_rows_map(rows: Observations, dh: np.ndarray, tool_mm: np.ndarray) -> ResidualMap | None:
    """The residual map of what ``rows`` observe (``calib.map_rows``) of the table ``dh`` (6, 4)
    (rad, mm) with the TCP ``tool_mm`` (3,) [mm]: the angle errors where they cut the folds' error
    by their ``MIN_GAIN``, then the shared error of what is left where it cuts that by
    ``MIN_GAIN``; None where neither does (or too few rows, or the rows fit exactly). A position
    instrument's rows take the shared error's three independent components (``SharedError``),
    other rows the observation operator (``ObservedShared``)."""
    if rows.q.shape[0] < 2 * FOLDS or not np.any(rows.value_mm):
        return None
    design = observation_design(rows, joint_jacobian(dh, rows.q, tool_mm))
    angles = fit_angle_errors_in_blocks(design, rows.value_mm, rows.row)
    left = rows.value_mm.copy()
    for at, a in design() if angles is not None else ():
        left[at] -= a @ angles.weights
    if rows.positions:
        shared = fit_shared(rows.q, left.reshape(-1, 3))
    else:
        shared = fit_observed_shared(rows, left)
    if angles is None and shared is None:
        return None
    table = rms3(rows.value_mm[:, None])
    best = shared.cv_rmse_mm if shared is not None else float(np.sqrt(3.0 * angles.rest_mm2))
    return ResidualMap(np.asarray(dh, float), np.asarray(tool_mm, float), angles, shared, best, table)


def observation_design(rows: Observations, jacobian: np.ndarray):
    """``design()``: the responses of ``rows``' observations to the angle errors' coefficients
    (``features`` of a position instrument's rows, ``observed_features`` of others') with the joint
    Jacobian (N, 3, 3) [mm/rad] of each row, yielded ``DESIGN_ROWS`` at a time as (slice of the
    observations, responses (k, F)) (``calib.angle_errors.Folds``)."""

    def design():
        if rows.positions:  # three observations a row, in order: the row's features
            step = DESIGN_ROWS // 3
            for s in range(0, rows.q.shape[0], step):
                a = features(rows.q[s : s + step], jacobian[s : s + step])
                yield slice(3 * s, 3 * (s + a.shape[0])), a.reshape(3 * a.shape[0], -1)
            return
        for s in range(0, rows.row.size, DESIGN_ROWS):
            at = slice(s, s + DESIGN_ROWS)
            yield at, observed_features(rows.q[rows.row[at]], jacobian[rows.row[at]], rows.direction[at])

    return design


def map_arrays(found: ResidualMap) -> dict[str, np.ndarray]:
    """The map as named arrays (what a file stores beside the corrected table): the table and TCP,
    the fold errors, the angle errors' kernel, coefficients and covariance, the shared error's
    kernel and its rows (joints 1-3 only, all its kernel reads, and their residuals)."""
    out = {
        "dh": found.dh,
        "tool_mm": found.tool_mm,
        "cv_rmse_mm": np.array([found.cv_rmse_mm, found.table_cv_rmse_mm]),
    }
    if found.angles is not None:
        a = found.angles
        out["angle_kernel"] = np.array([a.length_deg, a.sigma_deg, a.rest_mm2])
        out["angle_weights"], out["angle_covariance"] = a.weights, a.covariance
    if found.absorbed is not None:
        out["angle_absorbed"] = found.absorbed
    if found.absorbed_offset is not None:
        out["angle_absorbed_offset"] = found.absorbed_offset
    if found.shared is not None:
        s = found.shared
        out["shared_kernel"] = np.array(
            [s.length_scale_deg, s.shared_mm2, s.noise_mm2, s.cv_rmse_mm, s.table_cv_rmse_mm]
        )
        if isinstance(s, ObservedShared):
            out["observed_q"], out["observed_direction"] = s.q[:, :MAP_JOINTS], s.direction
            out["observed_value_mm"] = s.value_mm
        else:
            out["shared_q"], out["shared_error_mm"] = s.q[:, :MAP_JOINTS], s.error_mm
    return out


def map_from_arrays(arrays: dict[str, np.ndarray]) -> ResidualMap:
    """The map ``map_arrays`` wrote (the shared rows' wrist joints read as 0: the kernel ignores
    them)."""
    angles = shared = None
    if "angle_kernel" in arrays:
        length, sigma, rest = (float(v) for v in arrays["angle_kernel"])
        angles = AngleErrors(length, sigma, arrays["angle_weights"], arrays["angle_covariance"], rest)
    if "shared_kernel" in arrays:
        kernel = (float(v) for v in arrays["shared_kernel"])
        if "observed_q" in arrays:
            q = whole_readings(arrays["observed_q"])
            shared = ObservedShared(q, arrays["observed_direction"], arrays["observed_value_mm"], *kernel)
        else:
            shared = SharedError(whole_readings(arrays["shared_q"]), arrays["shared_error_mm"], *kernel)
    cv, table = (float(v) for v in arrays["cv_rmse_mm"])
    absorbed, offset = (arrays.get(key) for key in ("angle_absorbed", "angle_absorbed_offset"))
    return ResidualMap(arrays["dh"], arrays["tool_mm"], angles, shared, cv, table, absorbed, offset)


def whole_readings(q: np.ndarray) -> np.ndarray:
    """Readings (N, 6) [rad] of joints 1-3's ``q`` (N, 3), the wrist's read as 0 (the kernel ignores
    them)."""
    return np.hstack([q, np.zeros((q.shape[0], 6 - MAP_JOINTS))])


def left_share(found: ResidualMap, q: np.ndarray) -> np.ndarray:
    """Share (N,) of the error the table alone leaves that is left with the map at readings ``q``
    (N, 6) [rad]: the map's variance there over the table's mean square per component on the
    folds, at most 1 (near the rows the map learnt from: the instrument's noise and what neighbours
    do not share; far from them: 1, the table's)."""
    table_mm2 = found.table_cv_rmse_mm**2 / 3.0
    return np.minimum(found.predict(q)[1] / table_mm2, 1.0)


MAPPED_PASSES = 2
"""Newton steps of ``mapped_readings`` (the map changes by micrometres over the step)."""


def mapped_readings(found: ResidualMap, q: np.ndarray) -> np.ndarray:
    """Readings (N, 6) [rad] at which the table alone puts the TCP where the table plus the map's
    prediction put it at readings ``q`` (N, 6) [rad]: ``q`` moved by the least joint motion that
    carries the table's TCP by the prediction (the TCP's Jacobian by the six joints, its
    pseudo-inverse). What a measurement model of the table alone takes to judge table + map."""
    q = np.asarray(q, float)
    target = tcp_position(found.dh, q, found.tool_mm) + found.predict(q)[0]
    out = q.copy()
    for _ in range(MAPPED_PASSES):
        p, jac = tcp_jacobian(found.dh, out, found.tool_mm)
        joints = jac[:, :, [4 * j + THETA for j in range(6)]]
        out += np.einsum("njc,nc->nj", np.linalg.pinv(joints), target - p)
    return out
