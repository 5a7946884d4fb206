"""Mistakes a fit can absorb, caught and named: a gauge line's dial axis that its readings
contradict (flipped, another axis, no dial on that edge), many rows down-weighted (and by what),
the lines read without a dial (what is lost), and a calibration no better than the nominal table.

Each check returns the warnings it calls for and, where the evidence leaves no doubt, a refusal
naming the likely cause and its fix; ``station.jobs.fit_check.fit_check`` adds them to its own.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass

import numpy as np

from calib.accuracy import predicted_workspace_rmse, workspace_error_modes
from calib.calibrate import (
    DOWNWEIGHTED_BELOW,
    Calibration,
    CalibrationOptions,
    WithPrior,
    coarse_draw,
    robust_steps,
)
from calib.consistency import DialGain, dial_gain
from calib.kinematics import dh_table
from calib.models import GROUP_LENGTH, MeasurementModel

DIAL_GAIN_TOLERANCE, DIAL_GAIN_SIGMAS = 0.3, 4.0
"""How far (mm per mm of reading) a line's dial gain may lie from its stated axis before it
disagrees: this much, or this many of the gain's standard errors where it is known less well (few
rows, readings that hardly spread)."""
DIAL_GAIN_FOLLOWS = 0.5
"""A gain shorter than this: the dial does not read the tool's distance from the edge at all."""
DIAL_MIN_DOF = 5
"""A line's dial is judged from this many rows beyond the gain's three coefficients: with fewer,
its residual (and the gain's sigma) rests on one or two numbers (a rehearsed IRB 2600 session that
measured a line at 4 corrected targets, every reading within 0.08 mm of 0, was refused as 'does
not follow')."""
DIAL_SPREAD_NOISES = 3.0
"""A line's dial is judged only where its readings spread beyond the line's constant and trend by
this many of the line's stated noise: nearer that noise, it dilutes the gain towards zero
(``spread^2 / (spread^2 + noise^2)``; at 3 noises 0.9). A rehearsed IRB 2600 session's corrected
second pass landed a line's 30 targets 1.04-1.13 mm off its edge in a smooth trend, 0.0115 mm beyond
it at a 0.01 mm noise: gain 0.05 and refused as 'does not follow'."""
DIAL_FREE_STEPS = 4
"""Robust Gauss-Newton steps from the calibration to the dial-free one (``line_dials``): each cuts
the distance to a full dial-free calibration's TCPs about fivefold (a flipped dial: 1.8 mm at the
start, 0.002 mm after 4, the stated line noise 0.01 mm). On 128 simulated cells (1-3 lines, clean
or 3 % gross; a flipped, another or a shuffled dial) each line's gain came within 0.015 of its
standard error of the full refit's (0.9 where the readings ran along another axis, a verdict many
standard errors clear; at most 0.041 mm/mm against the tolerance's 0.3), every verdict the same,
at 5 ms instead of 65 ms."""
DOWNWEIGHTED_FINDING = 0.05
"""Down-weighted rows beyond this fraction of all, or most rows of one line, are a finding."""


@dataclass(frozen=True)
class LineDial:
    """One gauge line's dial judged against its rows: ``line`` id, stated unit ``axis``, the
    ``gain`` its readings show (``calib.consistency.dial_gain``: the stated axis across the line
    where right) with its ``sigma``, and the ``verdict`` (``agrees``, ``flipped``, ``other axis``,
    ``does not follow``, or ``inconclusive`` for an axis nearly along the line or fewer rows than
    ``DIAL_MIN_DOF`` beyond the gain's three coefficients)."""

    line: int
    axis: tuple[float, float, float]
    gain: tuple[float, float, float]
    sigma: float
    verdict: str


@dataclass(frozen=True)
class Findings:
    """What the checks found: ``warnings`` for the report, a ``refusal`` (None: none), each line's
    ``dials`` and the ``unread`` lines (with rows no dial reading measured the offset of)."""

    warnings: tuple[str, ...] = ()
    refusal: str | None = None
    dials: tuple[LineDial, ...] = ()
    unread: tuple[int, ...] = ()


def findings(model: MeasurementModel, cal: Calibration, weights: np.ndarray) -> Findings:
    """All checks of this module on a finished fit; ``weights`` are the robust loss's per residual
    row (``calib.calibrate.robust_weights``). Rows without dial readings on a line whose dial axis
    the setup states, or on a line the dial read elsewhere, are a lost channel (a warning); a line no
    dial read at all, without an axis, is a dial-less mode."""
    warnings = downweighted(model, cal, weights)
    if model.kind != "drawstring":
        return Findings(tuple(warnings))
    dials = line_dials(model, cal)
    refusal = dial_refusal(dials)
    unread = unread_lines(model)
    stated = [lid for lid in unread if model.setup_values.dial_axis_of(lid) is not None]
    if stated:
        warnings.insert(0, _unread_text(model, stated, "the setup states a dial_axis, but "))
    gaps = [lid for lid in unread if lid not in stated and _read(model, lid).any()]
    if gaps:
        warnings.insert(0, _unread_text(model, gaps, "the dial read other rows of the line, but "))
    return Findings(tuple(warnings), refusal, tuple(dials), tuple(unread))


def dial_mode(found: Findings, model: MeasurementModel) -> str | None:
    """The line saying what a session read without a dial loses; None where every line has one."""
    return _unread_text(model, list(found.unread), "") if found.unread else None


# -- the dial ------------------------------------------------------------------------------------
def line_dials(model, cal: Calibration) -> list[LineDial]:
    """Each line with a stated dial axis and readings, judged by the gain its readings show on
    the TCPs of a fit that does not use them: the calibration ``cal`` of ``model`` moved to the
    rows without their dial readings by ``DIAL_FREE_STEPS`` robust Gauss-Newton steps (the same
    robust cost as a refit's, from next to its optimum: a wrong dial moves the solution by a
    fraction of a millimetre, over which the model is linear); on more than ``COARSE_ROWS`` rows the
    steps on that many (``coarse_draw``), the gain on all."""
    if not judged_lines(model):
        return []
    free = dial_free(coarse_draw(model))
    x = robust_steps(WithPrior(free, free.x0), cal.x, cal.identified, DIAL_FREE_STEPS, CalibrationOptions())
    return judge_dials(model, x)


def dial_free(model):
    """``model`` with its rows' dial readings dropped."""
    samples = model.samples
    return model.with_samples(dataclasses.replace(samples, dial=np.full(len(samples), np.nan)))


def judge_dials(model, x: np.ndarray) -> list[LineDial]:
    """Each line of ``model`` with a stated dial axis and readings, judged by the gain its readings
    show on the TCPs at ``x``, a fit of ``dial_free(model)``."""
    samples = model.samples
    tcp = model.tcp(x)
    out = []
    for lid in judged_lines(model):
        rows = np.flatnonzero((model.placement_ids() == lid) & ~np.isnan(samples.dial))
        point, direction = model.line(x, lid)
        axis = np.asarray(model.setup_values.dial_axis_of(lid), float)
        noise = float(np.min(model.line_sigma(lid)))
        found = dial_gain(tcp[rows], point, direction, samples.dial[rows], noise)
        verdict = _verdict(found, axis, direction, noise)
        out.append(LineDial(lid, _t(axis), _t(found.gain), found.sigma, verdict))
    return out


def judged_lines(model) -> list[int]:
    """The lines whose dial can be judged: a stated axis and readings."""
    axis_of = model.setup_values.dial_axis_of
    return [lid for lid in model.line_ids if _read(model, lid).any() and axis_of(lid) is not None]


def dial_refusal(dials: list[LineDial]) -> str | None:
    """The first line whose dial disagrees with its stated axis, as the fix to make; None if none."""
    return next((_dial_text(d) for d in dials if d.verdict not in ("agrees", "inconclusive")), None)


def _verdict(found: DialGain, axis: np.ndarray, direction: np.ndarray, noise: float) -> str:
    if found.dof < DIAL_MIN_DOF:
        return "inconclusive"  # too few rows to judge the dial by
    if found.spread < DIAL_SPREAD_NOISES * noise:
        return "inconclusive"  # readings that hardly move beyond the line's trend: a diluted gain
    across = axis - (axis @ direction) * direction
    if np.linalg.norm(across) < 0.3:
        return "inconclusive"  # an axis nearly along the line: its readings barely move the TCP across it
    slack = max(DIAL_GAIN_TOLERANCE, DIAL_GAIN_SIGMAS * found.sigma)
    if np.linalg.norm(found.gain - across) <= slack:
        return "agrees"
    if np.linalg.norm(found.gain + across) <= slack:
        return "flipped"
    if np.linalg.norm(found.gain) <= max(DIAL_GAIN_FOLLOWS, DIAL_GAIN_SIGMAS * found.sigma):
        return "does not follow"
    return "other axis"


def _dial_text(d: LineDial) -> str:
    axis, gain = np.array(d.axis), np.array(d.gain)
    if d.verdict == "flipped":
        return (
            f"line {d.line}'s dial readings run against its dial_axis {_v(axis)}: flip it "
            f"(dial_axis = {_v(-axis)} on [[lines]] id {d.line})"
        )
    if d.verdict == "other axis":
        seen = _v(gain / np.linalg.norm(gain))
        return (
            f"line {d.line}'s dial readings move the tool along {seen}, not along its dial_axis {_v(axis)}: "
            f"set dial_axis = {seen} on [[lines]] id {d.line} (the way the indicator reads positive)"
        )
    return (
        f"line {d.line}'s dial readings do not follow the tool's distance from the edge (gain "
        f"{np.linalg.norm(gain):.2f} mm/mm, 1 expected): the dial is on another edge, or the rows carry "
        "the wrong line id"
    )


def unread_lines(model) -> list[int]:
    """The lines with rows no dial reading measures the tool's offset on (``dial_mm`` empty)."""
    return [lid for lid in model.line_ids if not _read(model, lid).all()]


def _read(model, lid: int) -> np.ndarray:
    return ~np.isnan(model.samples.dial[model.placement_ids() == lid])


DIAL_MODE_TEXT = {
    "axis": "dial axis stated (its readings move the TCP onto the edge: line_sigma_mm)",
    "gated": "dial gated, no dial_axis (each reading bounds the offset from the edge: |dial_mm|)",
    "none": "no dial (contact_sigma_mm)",
}
"""How a line's rows were held to its edge (``calib.drawstring.DrawstringLineModel.dial_mode``)."""


def line_modes(model) -> dict[int, str]:
    """Each gauge line's dial mode (``DIAL_MODE_TEXT``'s keys); empty for a tracker's positions."""
    return {lid: model.dial_mode(lid) for lid in model.line_ids} if model.kind == "drawstring" else {}


def _unread_text(model, unread: list[int], lead: str) -> str:
    st = model.setup_values
    some = len(unread) < len(model.line_ids)
    which = "line " + ", ".join(str(lid) for lid in unread) if some else "any line"
    return (
        f"{lead}no dial reading measures the tool's offset from the edge on {which} (rows without "
        f"dial_mm): those rows hold the TCP to contact_sigma_mm {st.sigma_contact:g} mm "
        f"instead of line_sigma_mm {st.sigma_line:g}, and the predicted workspace error counts it"
    )


# -- down-weighted rows --------------------------------------------------------------------------
def downweighted(model: MeasurementModel, cal: Calibration, weights: np.ndarray) -> list[str]:
    """A warning where the robust loss down-weighted more than ``DOWNWEIGHTED_FINDING`` of the rows
    or most rows of one line, naming by what (the drawstring or the line contacts) and the likely
    cause."""
    n, k = len(model.samples), len(cal.downweighted)
    if k == 0:
        return []
    cut = weights[: model.rows.size] ** 2 < DOWNWEIGHTED_BELOW
    by_length = np.unique(model.rows[cut & (model.groups == GROUP_LENGTH)])
    by_line = np.unique(model.rows[cut & (model.groups != GROUP_LENGTH)])
    place = model.placement_ids()
    most = [
        (int(lid), int(np.isin(np.flatnonzero(place == lid), by_line).sum()), int((place == lid).sum()))
        for lid in np.unique(place[place >= 0])
    ]
    most = [m for m in most if m[1] > m[2] / 2]
    if k <= DOWNWEIGHTED_FINDING * n and not most:
        return []
    if most:
        lid, cut_rows, rows = most[0]
        return [
            f"most rows of line {lid} ({cut_rows} of {rows}) are down-weighted by their line contact: "
            "its dial_axis or dial readings are wrong, the rows carry another line's id, or the gauge block "
            "moved while measuring; the fit rests on the other lines"
        ]
    cause = (
        "by their drawstring readings: the cable slipped or snagged, or the anchor moved while measuring"
        if by_length.size >= by_line.size
        else "by their line contacts: the tool left the edge, or a dial_axis or line id is wrong"
    )
    return [f"{k} of {n} rows ({100 * k / n:.0f} %) are down-weighted, {cause}"]


# -- better than the nominal table? ---------------------------------------------------------------
NOMINAL_SHARE = 1 / 3
"""A calibration whose predicted workspace error exceeds this share of the nominal table's expected
error, both predicted from the same tolerances (so an overstated tolerance cancels), cannot be
trusted to improve on the table: on simulated cells fits above it were as often worse than the
nominal table as better, those below it better (``benchmarks/mistakes.py``)."""


def nominal_rmse(model: MeasurementModel, cal: Calibration, q: np.ndarray) -> float:
    """The nominal table's expected workspace error [mm] as the parameters' priors (the
    manufacturing tolerance) predict it over configurations ``q`` [rad], as a calibration's is."""
    sigma = model.prior_sigma()[cal.robot_index]
    cov = np.diag(np.where(np.isfinite(sigma), sigma, 0.0) ** 2)
    modes = workspace_error_modes(
        dh_table(model.x0), model.tcp_in_flange(model.x0), q, cov, model.terms, model.tool_mask.any()
    )
    return predicted_workspace_rmse(modes)


def _t(v) -> tuple[float, float, float]:
    return tuple(round(float(c), 4) for c in v)


def _v(v) -> str:
    return "[" + ", ".join(f"{c + 0.0:.2f}" for c in np.round(v, 2)) + "]"
