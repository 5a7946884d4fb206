"""What a session that ends with targets left says to do next, where the running calibration's
own correction (``station.acquire.targets``) does not reach them.

- **Before the model is determined** nothing corrects a target the robot lands off the edge, and
  the samples on the edge may be too few to calibrate: the dial gate (``[session] dial_range_mm``)
  is widened to take what the dial read at the rejected targets. That is safe: the dial's reading
  bounds how far the tool sat from the edge (contract: ``p_TCP - dial_mm * dial_axis`` lies on the
  line, or within ``|dial_mm|`` of it without an axis), so a row off the edge keeps an exact line
  residual, and its drawstring reading does not depend on the edge at all. The program run again
  with ``--resume`` then measures them, and once the model is determined the running calibration
  corrects the later targets onto the edge (the target channel), or the offline second pass does.
- **Without a target channel**, a determined model corrects the targets left offline: calibrate,
  then ``station program PLAN --robot R --table CORRECTED.toml`` writes the plan's program corrected,
  run with ``--resume`` (the targets measured already are skipped).
"""

from __future__ import annotations

import math

import numpy as np

GATE_MARGIN_MM = 0.5
"""How far beyond the largest reading at a rejected target the widened gate reaches (the later
targets of the same line miss by about as much)."""


def widened_gate(readings_mm) -> float | None:
    """The half-width [mm] of a dial gate that takes every finite reading of ``readings_mm`` with
    ``GATE_MARGIN_MM`` to spare, in half millimetres; None without one (only out-of-range replies)."""
    finite = [abs(r) for r in readings_mm if math.isfinite(r)]
    if not finite:
        return None
    return math.ceil(2.0 * (max(finite) + GATE_MARGIN_MM)) / 2.0


def gate_advice(off_edge: dict[int, float], model: str, config: str, resume: str, then: str) -> str | None:
    """The procedure for targets rejected off the edge before the model is determined: ``off_edge``
    maps each such target id to what the dial read there (NaN: out of range), ``model`` says how far
    the model is from determined, ``config`` names the station config, ``resume`` the command that
    continues, ``then`` how the later targets get corrected. None where the dial read no number
    (out of range): a gate cannot take what the dial cannot read."""
    ids = sorted(off_edge)
    read = np.array([off_edge[t] for t in ids], float)
    if (half := widened_gate(read)) is None:
        return None
    where = f"target{'s' if len(ids) > 1 else ''} {_listed(ids)}"
    finite = read[np.isfinite(read)]
    seen = f"{finite.min():+.3f} .. {finite.max():+.3f} mm" if len(finite) > 1 else f"{finite[0]:+.3f} mm"
    return (
        f"{model}, so nothing corrects the targets: widen the dial gate in {config}, [session] "
        f"dial_range_mm = [{-half:g}, {half:g}] (the dial read {seen} at {where}), and run the robot "
        f"program again with {resume}. Safe: the dial's reading bounds how far each capture sat from "
        f"the edge, so the rows stay exact; {then}"
    )


def offline_pass(plan: str, robot: str, folder: str, resume: str) -> str:
    """The offline second pass for the targets left: calibrate, a corrected program of them, resume."""
    return (
        f"calibrate what was measured (station calibrate {folder} --out CORRECTED.toml), write the "
        f"plan's program corrected by that table (station program {plan} --robot {robot} --table "
        f"CORRECTED.toml --session {folder} --format F --out F, F: your controller's: the targets "
        f"left first) and run it with {resume}: the targets measured already are skipped"
    )


def _listed(ids: list[int]) -> str:
    more = f" and {len(ids) - 10} more" if len(ids) > 10 else ""
    return ", ".join(map(str, ids[:10])) + more
