"""The drawstring + line model (the paper's LMLC): a cable from a fixed anchor to the TCP read as a
length, and the TCP held to straight gauge edges, each row along a dial's axis at the dial's noise
and across it at the arm's own; a sweep's rows add the drawstring's timing. The tracker's model is
``calib.position``; both are ``calib.models.MeasurementModel``s.
"""

from __future__ import annotations

import copy
from dataclasses import dataclass, field
from typing import ClassVar

import numpy as np

from calib.alignment import pass_rates
from calib.blocks import each_block
from calib.identifiability import structural_holds, tolerance
from calib.joint_terms import JointTerms
from calib.kinematics import N_DH, dh_table, tcp_position, tcp_position_by_axes
from calib.lines import N_LINE_PARAMS, LineReference, fit_line, line_residual
from calib.models import GROUP_LENGTH, GROUP_LINE_ACROSS, GROUP_LINE_DIAL, MeasurementAdvice
from calib.params import DH_NAMES


@dataclass(frozen=True)
class DrawstringSamples:
    """Drawstring samples, one row per configuration.

    Attributes
    ----------
    q : ndarray, shape (N, 6)
        Joint readings [rad].
    length : ndarray, shape (N,)
        Drawstring readings [mm].
    dial : ndarray, shape (N,)
        Dial readings [mm], NaN where absent.
    line : ndarray of int, shape (N,)
        Gauge line id of each row, -1 for no line constraint.
    sweep_pass : ndarray of int, shape (N,), optional
        Sweep pass of each row (-1: a static pose); None for a static set.
    t_s : ndarray, shape (N,), optional
        When each row was read [s] (orders a pass's rows); with ``sweep_pass``.
    """

    q: np.ndarray
    length: np.ndarray
    dial: np.ndarray
    line: np.ndarray
    sweep_pass: np.ndarray | None = None
    t_s: np.ndarray | None = None

    def __len__(self) -> int:
        return self.q.shape[0]

    def subset(self, rows: np.ndarray) -> DrawstringSamples:
        """The samples of ``rows`` (indices or a boolean mask), in that order."""
        swept = self.sweep_pass is not None
        return DrawstringSamples(
            self.q[rows],
            self.length[rows],
            self.dial[rows],
            self.line[rows],
            self.sweep_pass[rows] if swept else None,
            self.t_s[rows] if swept else None,
        )


@dataclass(frozen=True)
class DrawstringSetup:
    """Station geometry and noise, as the setup file states them.

    Attributes
    ----------
    anchor : ndarray, shape (3,)
        Rough drawstring anchor [mm], base frame.
    length_offset : float
        Rough reading offset [mm]: reading = distance - offset.
    sigma_length, sigma_line : float
        Drawstring reading noise and line-contact noise [mm].
    dial_axis : dict of int to ndarray, shape (3,)
        Per line id, the dial's unit axis in the base frame.
    default_dial_axis : ndarray, shape (3,), optional
        The axis on lines without their own; with neither, the dial gates captures and its reading
        bounds the offset from the edge.
    sigma_contact : float
        How far the tool may sit off the edge where no dial read it [mm, 1 sigma]: a row without a
        reading (NaN); across the edge in both directions on a line without a dial axis. A row the
        dial read on such a line is held to its reading instead (``DrawstringLineModel.line_sigma``).
    rho : float
        Weight of the line terms.
    anchor_tolerance, offset_tolerance : float
        How far the rough values may be off [mm], taken as 2 sigma.
    """

    anchor: np.ndarray
    length_offset: float
    sigma_length: float = 0.02
    sigma_line: float = 0.01
    dial_axis: dict[int, np.ndarray] = field(default_factory=dict)
    default_dial_axis: np.ndarray | None = None
    sigma_contact: float = 0.2
    rho: float = 1.0
    anchor_tolerance: float = 50.0
    offset_tolerance: float = 10.0

    def dial_axis_of(self, line_id: int) -> np.ndarray | None:
        """The dial's unit axis (3,) on line ``line_id``, or None where the dial only gates."""
        return self.dial_axis.get(line_id, self.default_dial_axis)


@dataclass(frozen=True)
class DrawstringFrame:
    """What a training fit fixes for every later evaluation: the line references (by line id),
    the anchor's starting point [mm], the basis its three unknowns move it along, and whether the
    rows were ``timed`` (swept: the drawstring's timing is an unknown, ``DrawstringLineModel``)."""

    lines: dict[int, LineReference]
    anchor0: np.ndarray
    anchor_basis: np.ndarray
    timed: bool = False

    @classmethod
    def from_nominal(cls, samples: DrawstringSamples, setup: DrawstringSetup, dh, tool) -> DrawstringFrame:
        """The frame of a training set.

        Lines are fitted to the nominal TCPs of each line's samples; with a single line the anchor
        moves in (radial, along, tangential) coordinates so that its free rotation about the line
        is one named unknown.

        Parameters
        ----------
        samples : DrawstringSamples
            The training rows.
        setup : DrawstringSetup
            Rough anchor and dial axes.
        dh : ndarray, shape (6, 4)
            Nominal D-H table, internal units (rad, mm).
        tool : array_like, shape (3,)
            TCP in the flange frame [mm].

        Returns
        -------
        DrawstringFrame
        """
        p = tcp_position(dh, samples.q, tool)
        ids = sorted(int(i) for i in np.unique(samples.line) if i >= 0)
        lines = {i: fit_line(p[samples.line == i], setup.dial_axis_of(i)) for i in ids}
        anchor0 = np.asarray(setup.anchor, float)
        basis = np.eye(3)
        if len(lines) == 1:
            ref = next(iter(lines.values()))
            rel = anchor0 - ref.point
            radial = rel - (rel @ ref.direction) * ref.direction
            radial /= np.linalg.norm(radial)
            basis = np.column_stack([radial, ref.direction, np.cross(ref.direction, radial)])
        timed = samples.sweep_pass is not None and bool(np.any(samples.sweep_pass >= 0))
        return cls(lines, anchor0, basis, timed)

    def anchor_names(self) -> tuple[str, str, str]:
        """Names of the anchor's three unknowns: base axes, or (radial, along, about) one line."""
        if np.allclose(self.anchor_basis, np.eye(3)):
            return ("anchor.x_mm", "anchor.y_mm", "anchor.z_mm")
        return ("anchor.radial_mm", "anchor.along_mm", "anchor.about_line_mm")


@dataclass(frozen=True)
class FittedLine:
    """A gauge line as fitted: its ``id``, a point on it ``point_mm`` (3,) [mm] and its unit
    ``direction`` (3,), base frame."""

    id: int
    point_mm: np.ndarray
    direction: np.ndarray


@dataclass(frozen=True)
class DrawstringSetupEstimate:
    """The drawstring setup at a solution: ``anchor_mm`` (3,) [mm] in the base frame, the reading's
    ``length_offset_mm`` [mm], the fitted ``lines`` and, for swept rows, ``timing_ms``: how much
    later than stamped the drawstring's lengths were true [ms] (None: static rows). Field names are
    the report's keys."""

    anchor_mm: np.ndarray
    length_offset_mm: float
    lines: tuple[FittedLine, ...]
    timing_ms: float | None = None


CHAIN_ROWS = 2048
"""Rows per block of the Jacobian's rows (the chain rule through the TCP and the setup's columns,
``calib.blocks``' threads sharing the blocks): a block's products stay in the CPU's cache (on
100,000 rows twice as fast as whole-array products)."""


def _combine(out: np.ndarray, c: np.ndarray, dp: np.ndarray, columns, weigh, weight) -> None:
    """The chain rule through the TCP on a block of rows: ``out[:, to] = weigh(sum_k c[:, k]
    dp[k][:, of], weight)`` for each ``(to, of)`` pair of ``columns``, with the derivatives by the
    TCP ``c`` (M, 3), the TCP's derivatives ``dp`` (3, M, r) by the robot's r unknowns and the
    whitening ``weigh`` (``np.divide`` by a noise, ``np.multiply`` by a weight (M, 1)), in that
    order: an ``einsum`` over k, then the whitening, to the last digit; ``out`` (M, n) by ``x``."""
    for to, of in columns:
        cols, d = out[:, to], dp[:, :, of]
        np.multiply(d[0], c[:, 0, None], out=cols)
        cols += d[1] * c[:, 1, None]
        cols += d[2] * c[:, 2, None]
        weigh(cols, weight, out=cols)


def least_aligned_direction(directions: np.ndarray) -> np.ndarray:
    """A unit direction (3,) least aligned with every row of ``directions`` (k, 3): perpendicular
    to all of them while k < 3; the x axis when k = 0."""
    if directions.size == 0:
        return np.array([1.0, 0.0, 0.0])
    return np.linalg.svd(directions)[2][-1]


TIMING_NAME = "drawstring.timing_ms"
TIMING_PRIOR_MS = 10.0
"""What is known of a sweep's drawstring timing before measuring [ms, 1 sigma]: the latency the
station states, within what a device's round trip and a busy bus leave unknown."""
RATE_STEP_DEG = 2.0
"""Rows of a pass farther apart than this in a joint [deg] are not one stretch of a path (a sweep
records rows every few hundredths of a degree): no rate, no timing, where they meet."""


class DrawstringLineModel:
    """Drawstring distances to a ground anchor plus gauge-block line contacts (the paper's LMLC).

    Unknowns ``x = [dh (24), anchor (3), length_offset (1), 4 per line, timing (1, swept rows
    only), terms (K)]``. Residuals, in this order:

    - drawstring, every row: ``(|p - anchor| - length_offset + rate * timing - Y) / sigma_length``,
      ``rate`` the nominal length's rate along the row's pass [mm/s] (0 off a pass): a reading
      stamped ``timing`` earlier than its length was true (the moment a device measures inside its
      round trip is not known to the station) errs by ``rate * timing``, an error that follows the
      path and does not average out over rows; a tenth of a millisecond of it moved a sweep's
      table by more than its noise did
    - line, two per row on a line: ``sqrt(rho) * offset(p - dial * dial_axis, line) / sigma_line``

    with ``p`` the TCP at the angles the links take (``calib.joint_terms``).

    Parameters
    ----------
    samples : DrawstringSamples
        The N rows.
    setup : DrawstringSetup
        Rough geometry and noise.
    frame : DrawstringFrame
        Line references and anchor basis (``DrawstringFrame.from_nominal`` of the training rows).
    dh0 : ndarray, shape (6, 4)
        Starting table, internal units (rad, mm).
    tool : array_like, shape (3,)
        TCP in the flange frame [mm].
    terms : JointTerms, optional
        Joint-space terms beyond the table (default: none).
    """

    kind: ClassVar[str] = "drawstring"

    def __init__(self, samples, setup: DrawstringSetup, frame: DrawstringFrame, dh0, tool, terms=None):
        self.samples, self.setup_values, self.frame = samples, setup, frame
        self.tool = np.asarray(tool, float)
        self.terms = terms or JointTerms()
        self._basis = self.terms.basis(samples.q)
        self.line_ids = sorted(frame.lines)
        self._line_cols = {
            lid: slice(N_DH + 4 + N_LINE_PARAMS * k, N_DH + 4 + N_LINE_PARAMS * (k + 1))
            for k, lid in enumerate(self.line_ids)
        }
        line_names = tuple(f"line{lid}.{n}" for lid in self.line_ids for n in ("c1_mm", "c2_mm", "b1", "b2"))
        timing_names = (TIMING_NAME,) if frame.timed else ()
        setup_names = frame.anchor_names() + ("length_offset_mm",) + line_names + timing_names
        self.names = DH_NAMES + setup_names + self.terms.names
        self._terms_at = N_DH + len(setup_names)
        self._timing_at = self._terms_at - 1 if frame.timed else None
        self._rate = self._length_rate(dh0) if frame.timed else None
        self.x0 = np.concatenate(
            [
                np.ravel(dh0),
                np.zeros(3),
                [setup.length_offset],
                np.zeros(len(line_names) + len(timing_names) + len(self.terms)),
            ]
        )
        index = np.arange(len(self.names))
        self.setup_mask = (index >= N_DH) & (index < self._terms_at)
        self.tool_mask = np.zeros(len(self.names), bool)
        self._on_line = {lid: np.flatnonzero(samples.line == lid) for lid in self.line_ids}
        line_rows = np.concatenate([self._on_line[lid] for lid in self.line_ids] or [[]]).astype(int)
        n = len(samples)
        self.rows = np.concatenate([np.arange(n), np.repeat(line_rows, 2)])
        line_groups = np.tile([GROUP_LINE_DIAL, GROUP_LINE_ACROSS], line_rows.size)
        self.groups = np.concatenate([np.full(n, GROUP_LENGTH), line_groups])
        self.pose_groups = () if self.line_ids else (GROUP_LENGTH,)
        self._robot_held, self._by_axes = False, False
        self._robot_columns = (  # where the table's and the terms' derivatives go: (in x, in dp)
            (slice(0, N_DH), slice(0, N_DH)),
            (slice(self._terms_at, len(self.names)), slice(N_DH, None)),
        )
        self._line_weights = {  # per line: its rows' whitening (rows, 2) and dial shift (rows, 3) [mm]
            lid: (np.sqrt(setup.rho) / self.line_sigma(lid), self._dial_shift(self._on_line[lid], lid))
            for lid in self.line_ids
        }

    def _length_rate(self, dh0) -> np.ndarray:
        """Each row's nominal length's rate along its pass [mm/s] (N,) (``calib.alignment.pass_rates``
        of the starting table's distances to the starting anchor, where the rows lie within
        ``RATE_STEP_DEG`` of their neighbours: a rate's relative error is the table's, about 1e-3,
        and the timing it multiplies a fraction of a millisecond)."""
        s = self.samples
        if s.sweep_pass is None:
            return np.zeros(len(s))
        dist = np.linalg.norm(
            tcp_position(dh_table(np.ravel(dh0)), s.q, self.tool) - self.frame.anchor0, axis=1
        )
        return pass_rates(dist, s.t_s, s.sweep_pass, s.q, np.radians(RATE_STEP_DEG))

    def gauges(self, x: np.ndarray | None = None) -> dict[str, str]:
        """The table's structural gauges at ``x`` (default the start) with a free anchor and free
        lines, and, on one line, the anchor's turn about it."""
        x = self.x0 if x is None else x
        held = structural_holds(dh_table(x), self.tool, "anchor and the lines")
        if len(self.line_ids) == 1:
            held["anchor.about_line_mm"] = (
                "a single line: turning the anchor about it keeps every distance to the line"
            )
        return held

    def prior_sigma(self) -> np.ndarray:
        """The table's manufacturing tolerance, the rough anchor's and offset's (half the stated
        tolerances), the timing's ``TIMING_PRIOR_MS``, the terms' priors; the lines are free (inf)."""
        sigma = np.full(len(self.names), np.inf)
        sigma[:N_DH] = tolerance(self.names[:N_DH])
        sigma[N_DH : N_DH + 3] = self.setup_values.anchor_tolerance / 2
        sigma[N_DH + 3] = self.setup_values.offset_tolerance / 2
        if self._timing_at is not None:
            sigma[self._timing_at] = TIMING_PRIOR_MS
        sigma[self._terms_at :] = self.terms.prior_sigma()
        return sigma

    def holding_robot(self) -> DrawstringLineModel:
        """This model with the robot's Jacobian columns left zero: the setup fit needs no chain rule
        through the TCP (nor the TCP's derivatives)."""
        held = copy.copy(self)
        held._robot_held = True
        return held

    def by_axes(self) -> DrawstringLineModel:
        """This model with its TCPs and their derivatives from ``kinematics.*_by_axes``."""
        fast = copy.copy(self)
        fast._by_axes, fast._robot_cache = True, None
        return fast

    def with_samples(self, samples: DrawstringSamples) -> DrawstringLineModel:
        """The same model (frame, setup, terms, kinematics) on other rows, e.g. a hold-out set."""
        return self._alike(samples, self.terms)

    def with_terms(self, terms: JointTerms) -> DrawstringLineModel:
        """The same model (rows, frame, setup, kinematics) with other joint-space terms."""
        return self._alike(self.samples, terms)

    def _alike(self, samples: DrawstringSamples, terms: JointTerms) -> DrawstringLineModel:
        model = DrawstringLineModel(samples, self.setup_values, self.frame, self.x0[:N_DH], self.tool, terms)
        model._robot_held = self._robot_held
        return model.by_axes() if self._by_axes else model

    # -- unpacking ---------------------------------------------------------------------------
    def dh(self, x: np.ndarray) -> np.ndarray:
        """The D-H table (6, 4) in ``x``, internal units."""
        return dh_table(x)

    def term_values(self, x: np.ndarray) -> np.ndarray:
        """The joint-space terms' values (K,) in ``x``, internal units."""
        return x[self._terms_at :]

    def tcp_in_flange(self, x: np.ndarray) -> np.ndarray:
        """The TCP (3,) [mm] in the flange frame: given, the cable is tied there."""
        return self.tool

    def anchor(self, x: np.ndarray) -> np.ndarray:
        """The anchor (3,) [mm], base frame."""
        return self.frame.anchor0 + self.frame.anchor_basis @ x[N_DH : N_DH + 3]

    def length_offset(self, x: np.ndarray) -> float:
        """The reading's offset [mm]: model length = distance - offset."""
        return float(x[N_DH + 3])

    def line(self, x: np.ndarray, lid: int) -> tuple[np.ndarray, np.ndarray]:
        """Line ``lid`` as (point [mm], unit direction)."""
        return self.frame.lines[lid].line(x[self._line_cols[lid]])

    def timing_ms(self, x: np.ndarray) -> float | None:
        """How much later than stamped the swept rows' lengths were true [ms]; None: static rows."""
        return None if self._timing_at is None else float(x[self._timing_at])

    def model_length(self, x: np.ndarray, p: np.ndarray) -> np.ndarray:
        """The length each row's reading should show (N,) [mm] with its TCP at ``p`` (N, 3)."""
        return self._reading(x, np.linalg.norm(p - self.anchor(x), axis=1))

    def _reading(self, x: np.ndarray, dist: np.ndarray) -> np.ndarray:
        """The readings (N,) [mm] of cable lengths ``dist`` (N,) [mm]: less the offset, plus what
        the timing moves a swept row's."""
        length = dist - self.length_offset(x)
        if self._timing_at is not None:
            length += self._rate * x[self._timing_at] / 1e3
        return length

    def setup_estimate(self, x: np.ndarray) -> DrawstringSetupEstimate:
        """Anchor, offset, lines and timing at ``x`` (see ``DrawstringSetupEstimate``)."""
        lines = tuple(FittedLine(lid, *self.line(x, lid)) for lid in self.line_ids)
        return DrawstringSetupEstimate(self.anchor(x), self.length_offset(x), lines, self.timing_ms(x))

    # -- what the station asks ---------------------------------------------------------------
    def placement_ids(self) -> np.ndarray:
        """The gauge line of each row (N,), -1 where none."""
        return self.samples.line

    def measurement_advice(self, x: np.ndarray) -> MeasurementAdvice:
        """Another line placement, least aligned with the lines fitted at ``x``."""
        k = len(self.line_ids)
        cover = "its own line" if k == 1 else f"its own {k} lines"
        s = least_aligned_direction(np.array([self.line(x, lid)[1] for lid in self.line_ids]))
        return MeasurementAdvice(
            cover,
            f"add a line placement along [{s[0]:.2f}, {s[1]:.2f}, {s[2]:.2f}] (base frame), "
            "elsewhere in the workspace and with varied tool orientations",
        )

    # -- residuals ---------------------------------------------------------------------------
    def tcp(self, x: np.ndarray) -> np.ndarray:
        """The TCP of every row [mm], (N, 3), base frame, at the angles the links take."""
        q = self.terms.link_angles(self.samples.q, self.term_values(x), self._basis)
        return (tcp_position_by_axes if self._by_axes else tcp_position)(self.dh(x), q, self.tool)

    def row_error_mm(self, x: np.ndarray) -> np.ndarray:
        """Drawstring residuals ``Y - Y_model`` [mm], shape (N,) (the contract's metric).

        Parameters
        ----------
        x : ndarray, shape (n,)
            Full parameter vector, internal units.

        Returns
        -------
        ndarray, shape (N,)
            Reading minus model length, ``Y - (|p - anchor| - length_offset)`` [mm].
        """
        return self.samples.length - self.model_length(x, self.tcp(x))

    def residuals(self, x: np.ndarray) -> np.ndarray:
        """Whitened residuals (m,): N drawstring rows, then two per row on a line."""
        return self._evaluate(x, jacobian=False)[0]

    def row_residuals(self, x: np.ndarray) -> np.ndarray:
        """Each row's whitened drawstring residual (N, 1) (the line rows are the fit's, not the row's)."""
        return self.residuals(x)[: len(self.samples), None]

    def residuals_and_jacobian(self, x: np.ndarray, jacobian: bool = True):
        """Whitened residuals (m,) and their analytic Jacobian (m, n), None unless ``jacobian``."""
        return self._evaluate(x, jacobian)

    def residuals_and_tall_jacobian(self, x: np.ndarray, spare_rows: int):
        """``residuals_and_jacobian`` with ``spare_rows`` zero rows after the model's (m + spare_rows,
        n): room for ``calib.calibrate.WithPrior``'s rows without a copy of the Jacobian (a million
        rows' is some 1.5 GB)."""
        return self._evaluate(x, True, spare_rows)

    def _robot_jacobian(self, x) -> tuple[np.ndarray, np.ndarray]:
        """TCPs (N, 3) and their derivatives (3, N, 24 + K) by the table and the terms."""
        if self._by_axes:
            return self.terms.tcp_derivatives(
                self.dh(x), self.samples.q, self.tool, self.term_values(x), self._basis
            )
        p, jac_table, jac_terms = self.terms.tcp_jacobian(
            self.dh(x), self.samples.q, self.tool, self.term_values(x), self._basis, self._by_axes
        )
        dp = np.empty((3, len(self.samples), N_DH + jac_terms.shape[2]))  # coordinate-major
        dp[:, :, :N_DH], dp[:, :, N_DH:] = jac_table.transpose(1, 0, 2), jac_terms.transpose(1, 0, 2)
        return p, dp

    def _robot_points(self, x, jacobian: bool):
        """``(p, dp)`` of :meth:`_robot_jacobian` (dp None unless ``jacobian``), reused while the
        table and terms stay as they were: the setup fit moves only the setup unknowns, and its
        every evaluation would otherwise redo the kinematics of all rows."""
        key = np.concatenate([x[:N_DH], x[self._terms_at :]]).tobytes()
        cached = getattr(self, "_robot_cache", None)
        if cached is not None and cached[0] == key and (cached[2] is not None or not jacobian):
            return cached[1], cached[2]
        self._robot_cache = None  # not two sets of Jacobians alive at once
        p, dp = self._robot_jacobian(x) if jacobian else (self.tcp(x), None)
        self._robot_cache = (key, p, dp)
        return p, dp

    def _evaluate(self, x, jacobian, spare_rows: int = 0):
        """Residuals (m,) and Jacobian (m + spare_rows, n) (None unless ``jacobian``; robot columns
        zero where the robot is held, the spare rows zero), filled block by block: the drawstring
        rows, then each line's."""
        p, dp = self._robot_points(x, jacobian and not self._robot_held)
        dp = None if self._robot_held else dp  # (a cached one too)
        r = np.empty(self.rows.size)
        jac = np.zeros((self.rows.size + spare_rows, x.size)) if jacobian else None
        at = self._length_block(x, p, dp, r, jac)
        for lid in self.line_ids:
            at = self._line_block(x, lid, p, dp, r, jac, at)
        return r, jac

    def _length_block(self, x, p, dp, r, jac) -> int:
        """The drawstring rows' residuals into ``r`` and Jacobian into ``jac``; returns the next row."""
        st, n_rows = self.setup_values, len(self.samples)
        rel = p - self.anchor(x)
        dist = np.linalg.norm(rel, axis=1)
        r[:n_rows] = (self._reading(x, dist) - self.samples.length) / st.sigma_length
        if jac is not None:
            u = rel / dist[:, None]

            def block(s: int, e: int) -> None:
                out = jac[s : min(e, n_rows)]
                if dp is not None:
                    _combine(out, u[s:e], dp[:, s:e], self._robot_columns, np.divide, st.sigma_length)
                out[:, N_DH : N_DH + 3] = -(u[s:e] @ self.frame.anchor_basis) / st.sigma_length
                out[:, N_DH + 3] = -1.0 / st.sigma_length
                if self._timing_at is not None:
                    out[:, self._timing_at] = self._rate[s:e] / 1e3 / st.sigma_length

            each_block(n_rows, CHAIN_ROWS, block)
        return n_rows

    def _line_block(self, x, lid, p, dp, r, jac, at: int) -> int:
        """Line ``lid``'s two residuals per row into ``r`` and ``jac`` from row ``at``; returns the next."""
        rows, (w_line, shift) = self._on_line[lid], self._line_weights[lid]
        r_line, dr_dp, dr_dl = line_residual(self.frame.lines[lid], x[self._line_cols[lid]], p[rows] - shift)
        end = at + 2 * rows.size
        r[at:end] = (w_line * r_line).ravel()
        if jac is not None:
            j = jac[at:end].reshape(rows.size, 2, x.size)

            def block(s: int, e: int) -> None:
                part = j[s:e]
                if dp is not None:
                    chain = dp[:, rows[s:e]]  # the block's rows' derivatives, once for both offsets
                    for i in range(2):  # dr_dp is the line's, the same on every row
                        c = np.broadcast_to(dr_dp[0, i], (len(part), 3))
                        _combine(part[:, i], c, chain, self._robot_columns, np.multiply, w_line[s:e, i, None])
                part[:, :, self._line_cols[lid]] = w_line[s:e, :, None] * dr_dl[s:e]

            each_block(rows.size, CHAIN_ROWS, block)  # a line may hold none of these rows (a subset)
        return end

    def line_sigma(self, lid: int) -> np.ndarray:
        """Each row's stated noise on line ``lid`` along (e1, e2) [mm], (rows, 2).

        Where the dial's axis is stated, its reading moves the TCP onto the edge: ``sigma_line``.
        Where it is not, the dial gated the capture and its reading ``dial_mm`` is how far the tool
        sat from the edge, in a direction across it that no file states: either component may
        carry the whole offset, so ``|dial_mm|`` is added in quadrature on both (a bound: RMS over
        directions would be ``|dial_mm| / sqrt(2)``, and held the true error of fewer simulated
        cells). Where no dial read the row, ``sigma_contact`` is (on the axis's component alone
        where an axis is stated)."""
        st, rows = self.setup_values, self._on_line[lid]
        dial = self.samples.dial[rows]
        unread = np.isnan(dial)
        sigma = np.full((rows.size, 2), st.sigma_line)
        if st.dial_axis_of(lid) is None:
            sigma[:] = np.hypot(st.sigma_line, np.nan_to_num(np.abs(dial)))[:, None]
            sigma[unread] = np.hypot(st.sigma_line, st.sigma_contact)
        else:
            sigma[unread, 0] = np.hypot(st.sigma_line, st.sigma_contact)
        return sigma

    def dial_mode(self, lid: int) -> str:
        """How line ``lid``'s rows were held to its edge: ``"axis"`` (the setup states the dial's
        axis and the dial read rows there), ``"gated"`` (the dial read rows without an axis: it gated
        them and bounds their offset), ``"none"`` (no dial reading on the line: ``sigma_contact``)."""
        if np.isnan(self.samples.dial[self._on_line[lid]]).all():
            return "none"
        return "gated" if self.setup_values.dial_axis_of(lid) is None else "axis"

    def _dial_shift(self, rows: np.ndarray, lid: int) -> np.ndarray:
        axis = self.setup_values.dial_axis_of(lid)
        if axis is None:
            return np.zeros((rows.size, 3))
        return np.nan_to_num(self.samples.dial[rows])[:, None] * np.asarray(axis, float)
