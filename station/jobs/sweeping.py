"""``station plan --sweep`` behind the command line: per gauge line, one or a few continuous passes
along the edge (``calib.sweep``), chosen among random ones by what their swept rows promise.

Candidates: from the roomiest configuration at each line's centre (furthest from the joint
limits), passes of ``PassShape.waypoints`` waypoints from one end of the edge to the other, the tool
tilted and rolled at random at each (as ``station plan``'s candidates), kept where every swept row
is reachable, inside the limits and away from singularities. Choice: greedily, a pass per line at a
time, the one whose rows (sampled at ``SCORE_HZ``, each weighing ``row_hz / SCORE_HZ`` rows) lower
the predicted workspace error of everything chosen most (``calib.experiment.expected_modes``, the
static planner's promise); then ``extra`` passes more, each the best of every line's candidates left.
The plan's rows are the waypoints; ``pass`` numbers the passes: a pass on each line, then a second
on each, ..., the extra ones among them so that no two consecutive passes share a line.
"""

from __future__ import annotations

import numpy as np

from calib.experiment import design_model, expected_modes
from calib.sweep import PassShape, SweepLimits, line_passes, swept_rows
from errors import InputError
from station.formats.plan import Plan
from station.formats.tables import RobotFile, SetupFile
from station.jobs.calibration import WORKSPACE_POSES, drawstring_setup
from station.jobs.planning import Design, contact_poses, placements, promise, robot_arrays

SHAPE = PassShape()
"""A pass: 6 waypoints end to end, the tool tilted up to 45 deg and rolled up to 90 deg at each."""
SWEEP = SweepLimits()
"""The speeds a sweep keeps to (``calib.sweep.SweepLimits``): 40 mm/s along the edge, 20 deg/s of
tool turn, rows recorded at 240 Hz."""
SCORE_HZ = 5.0
"""Rows a second the choice scores a pass by (each weighing ``row_hz / SCORE_HZ`` recorded rows)."""
CANDIDATES = 8
"""Random passes drawn per line to choose from."""
ROW_SLACK = 1e-6
"""Of a row: a pass whose duration times the row rate falls this short of a whole number (12.5 s
computed as 12.499999999999995) still counts its last row."""


def sweep_design(
    robot: RobotFile,
    setup: SetupFile,
    where: str = "setup",
    *,
    passes: int = 1,
    extra: int = 0,
    seed: int = 0,
    shape: PassShape = SHAPE,
    sweep: SweepLimits = SWEEP,
) -> Design:
    """``passes`` passes per gauge line of ``setup``, then ``extra`` more on whichever lines promise
    most (module docstring); InputError naming the line where too few valid passes were found."""
    lines = placements(setup, where)
    ds_setup = drawstring_setup(setup, where)
    dh, tool = robot_arrays(robot)
    limits = np.radians(robot.limits_deg())
    rng = np.random.default_rng(seed)
    pool = {}
    for lid, line in lines.items():
        found = line_passes(dh, tool, limits, line, shape, sweep, rng, max(CANDIDATES, passes + extra))
        if len(found) < passes:
            raise InputError(
                f"{where}: [[lines]] id {lid}: {len(found)} of {passes} passes along the edge stay "
                "within the joint limits away from singularities; move the gauge block, sweep fewer or let "
                f"the tool tilt more than {shape.max_tilt_deg:g} deg"
            )
        pool[lid] = [(q, swept_rows(dh, tool, limits, q, sweep, hz=SCORE_HZ).q) for q in found]
    workspace_q = rng.uniform(limits[:, 0], limits[:, 1], (WORKSPACE_POSES, 6))
    weight = max(1, round(sweep.row_hz / SCORE_HZ))

    def promised(chosen) -> dict:
        q = np.concatenate([rows for _, _, rows in chosen])
        line = np.concatenate([np.full(len(rows), lid) for lid, _, rows in chosen])
        return promise(expected_modes(design_model(dh, tool, ds_setup, q, line), workspace_q, weight))

    def best(chosen: list, lids) -> tuple:
        """The (line id, waypoints, rows) of ``lids``' candidates promising least beside ``chosen``."""
        scored = [
            (promised([*chosen, (lid, q, rows)])["predicted_rmse_mm"], lid, k)
            for lid in lids
            for k, (q, rows) in enumerate(pool[lid])
        ]
        _, lid, k = min(scored)
        return (lid, *pool[lid].pop(k))

    chosen: list = []
    for _ in range(passes):
        for lid in pool:
            chosen.append(best(chosen, [lid]))
    for _ in range(extra):
        if lids := [lid for lid in pool if pool[lid]]:
            chosen.append(best(chosen, lids))
    chosen = alternating(chosen)
    report = _report(dh, tool, limits, chosen, sweep, shape, promised(chosen))
    return Design(_plan(robot, lines, chosen), report)


def alternating(chosen: list) -> list:
    """``chosen`` passes (line id first) reordered so that no two in a row share a line where the
    counts allow: each next from the line with most passes left that is not the one just swept
    (ties: the lines' order), in the order chosen within a line."""
    left = {lid: [c for c in chosen if c[0] == lid] for lid in dict.fromkeys(c[0] for c in chosen)}
    out: list = []
    while any(left.values()):
        others = [lid for lid in left if left[lid] and (not out or lid != out[-1][0])]
        lid = max(others or [lid for lid in left if left[lid]], key=lambda k: len(left[k]))
        out.append(left[lid].pop(0))
    return out


def _plan(robot: RobotFile, lines: dict, chosen: list) -> Plan:
    """The waypoints of the ``chosen`` passes (line id, waypoints (K, 6) [rad], rows), in order."""
    q = np.concatenate([w for _, w, _ in chosen])
    line = np.concatenate([np.full(len(w), lid) for lid, w, _ in chosen])
    sweep_pass = np.concatenate([np.full(len(w), k) for k, (_, w, _) in enumerate(chosen)])
    approach = np.array([lines[int(lid)][3] for lid in line])
    return Plan(np.arange(len(q)), line, np.degrees(q), contact_poses(robot, q), approach, sweep_pass)


def _report(dh, tool, limits, chosen: list, sweep: SweepLimits, shape: PassShape, promised: dict) -> dict:
    """What the design promises, per pass its line, waypoints, seconds and rows; the speeds and
    turns it kept to."""
    passes = []
    for k, (lid, w, _) in enumerate(chosen):
        swept = swept_rows(dh, tool, limits, w, sweep, hz=1.0)
        passes.append(
            {
                "pass": k,
                "line": int(lid),
                "waypoints": len(w),
                "duration_s": swept.duration_s,
                "rows": int(swept.duration_s * sweep.row_hz + ROW_SLACK) + 1,
            }
        )
    return {
        "sweep": True,
        "limits": {
            "tcp_mm_s": sweep.tcp_mm_s,
            "turn_deg_s": sweep.turn_deg_s,
            "row_hz": sweep.row_hz,
            "max_tilt_deg": shape.max_tilt_deg,
            "max_roll_deg": shape.max_roll_deg,
        },
        "passes": passes,
        "swept_s": sum(p["duration_s"] for p in passes),
        "rows": sum(p["rows"] for p in passes),
        "predicted": {"plan": promised},
    }


def sweep_summary(design: Design) -> str:
    """What a person reads: each pass, the time swept, the rows and the promise."""
    r = design.report
    lim = r["limits"]
    out = [
        f"sweep plan: {len(r['passes'])} passes, the tool kept on the edge at up to {lim['tcp_mm_s']:g} "
        f"mm/s and {lim['turn_deg_s']:g} deg/s of turn, tilted up to {lim['max_tilt_deg']:g} deg and "
        f"rolled up to {lim['max_roll_deg']:g} deg, rows recorded at {lim['row_hz']:g} Hz:"
    ]
    out += [
        f"  pass {p['pass']}: line {p['line']}, {p['waypoints']} waypoints, {p['duration_s']:.1f} s, "
        f"{p['rows']} rows"
        for p in r["passes"]
    ]
    promise = r["predicted"]["plan"]
    out.append(
        f"swept {r['swept_s']:.1f} s ({r['rows']} rows; approaches, retreats and moves between passes "
        f"add to it); predicted workspace error {promise['predicted_rmse_mm']:.3f} mm (95 %: below "
        f"{promise['predicted_rmse_95_mm']:.3f} mm) from the setup's stated noise, single readings"
    )
    return "\n".join(out)
