"""``station plan`` behind the command line: candidate configurations on every gauge line of the
setup, MCS to choose the plan, and what each choice promises over the workspace.

All promises are expectations from the nominal robot and the instruments' stated noise
(``calib.experiment``), averaged over the readings a capture takes (``[session] readings``): before
anything is measured, nothing else is known. A session then predicts from the noise its fit finds:
lower where the instruments read better than stated.
"""

from __future__ import annotations

import dataclasses
import itertools
from dataclasses import dataclass

import numpy as np

from calib import ik
from calib.accuracy import predicted_workspace_rmse, workspace_rmse_bound
from calib.calibrate import setup_unknowns
from calib.conventions import dh_from_mdh
from calib.experiment import design_model, expected_modes, line_candidates
from calib.kinematics import ALPHA, N_DH, A
from calib.params import dh_from_degrees
from calib.verification import sensitive_rows
from errors import InputError, ParameterError
from station.formats.plan import Plan
from station.formats.tables import RobotFile, SetupCell, SetupFile
from station.jobs.calibration import WORKSPACE_POSES, drawstring_setup, select_measurements, unknowns

NEXT_CONFIGURATIONS = 12
"""Random well-conditioned poses whose TCP and tool axis seed the candidate next placements."""

PLAN_SIZE = (
    "{n} reachable candidates for {unknowns} unknowns: the plan must lie between the two; "
    "raise {per_line} or change {n_select}"
)
"""Too few candidates or a plan size out of range; ``{per_line}``, ``{n_select}`` are parameters."""


@dataclass(frozen=True)
class NextPlacement:
    """A further gauge line: through ``point_mm`` [mm] along unit ``direction``, the tool meeting it
    along ``approach``; the workspace error [mm] predicted with the present configurations alone
    and with the line added (both from the stated noise, one reading per configuration)."""

    point_mm: np.ndarray
    direction: np.ndarray
    approach: np.ndarray
    present_rmse_mm: float
    predicted_rmse_mm: float

    @property
    def gain(self) -> float:
        """The fraction of the predicted workspace error the new line takes away."""
        return 1.0 - self.predicted_rmse_mm / self.present_rmse_mm


@dataclass
class Design:
    """The chosen ``plan`` and the ``report`` (JSON-ready) of how it was chosen and what it promises."""

    plan: Plan
    report: dict


Line = tuple[np.ndarray, np.ndarray, float, np.ndarray]


def placements(setup: SetupFile, where: str) -> dict[int, Line]:
    """Each ``[[lines]]`` entry as (point [mm], unit direction, length [mm], unit approach); the
    approach defaults to pressing against the dial (minus its axis)."""
    if not setup.lines:
        raise InputError(f"{where}: no [[lines]]: station plan needs each gauge line's rough placement")
    out = {}
    for ln in setup.lines:
        name = f"{where}: [[lines]] id {ln.id}"
        if ln.point_mm is None or ln.direction is None:
            raise InputError(f"{name}: missing point_mm or direction (needed to plan measurements)")
        approach = ln.approach or ([-v for v in ln.dial_axis] if ln.dial_axis else None)
        if approach is None:
            raise InputError(f"{name}: missing approach (or dial_axis): which way the tool points")
        direction, approach = _unit(ln.direction, f"{name}: direction"), _unit(approach, f"{name}: approach")
        if abs(direction @ approach) > 0.9:
            raise InputError(f"{name}: approach runs along the line; the tool must meet the edge across it")
        out[ln.id] = (np.array(ln.point_mm, float), direction, ln.length_mm, approach)
    return out


def design(
    robot: RobotFile,
    setup: SetupFile,
    where: str = "setup",
    *,
    per_line: int = 100,
    n_select: int | None = None,
    seed: int = 0,
    suggest: bool = True,
    readings: int = 1,
    robot_where: str = "the robot file",
    progress=lambda message: None,
) -> Design:
    """Candidates on every line, the MCS plan, its promise next to all candidates', every subset
    of the lines, and (``suggest``) the best next line placements; every promise with ``readings``
    readings averaged per capture. A line the arm cannot reach (under 4 points) is refused with its
    likely cause: a robot file in the wrong convention (``convention_cause``; ``robot_where`` names
    the file), else as ``unreachable_cause`` finds."""
    lines = placements(setup, where)
    ds_setup = drawstring_setup(setup, where)
    dh, tool = robot_arrays(robot)
    limits = np.radians(robot.limits_deg())
    rng = np.random.default_rng(seed)
    q_line = {}
    for lid, line in lines.items():
        progress(f"candidates on line {lid}")
        q, ok = line_candidates(dh, tool, limits, line, per_line, rng)
        found = f"{where}: [[lines]] id {lid}: only {int(ok.sum())} of {per_line} points reachable"
        if ok.sum() < 4:
            cause = convention_cause(robot, robot_where, line) or unreachable_cause(
                dh, tool, limits, line, rng
            )
            raise InputError(f"{found} within the joint limits away from singularities; {cause}")
        q_line[lid] = q[ok]
    q_all = np.concatenate(list(q_line.values()))
    line_all = np.concatenate([np.full(len(q), lid) for lid, q in q_line.items()])
    model = design_model(dh, tool, ds_setup, q_all, line_all)
    needed = unknowns(model)
    if len(q_all) <= needed or (n_select is not None and not needed <= n_select <= len(q_all)):
        asked = "" if n_select is None else "{n_select} {value}: "
        raise ParameterError(asked + PLAN_SIZE, value=n_select, n=len(q_all), unknowns=needed)
    progress("selecting configurations (MCS)")
    mcs = select_measurements(model, n_select)
    rows = np.sort(mcs.selection.rows)
    workspace_q = rng.uniform(limits[:, 0], limits[:, 1], (WORKSPACE_POSES, 6))
    plan_modes = expected_modes(model.with_samples(model.samples.subset(rows)), workspace_q, readings)
    all_modes = expected_modes(model, workspace_q, readings)
    report = {
        "readings": readings,
        "candidates": {str(lid): len(q) for lid, q in q_line.items()},
        "selection": {
            "n": int(len(rows)),
            "index": "O1",
            "value": float(mcs.selection.value),
            "curve": {"n": mcs.sizes.tolist(), "O1": mcs.curve.tolist()},
        },
        "predicted": {"plan": promise(plan_modes), "all_candidates": promise(all_modes)},
        "placements": [
            {
                "lines": [int(i) for i in subset],
                **promise(expected_modes(_on(model, line_all, subset), workspace_q, readings)),
            }
            for subset in _subsets(list(q_line))
        ],
        "next": [],
    }
    if suggest:
        progress("trying further gauge-line placements")
        report["next"] = _next_placements(
            dh,
            tool,
            limits,
            lines,
            q_all,
            line_all,
            ds_setup,
            workspace_q,
            rng,
            readings=readings,
            cell=setup.cell,
        )
    approach = np.array([lines[int(lid)][3] for lid in line_all[rows]])
    plan = Plan(
        np.arange(len(rows)),
        line_all[rows],
        np.degrees(q_all[rows]),
        contact_poses(robot, q_all[rows]),
        approach,
    )
    return Design(plan, report)


TRIAL_POINTS = 20
"""Points on a line tried for each other reading of the robot file (``convention_cause``)."""


def convention_cause(robot: RobotFile, robot_where: str, line: Line) -> str | None:
    """The likely convention mistake of a robot file whose arm barely reaches ``line``: the first
    other reading of its table (``other_readings``) that reaches at least half of ``TRIAL_POINTS``
    points on it, said with the fix; None if none does. Its own random draws: a plan stays as it was."""
    tool, limits = np.asarray(robot.tool_mm, float), np.radians(robot.limits_deg())
    rng = np.random.default_rng(0)
    for table, fix in other_readings(robot, robot_where):
        _, ok = line_candidates(dh_from_degrees(table), tool, limits, line, TRIAL_POINTS, rng)
        if ok.sum() >= TRIAL_POINTS / 2:
            return fix.format(n=int(ok.sum()), of=TRIAL_POINTS)
    return None


def other_readings(robot: RobotFile, where: str) -> list[tuple[np.ndarray, str]]:
    """Other standard tables (6, 4) [deg, mm] the file's numbers may have meant, each with the
    sentence naming that mistake and its fix (``{n}`` of ``{of}`` points reached): modified numbers
    under ``dh`` (or under no ``convention``: the default is ``dh``), standard ones under ``mdh``,
    and a standard table whose row 1 twist (usually +-90 deg) was zeroed as a modified table's."""
    table = robot.file_table_deg()
    zeroed = table[0, A] == 0.0 and table[0, ALPHA] == 0.0
    out = []
    if robot.convention == "dh" and zeroed:
        given = "convention" in robot.model_fields_set
        said = 'it says convention = "dh"' if given else 'it gives no convention: the default is "dh"'
        out.append((dh_from_mdh(table), MISTAKES["mdh"].format(where=where, said=said)))
    if robot.convention == "mdh":
        out.append((table, MISTAKES["dh"].format(where=where)))
    if zeroed:
        fix = 'set convention = "dh"' if robot.convention == "mdh" else 'keep convention = "dh"'
        for alpha in (-90.0, 90.0):
            twisted = table.copy()
            twisted[0, ALPHA] = alpha
            out.append((twisted, MISTAKES["zeroed"].format(where=where, alpha=alpha, fix=fix)))
    return out


MISTAKES = {
    "mdh": (
        'with convention = "mdh" {{n}} of {{of}} points are reachable: the table is likely modified D-H '
        '({said}); set convention = "mdh" in {where}'
    ),
    "dh": (
        'with convention = "dh" {{n}} of {{of}} points are reachable: the table is likely standard D-H; '
        'set convention = "dh" in {where}'
    ),
    "zeroed": (
        "with joints.0 alpha_deg = {alpha:g} {{n}} of {{of}} points are reachable: the table is likely "
        "standard D-H with row 1's twist and offset zeroed as a modified table's; restore row 1's "
        "alpha_deg and a_mm from the data sheet and {fix} in {where}"
    ),
}
"""The convention mistakes ``other_readings`` tries, each with its fix."""


def unreachable_cause(dh: np.ndarray, tool: np.ndarray, limits: np.ndarray, line: Line, rng) -> str:
    """The likely cause of a gauge line the arm cannot touch: beyond its reach (a wrong point_mm or
    robot file), an approach pointing the wrong way (reachable when flipped), else its placement."""
    point, direction, length, approach = line
    reach = float(np.abs(dh[:, 1:3]).sum() + np.linalg.norm(tool))
    if np.linalg.norm(point) - length / 2 > reach:
        return (
            f"point_mm lies {np.linalg.norm(point):.0f} mm from the base, beyond the arm's reach "
            f"({reach:.0f} mm by the robot file): a wrong point_mm or robot file"
        )
    _, flipped = line_candidates(dh, tool, limits, (point, direction, length, -approach), 20, rng)
    if flipped.sum() >= 4:
        a = vector_text(0.0 - approach, 2)
        return (
            f"with approach = {a} {int(flipped.sum())} of 20 points are reachable: the approach likely "
            "points the wrong way (it is the way the tool points as it meets the edge)"
        )
    return "move the gauge block"


def next_placement(
    robot: RobotFile, setup: SetupFile, q_deg: np.ndarray, line: np.ndarray, *, seed: int = 0
) -> NextPlacement | None:
    """The best further line placement for configurations ``q_deg`` (N, 6) [deg] measured on
    gauge lines ``line`` (N,) of ``setup`` (whose ``[[lines]]`` give each placement); None if no
    candidate line is reachable."""
    dh, tool = robot_arrays(robot)
    limits = np.radians(robot.limits_deg())
    rng = np.random.default_rng(seed)
    workspace_q = rng.uniform(limits[:, 0], limits[:, 1], (WORKSPACE_POSES, 6))
    on_line = np.asarray(line) >= 0
    q, line = np.radians(np.asarray(q_deg, float)[on_line]), np.asarray(line)[on_line]
    ds_setup = drawstring_setup(setup, "setup")
    lines = placements(setup, "setup")
    found = _next_placements(
        dh, tool, limits, lines, q, line, ds_setup, workspace_q, rng, keep=1, cell=setup.cell
    )
    if not found:
        return None
    present = promise(expected_modes(design_model(dh, tool, ds_setup, q, line), workspace_q))
    best = found[0]
    return NextPlacement(
        *(np.array(best[k]) for k in ("point_mm", "direction", "approach")),
        present["predicted_rmse_mm"],
        best["predicted_rmse_mm"],
    )


def robot_arrays(robot: RobotFile) -> tuple[np.ndarray, np.ndarray]:
    """The nominal table (6, 4) in internal units and the TCP [mm]."""
    return dh_from_degrees(robot.table_deg()), np.asarray(robot.tool_mm, float)


def contact_poses(robot: RobotFile, q: np.ndarray) -> np.ndarray:
    """The nominal model's TCP poses (N, 6) at configurations ``q`` (N, 6) [rad]: position [mm] and
    tool orientation as a rotation vector [deg] (``station.formats.plan.POSE_COLUMNS``)."""
    from scipy.spatial.transform import Rotation

    dh, tool = robot_arrays(robot)
    p, rot = ik.tool_frames(dh, q, tool)
    return np.column_stack([p, Rotation.from_matrix(rot).as_rotvec(degrees=True)])


def summary(design_: Design) -> str:
    """What a person reads: the plan, its promise, and the answer to "is one line enough?"."""
    r = design_.report
    cand = ", ".join(f"line {k}: {v}" for k, v in r["candidates"].items())
    plan, everything = r["predicted"]["plan"], r["predicted"]["all_candidates"]
    out = [
        f"reachable candidates: {cand}",
        f"O1 flattens at N = {r['selection']['n']}; chose {r['selection']['n']} by simulated annealing",
        f"predicted workspace error (RMS over random poses, after a base re-fit), from the setup's "
        f"stated noise with {_readings(r['readings'])} (a session predicts from the noise its fit "
        "finds: lower where the instruments read better than stated):",
        f"  plan ({len(design_.plan)} poses)  {_fmt(plan)}",
        f"  all {sum(r['candidates'].values())} candidates  {_fmt(everything)}",
        "gauge-line placements (all candidates on the lines named):",
    ]
    out += [f"  lines {p['lines']}  {_fmt(p)}" for p in r["placements"]]
    if "near" in r:
        n = r["near"]
        out.append(
            f"near {n['program']}: {n['poses']} of {n['candidates']} contacts within {n['near_deg']:g} deg "
            f"(joints 1-3) of its {n['program_poses']} poses added to the plan; {100 * n['covered']:.0f} % "
            f"of its poses have a planned pose that near (a contact: {100 * n['coverable']:.0f} %)"
        )
    for k, nxt in enumerate(r["next"][:3]):
        lead = "next placement" if k == 0 else "           or"
        out.append(
            f"{lead}: point {vector_text(nxt['point_mm'], 0)} mm, "
            f"direction {vector_text(nxt['direction'], 2)}, "
            f"tool approach {vector_text(nxt['approach'], 2)} -> {_fmt(nxt)} with the present lines"
        )
    return "\n".join(out)


def _readings(k: int) -> str:
    """How the promise takes the captures: ``5 readings averaged per capture``."""
    return "single readings" if k == 1 else f"{k} readings averaged per capture"


def promise(modes: np.ndarray) -> dict:
    return {
        "predicted_rmse_mm": predicted_workspace_rmse(modes),
        "predicted_rmse_95_mm": workspace_rmse_bound(modes, 0.95),
    }


def _on(model, line_all: np.ndarray, subset) -> object:
    return model.with_samples(model.samples.subset(np.flatnonzero(np.isin(line_all, subset))))


def _subsets(ids: list[int], most: int = 7) -> list[tuple[int, ...]]:
    """Non-empty subsets of the line ids, singles first, at most ``most`` of them."""
    return [s for k in range(1, len(ids) + 1) for s in itertools.combinations(ids, k)][:most]


def _next_placements(
    dh,
    tool,
    limits,
    lines,
    q_all,
    line_all,
    ds_setup,
    workspace_q,
    rng,
    keep: int = 3,
    readings: int = 1,
    cell: SetupCell | None = None,
):
    """Candidate further lines ranked by the predicted workspace error of all lines together:
    through the TCP of random well-conditioned poses in the present lines' working area (their
    height range, +-300 mm; their distance from the base axis, +-300 mm), along each base axis
    across the tool, the tool meeting the edge as in that pose; only those the setup's ``cell``
    allows (:func:`allowed`)."""
    new_id = max(lines) + 1
    centres = np.array([p for p, *_ in lines.values()])
    z_range = centres[:, 2].min() - 300.0, centres[:, 2].max() + 300.0
    radius = np.hypot(centres[:, 0], centres[:, 1])
    r_range = radius.min() - 300.0, radius.max() + 300.0
    q = rng.uniform(limits[:, 0], limits[:, 1], (2000, 6))
    p, rot = ik.tool_frames(dh, q, tool)
    r = np.hypot(p[:, 0], p[:, 1])
    ok = (
        (p[:, 2] >= z_range[0])
        & (p[:, 2] <= z_range[1])
        & (r >= r_range[0])
        & (r <= r_range[1])
        & (ik.conditioning(dh, q, tool) > 0.1)
    )
    found, seeds = [], 0
    for i in np.flatnonzero(ok):
        approach = rot[i, :, 2]
        across = [
            (p[i], direction, 400.0, approach)
            for direction in np.eye(3)
            if abs(direction @ approach) <= 0.7 and allowed(cell, p[i], direction, 400.0, approach)
        ]
        if not across:
            continue
        seeds += 1
        if seeds > NEXT_CONFIGURATIONS:
            break
        for line in across:
            direction = line[1]
            q_new, reached = line_candidates(dh, tool, limits, line, 30, rng)
            if reached.sum() < 20:
                continue
            dial = -(approach - (approach @ direction) * direction)
            setup = dataclasses.replace(
                ds_setup, dial_axis={**ds_setup.dial_axis, new_id: dial / np.linalg.norm(dial)}
            )
            model = design_model(
                dh,
                tool,
                setup,
                np.concatenate([q_all, q_new[reached]]),
                np.concatenate([line_all, np.full(int(reached.sum()), new_id)]),
            )
            found.append(
                {
                    "point_mm": p[i].tolist(),
                    "direction": direction.tolist(),
                    "approach": approach.tolist(),
                    "length_mm": 400.0,
                    **promise(expected_modes(model, workspace_q, readings)),
                }
            )
    return sorted(found, key=lambda f: f["predicted_rmse_mm"])[:keep]


TOOL_MM = 150.0
"""How far back along its approach the tool is kept clear of the keep-out boxes [mm]."""


def allowed(cell: SetupCell | None, point, direction, length_mm: float, approach) -> bool:
    """Whether a line placement (``point`` its centre [mm], unit ``direction``, ``length_mm``, the
    tool's unit ``approach``) fits the ``cell``: the whole edge inside its reach box, the edge and
    the last ``TOOL_MM`` of the tool coming onto any point of it outside every keep-out box, the
    approach within the tilt allowed from straight down."""
    if cell is None:
        return True
    point, direction, approach = (np.asarray(v, float) for v in (point, direction, approach))
    edge = point + np.linspace(-0.5, 0.5, 21)[:, None] * length_mm * direction
    if cell.reach is not None and not cell.reach.contains(edge).all():
        return False
    tool = (edge[:, None, :] - np.linspace(0.0, TOOL_MM, 7)[None, :, None] * approach).reshape(-1, 3)
    if any(box.contains(tool).any() for box in cell.keep_out):
        return False
    if cell.max_tilt_from_down_deg is not None:
        tilt = np.degrees(np.arccos(np.clip(-approach[2], -1.0, 1.0)))
        return bool(tilt <= cell.max_tilt_from_down_deg)
    return True


def _fmt(promise: dict) -> str:
    return f"{promise['predicted_rmse_mm']:.3f} mm (95 %: below {promise['predicted_rmse_95_mm']:.3f} mm)"


def vector_text(v, digits: int) -> str:
    """A vector as a person reads it: ``[1.00, 0.00, 0.00]``."""
    return "[" + ", ".join(f"{x:.{digits}f}" for x in v) + "]"


def _unit(v, what: str) -> np.ndarray:
    v = np.asarray(v, float)
    n = np.linalg.norm(v)
    if not np.isfinite(n) or n < 1e-9:
        raise InputError(f"{what}: {list(v)} is not a direction")
    return v / n


VERIFY_POSES = 15
"""The default short plan: what one line gives in a few minutes (see the README for what it sees)."""
USUALLY_MOVE = ("theta_deg", "a_mm", "alpha_deg")
"""What a crash or wear changes: a joint's zero (an encoder that slipped, a joint re-zeroed) and a
link's length and twist (a bent link); a verification plan is chosen to see these."""


def verify_design(
    robot: RobotFile,
    setup: SetupFile,
    where: str = "setup",
    *,
    n_select: int = VERIFY_POSES,
    per_line: int = 100,
    seed: int = 0,
    robot_where: str = "the robot file",
) -> Design:
    """A short verification plan: ``n_select`` configurations on one gauge line, greedily the most
    informative (``calib.verification.sensitive_rows``) on ``USUALLY_MOVE`` with the line, anchor and
    offset fitted; of the setup's lines, the one whose plan sees them best."""
    lines = placements(setup, where)
    ds_setup = drawstring_setup(setup, where)
    dh, tool = robot_arrays(robot)
    limits = np.radians(robot.limits_deg())
    rng = np.random.default_rng(seed)
    best = None
    for lid, line in lines.items():
        q, ok = line_candidates(dh, tool, limits, line, per_line, rng)
        q = q[ok]
        if len(q) < n_select:
            continue
        model = design_model(dh, tool, ds_setup, q, np.full(len(q), lid))
        _, jac = model.residuals_and_jacobian(model.x0)
        gauges = model.gauges()
        moving = [k for k, name in enumerate(model.names[:N_DH]) if name.partition(".")[2] in USUALLY_MOVE]
        moving = [k for k in moving if model.names[k] not in gauges]
        setup_cols = setup_unknowns(model)
        prior = model.prior_sigma()[moving]
        rows, info = sensitive_rows(jac[:, setup_cols], jac[:, moving], model.rows, prior, n_select)
        if best is None or info > best[0]:
            best = (info, lid, q[np.sort(rows)])
    if best is None:
        causes = (convention_cause(robot, robot_where, line) for line in lines.values())
        cause = next((c for c in causes if c), "move the gauge block or plan fewer poses")
        raise InputError(
            f"{where}: no gauge line has {n_select} reachable points within the joint limits: {cause}"
        )
    _, lid, q = best
    approach = np.tile(lines[lid][3], (len(q), 1))
    plan = Plan(np.arange(len(q)), np.full(len(q), lid), np.degrees(q), contact_poses(robot, q), approach)
    report = {"verify": True, "line": int(lid), "n": len(q), "sensitive_to": list(USUALLY_MOVE)}
    return Design(plan, report)
