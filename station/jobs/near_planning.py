"""``station plan --near PROGRAM.csv`` behind the command line: ``station.jobs.planning``'s plan
plus gauge-line contacts near a program's poses (``calib.near``), so that the residual map is learnt
where the program works."""

from __future__ import annotations

import numpy as np

from calib.experiment import design_model, expected_modes
from calib.near import NEAR_DEG, NEAR_POSES, SITES, choose, chord_deg, covered, line_contacts, spread
from errors import InputError
from station.formats.plan import Plan
from station.formats.tables import RobotFile, SetupFile
from station.jobs.calibration import WORKSPACE_POSES, drawstring_setup
from station.jobs.planning import Design, contact_poses, design, placements, promise, robot_arrays


def near_design(
    robot: RobotFile,
    setup: SetupFile,
    program_q_deg: np.ndarray,
    where: str = "setup",
    *,
    n_near: int = NEAR_POSES,
    near_deg: float = NEAR_DEG,
    program_where: str = "the program",
    **options,
) -> Design:
    """``design``'s plan, which determines the table, plus ``n_near`` gauge-line contacts within
    ``near_deg`` [deg] (chord distance of joints 1-3) of the program's poses ``program_q_deg`` (P, 6)
    [deg, the model's joints], spread over them (``calib.near``): the residual map is then learnt
    where the program works. The promise is the whole plan's; ``options`` as ``design``'s. No contact
    that near is an ``InputError`` naming ``program_where``."""
    program_q = np.radians(np.asarray(program_q_deg, float))
    rng = np.random.default_rng(options.get("seed", 0))
    q, line = near_contacts(robot, setup, where, program_q, rng, near_deg, program_where)
    chosen = choose(q, program_q, n_near, near_deg)
    base = design(robot, setup, where, **options)
    q_plan = np.concatenate([np.radians(base.plan.q_deg), q[chosen]])
    line_plan = np.concatenate([base.plan.line, line[chosen]])
    dh, tool = robot_arrays(robot)
    limits = np.radians(robot.limits_deg())
    model = design_model(dh, tool, drawstring_setup(setup, where), q_plan, line_plan)
    workspace_q = rng.uniform(limits[:, 0], limits[:, 1], (WORKSPACE_POSES, 6))
    report = dict(base.report)
    promised = promise(expected_modes(model, workspace_q, report["readings"]))
    report["predicted"] = {**report["predicted"], "plan": promised}
    report["near"] = {
        "program": program_where,
        "program_poses": len(program_q),
        "near_deg": near_deg,
        "candidates": len(q),
        "poses": len(chosen),
        "covered": float(np.mean(covered(q_plan, program_q, near_deg))),
        "coverable": float(np.mean(covered(np.concatenate([q_plan, q]), program_q, near_deg))),
    }
    lines = placements(setup, where)
    approach = np.array([lines[int(k)][3] for k in line_plan])
    plan = Plan(np.arange(len(q_plan)), line_plan, np.degrees(q_plan), contact_poses(robot, q_plan), approach)
    return Design(plan, report)


def near_contacts(
    robot: RobotFile,
    setup: SetupFile,
    where: str,
    program_q: np.ndarray,
    rng: np.random.Generator,
    near_deg: float = NEAR_DEG,
    program_where: str = "the program",
) -> tuple[np.ndarray, np.ndarray]:
    """Contacts (M, 6) [rad] with every gauge line of ``setup`` within ``near_deg`` [deg] of the
    program's poses ``program_q`` (P, 6) [rad] (``calib.near.line_contacts``), and their line ids
    (M,); none is an ``InputError`` saying how near the nearest came."""
    dh, tool = robot_arrays(robot)
    limits = np.radians(robot.limits_deg())
    q, line, nearest = [], [], np.inf
    sites = program_q[spread(program_q, SITES)]
    for lid, ln in placements(setup, where).items():
        found, ok = line_contacts(dh, tool, limits, ln, sites, rng)
        distance = chord_deg(found[ok], program_q) if ok.any() else np.array([np.inf])
        nearest = min(nearest, float(distance.min()))
        q.append(found[ok][distance <= near_deg])
        line.append(np.full(len(q[-1]), lid))
    q, line = np.concatenate(q), np.concatenate(line)
    if not len(q):
        raise InputError(
            f"no gauge line within reach of the program's poses: the nearest contact {where}'s lines "
            f"allow is {nearest:.1f} deg (joints 1-3) from {program_where}'s poses, {near_deg:g} deg "
            "needed; place a gauge line where the program works"
        )
    return q, line
