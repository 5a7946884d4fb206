"""A simulated calibration cell: a true robot, gauge-block lines, a drawstring anchor, noisy instruments.

The truth is drawn here (the robot's errors, where the lines and the anchor are, the noise of every
reading); its geometry is computed with ``calib``'s kinematics (``calib.kinematics`` forward,
``calib.ik`` inverse), the one D-H implementation of the project. What checks that kinematics
independently is ``tests/unit/calib/test_kinematics.py``: the contract's reference pose, a second
formulation (elementary rotations and translations composed with scipy's ``Rotation``) on seeded
random tables and configurations, and the analytic Jacobians against finite differences.

Units as a person measures them: mm and degrees. The nominal robot is the shipped robot file
(``configs/robots/hsr_jr680.toml``, the paper's Table I; ``World.around``: any robot and cell, as
``station sim serve --robot R --setup S`` rehearses one); tables are in the robot file's and
``calib``'s column order (theta_deg, d_mm, a_mm, alpha_deg). The physics:

- the true robot is the nominal table plus errors of a machined, assembled arm (:data:`TOLERANCES`,
  their one statement): N(0, 0.15 deg) on each angle, N(0, 0.75 mm) on each length;
- each gauge-block line is a straight edge the tool touches; the operator's placement leaves the
  TCP off the edge along the dial axis by U(-0.3, 0.3) mm, which the dial reads;
- the instruments (:class:`Noise`, the one statement of the simulator's noise): the drawstring
  reads ``|p_TCP - anchor| - length_offset`` with N(0, 0.02 mm) noise and 1 um resolution; the dial
  N(0, 0.002 mm), 1 um; the controller's joint readings N(0, 0.0005 deg);
- a gross reading (cable slip, bumped probe) adds 2-5 mm, either sign, to the drawstring;
- optionally (``JointError``) the joints read other than the links turn: a compliance under gravity,
  a harmonic of the joint's angle, as ``calib.joint_terms`` models them;
- optionally (``sim_fixtures.unmodelled.Unmodelled``) a smooth error no table expresses (a joint's
  cyclic error, a sag with reach): the true TCP carries it in every reading, the joints read as ever.
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np

import configs
from calib import ik
from calib.joint_terms import JointTerms
from calib.kinematics import tcp_position
from calib.params import DH_KEYS, DH_NAMES, dh_from_degrees
from sim_fixtures.sources import Instrument
from sim_fixtures.unmodelled import Unmodelled

try:
    import tomllib
except ModuleNotFoundError:  # Python 3.10
    import tomli as tomllib

JR680_FILE = configs.path("robots/hsr_jr680.toml")
WORKING_POSE_DEG = np.array([0.0, -50.0, -20.0, 0.0, -90.0, 0.0])
IK_TOL = 1e-7  # mm (orientation: mm at a metre): a pose counts as reached below this error
IK_DAMPING = 1e-6  # Newton's damping: only keeps a step finite at an exact singularity
UNMODELLED_PASSES = 4  # re-aims of the IK at an unmodelled error: each gains ~3 orders (it is smooth)


@dataclass(frozen=True)
class Noise:
    """The simulator's instruments, the one place their noise is stated: noise (1 sigma) and
    resolution in mm and degrees, and the operator's placement off the edge (half width, mm).
    ``configs/setups/sim.toml`` states the same noise for the user (a test holds them equal)."""

    length_mm: float = 0.02
    length_resolution_mm: float = 0.001
    dial_mm: float = 0.002
    dial_resolution_mm: float = 0.001
    q_deg: float = 0.0005
    placement_mm: float = 0.3

    def drawstring(self, rng: np.random.Generator) -> Instrument:
        """The drawstring as a live device reads (``sim serve``), noise drawn from ``rng``."""
        return Instrument(self.length_mm, self.length_resolution_mm, rng)

    def dial(self, rng: np.random.Generator) -> Instrument:
        """The dial as a live device reads (``sim serve``), noise drawn from ``rng``."""
        return Instrument(self.dial_mm, self.dial_resolution_mm, rng)


@dataclass(frozen=True)
class GaugeLine:
    """A gauge-block edge: its centre [mm], unit direction, usable length [mm], the dial axis (unit,
    perpendicular to the edge) and the tool approach direction used there (unit, base frame)."""

    id: int
    centre: np.ndarray
    direction: np.ndarray
    length_mm: float
    dial_axis: np.ndarray
    approach: np.ndarray


def _unit(v) -> np.ndarray:
    v = np.asarray(v, float)
    return v / np.linalg.norm(v)


DEFAULT_LINES = (
    GaugeLine(
        0, np.array([-1100.0, 0.0, 150.0]), _unit([0, 1, 0]), 500.0, _unit([0, 0, 1]), _unit([0, 0, -1])
    ),
    GaugeLine(
        1, np.array([-1050.0, -450.0, 450.0]), _unit([1, 0, 0]), 400.0, _unit([0, 0, 1]), _unit([0, 0, -1])
    ),
    GaugeLine(
        2,
        np.array([-1000.0, 450.0, 600.0]),
        _unit([0.2, 0, 1]),
        400.0,
        _unit([1, 0, -0.2]),  # the dial reads positive against the approach, as on lines 0 and 1
        _unit([-1, 0, 0.2]),
    ),
)


@dataclass
class Robot:
    """A D-H robot: ``table_deg`` (6, 4) with rows (theta_deg, d_mm, a_mm, alpha_deg), TCP ``tool``
    [mm] in the flange frame, joint ``limits_deg`` (6, 2)."""

    table_deg: np.ndarray
    tool: np.ndarray
    limits_deg: np.ndarray

    @classmethod
    def from_file(cls, path: Path) -> Robot:
        """The robot of a robot model TOML (contract), e.g. ``JR680_FILE``; joint limits +-180 deg
        where the file gives none. Shipped files only: a user's file goes through ``station``'s
        validated reader."""
        with open(path, "rb") as f:
            doc = tomllib.load(f)
        joints = doc["joints"]
        return cls(
            np.array([[j[k] for k in DH_KEYS] for j in joints], float),
            np.array(doc.get("tool_mm", [0.0, 0.0, 0.0]), float),
            np.array([[j.get("q_min_deg", -180.0), j.get("q_max_deg", 180.0)] for j in joints], float),
        )

    @property
    def dh(self) -> np.ndarray:
        """The table in ``calib``'s internal units (rad, mm)."""
        return dh_from_degrees(self.table_deg)

    def pose(self, q_deg) -> np.ndarray:
        """Base-frame pose (4, 4) of the TCP for one configuration [deg]: the flange's rotation,
        the tool point's position [mm]."""
        p, rot = ik.tool_frames(self.dh, np.radians(np.asarray(q_deg, float))[None], self.tool)
        pose = np.eye(4)
        pose[:3, :3], pose[:3, 3] = rot[0], p[0]
        return pose

    def tcp(self, q_deg) -> np.ndarray:
        """TCP positions [mm] for configurations (N, 6) or (6,) in degrees."""
        p = tcp_position(self.dh, np.radians(np.atleast_2d(q_deg)), self.tool)
        return p if np.ndim(q_deg) == 2 else p[0]

    def ik(
        self, targets: np.ndarray, seeds_deg: np.ndarray, iters: int = 60
    ) -> tuple[np.ndarray, np.ndarray]:
        """Joint angles [deg] (N, 6) reaching the TCP poses ``targets`` (N, 4, 4), by ``calib.ik``'s
        damped Newton from ``seeds_deg`` (N, 6), and which of them (N,) got within ``IK_TOL`` in
        ``iters`` iterations and inside the joint limits."""
        q, err = ik.solve(
            self.dh,
            self.tool,
            targets[:, :3, 3],
            targets[:, :3, :3],
            np.radians(seeds_deg),
            iterations=iters,
            damping=IK_DAMPING,
            tol=IK_TOL,
        )
        q_deg = np.degrees(q)
        inside = np.all((q_deg >= self.limits_deg[:, 0]) & (q_deg <= self.limits_deg[:, 1]), axis=1)
        return q_deg, (err < IK_TOL) & inside


def tool_pose(position, approach, roll_rad) -> np.ndarray:
    """A TCP pose whose z axis is ``approach``, rolled by ``roll_rad`` about it."""
    z = _unit(approach)
    helper = np.array([1.0, 0, 0]) if abs(z[0]) < 0.9 else np.array([0, 1.0, 0])
    x = _unit(np.cross(helper, z))
    y = np.cross(z, x)
    c, s = np.cos(roll_rad), np.sin(roll_rad)
    pose = np.eye(4)
    pose[:3, 0], pose[:3, 1], pose[:3, 2] = c * x + s * y, -s * x + c * y, z
    pose[:3, 3] = position
    return pose


def tilted(axis: np.ndarray, max_tilt_deg: float, rng: np.random.Generator) -> np.ndarray:
    """``axis`` tilted by up to ``max_tilt_deg`` towards a random perpendicular direction."""
    perp = _unit(np.cross(axis, rng.normal(size=3)))
    tilt = np.radians(rng.uniform(0.0, max_tilt_deg))
    return _unit(np.cos(tilt) * axis + np.sin(tilt) * perp)


@dataclass
class SampleSet:
    """What the station would record: joint readings [deg], drawstring [mm], dial [mm], line ids,
    plus the truth behind them (true joints, indices of the gross readings)."""

    q_deg: np.ndarray
    length_mm: np.ndarray
    dial_mm: np.ndarray
    line: np.ndarray
    q_true_deg: np.ndarray
    outliers: np.ndarray

    def __len__(self) -> int:
        return self.q_deg.shape[0]

    def to_csv(self, path) -> None:
        """Write as the contract's samples CSV."""
        header = "sample,line," + ",".join(f"q{i}_deg" for i in range(1, 7)) + ",length_mm,dial_mm"
        rows = np.column_stack([np.arange(len(self)), self.line, self.q_deg, self.length_mm, self.dial_mm])
        fmt = ["%d", "%d"] + ["%.6f"] * 6 + ["%.4f", "%.4f"]
        np.savetxt(path, rows, fmt=fmt, delimiter=",", header=header, comments="")


@dataclass(frozen=True)
class JointError:
    """Joints that read other than their links turn: ``terms`` (``calib.joint_terms.JointTerms``)
    with their true ``values`` (internal units)."""

    terms: JointTerms
    values: np.ndarray

    def readings_deg(self, q_link_deg: np.ndarray) -> np.ndarray:
        """What the joints read [deg] (N, 6) when the links stand at ``q_link_deg`` (N, 6): the
        reading ``q`` solves ``q + B(q) c = q_link`` (fixed point; the deflections are
        milliradians, so each pass gains three orders)."""
        q_link = np.radians(q_link_deg)
        q = q_link
        for _ in range(4):
            q = q_link - (self.terms.link_angles(q, self.values, self.terms.basis(q)) - q)
        return np.degrees(q)


@dataclass(frozen=True)
class Tolerances:
    """How far a true cell lies from what its files say, the one statement of it (1 sigma): each
    D-H angle [deg] and length [mm] of a machined, assembled arm, the drawstring's cable exit [mm]
    and offset [mm] from the factory's figures."""

    angle_deg: float = 0.15
    length_mm: float = 0.75
    anchor_mm: float = 5.0
    length_offset_mm: float = 2.0


TOLERANCES = Tolerances()


@dataclass(frozen=True)
class Placement:
    """A cell as a person measured it: the drawstring's ``anchor_mm`` and ``length_offset_mm``, the
    gauge ``lines`` where the setup file puts them, and how far each true edge lies from there
    (``line_sigma_mm``, 1 sigma per axis; 0: exactly there)."""

    anchor_mm: np.ndarray
    length_offset_mm: float
    lines: tuple[GaugeLine, ...]
    line_sigma_mm: float = 0.0


@dataclass
class World:
    """The true cell. Build one with ``World.create(seed)``."""

    nominal: Robot
    true: Robot
    anchor_mm: np.ndarray
    length_offset_mm: float
    lines: tuple[GaugeLine, ...]
    noise: Noise = field(default_factory=Noise)
    joint_error: JointError | None = None
    unmodelled: Unmodelled | None = None

    @classmethod
    def create(cls, seed: int = 0, n_lines: int = 3, noise: Noise | None = None) -> World:
        """A JR680 with random geometric errors, ``n_lines`` of the default gauge-block placements."""
        nominal = Robot.from_file(JR680_FILE)
        cell = Placement(np.array([-800.0, 600.0, -600.0]), 200.0, DEFAULT_LINES[:n_lines], 0.0)
        return cls.around(nominal, cell, seed, noise)

    @classmethod
    def around(cls, nominal: Robot, placement: Placement, seed: int = 0, noise: Noise | None = None) -> World:
        """Any robot and cell: the true robot drawn around ``nominal`` (``TOLERANCES``), the true
        anchor, offset and gauge lines around the ``placement`` a person measured."""
        rng = np.random.default_rng(seed)
        tol = TOLERANCES
        # drawn alpha, a, d, theta: the order every seeded world so far was drawn in
        sigmas = (tol.angle_deg, tol.length_mm, tol.length_mm, tol.angle_deg)
        alpha, a, d, theta = (rng.normal(0, s, 6) for s in sigmas)
        error = np.column_stack([theta, d, a, alpha])
        true = Robot(nominal.table_deg + error, nominal.tool.copy(), nominal.limits_deg.copy())
        anchor = placement.anchor_mm + rng.normal(0, tol.anchor_mm, 3)
        offset = placement.length_offset_mm + rng.normal(0, tol.length_offset_mm)
        lines = placement.lines
        if placement.line_sigma_mm > 0:  # drawn last: a world without it shares every other draw
            moved = rng.normal(0, placement.line_sigma_mm, (len(lines), 3))
            lines = tuple(replace(ln, centre=ln.centre + dp) for ln, dp in zip(lines, moved, strict=True))
        return cls(nominal, true, anchor, offset, lines, noise or Noise())

    def changed(self, offsets: dict[str, float]) -> World:
        """This cell after its robot changed (a bent link, a slipped encoder): ``offsets`` [mm, deg]
        by D-H parameter name (``{"J2.a_mm": 0.3}``) added to the true table."""
        table = self.true.table_deg.copy()
        for name, value in offsets.items():
            table.flat[DH_NAMES.index(name)] += value
        true = Robot(table, self.true.tool.copy(), self.true.limits_deg.copy())
        return replace(self, true=true)

    def rough_setup(self, rng: np.random.Generator) -> dict:
        """Setup values as a person would measure them: anchor to +-30 mm, offset to +-8 mm."""
        return {
            "anchor_mm": self.anchor_mm + rng.uniform(-30, 30, 3),
            "length_offset_mm": self.length_offset_mm + rng.uniform(-8, 8),
            "sigma_mm": self.noise.length_mm,
            "dial_sigma_mm": self.noise.dial_mm,
            "dial_axes": {ln.id: ln.dial_axis for ln in self.lines},
        }

    def true_tcp_mm(self, q_deg) -> np.ndarray:
        """Where the TCP truly is [mm, base frame] at joint readings (N, 6) or (6,) [deg]: the true
        table's, plus the ``unmodelled`` error where the cell has one (the truth the residual map
        is checked against)."""
        if self.unmodelled is None:
            return self.true.tcp(q_deg)
        q = np.radians(np.atleast_2d(np.asarray(q_deg, float)))
        p = self.unmodelled.tcp_mm(self.true.dh, q, self.true.tool)
        return p if np.ndim(q_deg) == 2 else p[0]

    def true_length_mm(self, q_deg) -> np.ndarray:
        """Noise-free drawstring reading [mm] for configurations (N, 6) [deg]."""
        return (
            np.linalg.norm(self.true_tcp_mm(np.atleast_2d(q_deg)) - self.anchor_mm, axis=1)
            - self.length_offset_mm
        )

    def true_dial_mm(self, q_deg, line_ids) -> np.ndarray:
        """Noise-free dial reading [mm]: the TCP's offset from its line along the dial axis."""
        p = self.true_tcp_mm(np.atleast_2d(q_deg))
        by_id = {ln.id: ln for ln in self.lines}
        return np.array(
            [
                (pi - by_id[int(k)].centre) @ by_id[int(k)].dial_axis
                for pi, k in zip(p, np.atleast_1d(line_ids), strict=True)
            ]
        )

    def line_configurations(self, n_per_line: int, rng: np.random.Generator, max_tilt_deg: float = 25.0):
        """True joint configurations [deg] (N, 6) and line ids (N,) whose TRUE TCPs touch the lines,
        evenly spread along each edge, each with a random tool tilt and roll."""
        q_all, ids = [], []
        for ln in self.lines:
            seed = self._seed_for(ln)
            for s in np.linspace(-0.5, 0.5, n_per_line) * ln.length_mm:
                reached = False
                while not reached:
                    offset = rng.uniform(-1, 1) * self.noise.placement_mm
                    pos = ln.centre + s * ln.direction + offset * ln.dial_axis
                    pose = tool_pose(pos, tilted(ln.approach, max_tilt_deg, rng), rng.uniform(-np.pi, np.pi))
                    (q,), (reached,) = self.true_ik(pose[None], seed[None])
                q_all.append(q)
                ids.append(ln.id)
                seed = q
        return np.array(q_all), np.array(ids)

    def sweep_configurations(
        self,
        n_per_line: int,
        passes_per_line: int,
        rng: np.random.Generator,
        max_tilt_deg: float = 25.0,
        rounds: int = 1,
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """A sweep plan of true configurations [deg] (N, 6) whose TRUE TCPs touch the lines, with
        line ids (N,) and pass ids (N,): ``n_per_line`` waypoints evenly along each edge, split into
        ``passes_per_line`` passes, the tool's tilt and roll turning steadily from a random one at a
        pass's start to another at its end (a sweep that keeps contact, orientation varying); every
        line swept ``rounds`` times, each with orientations of its own."""
        q_all, ids, passes = [], [], []
        for ln in [ln for _ in range(rounds) for ln in self.lines]:
            seed = self._seed_for(ln)
            spots = np.array_split(np.linspace(-0.5, 0.5, n_per_line) * ln.length_mm, passes_per_line)
            for chunk in spots:
                pid = max(passes, default=-1) + 1
                ends = [tilted(ln.approach, max_tilt_deg, rng) for _ in range(2)]
                rolls = rng.uniform(-0.3, 0.3, 2)
                for k, w in enumerate(np.linspace(0.0, 1.0, len(chunk))):
                    pos = ln.centre + chunk[k] * ln.direction
                    pos = pos + rng.uniform(-1, 1) * self.noise.placement_mm * ln.dial_axis
                    approach = _unit((1 - w) * ends[0] + w * ends[1])
                    pose = tool_pose(pos, approach, (1 - w) * rolls[0] + w * rolls[1])
                    (q,), (reached,) = self.true.ik(pose[None], seed[None])
                    if reached:
                        q_all.append(q)
                        ids.append(ln.id)
                        passes.append(pid)
                        seed = q
        return np.array(q_all), np.array(ids), np.array(passes)

    def touch_lines(self, q_plan_deg, line_ids, rng: np.random.Generator, every: bool = False):
        """Where the tool really goes for planned configurations (N, 6) [deg]: the pose the true
        robot reaches there, moved (orientation kept) onto its true line, off it along the dial axis
        by the operator's placement. Returns true configurations [deg] and the line ids of those
        reached (a target pushed out of the joint limits is skipped, as an operator would; ``every``:
        all configurations, and which (N,) the true robot reaches)."""

        def placed(ln: GaugeLine, rel: np.ndarray) -> np.ndarray:
            return rng.uniform(-1, 1) * self.noise.placement_mm * ln.dial_axis

        return self._onto_lines(q_plan_deg, line_ids, placed, every)

    def land(self, q_plan_deg, line_ids) -> tuple[np.ndarray, np.ndarray]:
        """Where a program commanding configurations (N, 6) [deg] really touches: the pose the true
        robot reaches there, brought across onto its true line (the edge guides the tool across it)
        but left off it along the dial axis by the robot's own miss, which the dial reads. Returns
        true configurations [deg] and the line ids of those reached."""
        q_true, reached = self.landing(q_plan_deg, line_ids)
        return q_true[reached], np.asarray(line_ids, int)[reached]

    def landing(self, q_plan_deg, line_ids) -> tuple[np.ndarray, np.ndarray]:
        """:meth:`land` for every commanded configuration: the true configurations (N, 6) [deg] and
        which of them (N,) the true robot reaches."""
        return self._onto_lines(
            q_plan_deg, line_ids, lambda ln, rel: (rel @ ln.dial_axis) * ln.dial_axis, True
        )

    def _onto_lines(self, q_plan_deg, line_ids, off, every: bool = False) -> tuple[np.ndarray, np.ndarray]:
        """The true robot's poses at planned configurations (N, 6) [deg] moved onto their true lines
        (orientation kept), then by ``off(line, pose - centre)`` [mm]; the true configurations [deg]
        and the line ids of those the true robot reaches (``every``: all configurations, and which
        (N,) it reaches)."""
        by_id = {ln.id: ln for ln in self.lines}
        q_plan = np.atleast_2d(q_plan_deg)
        targets = np.empty((len(q_plan), 4, 4))
        for k, (q, lid) in enumerate(zip(q_plan, line_ids, strict=True)):
            ln = by_id[int(lid)]
            targets[k] = self.true.pose(q)
            if self.unmodelled is not None:
                targets[k, :3, 3] = self.true_tcp_mm(q)
            rel = targets[k, :3, 3] - ln.centre
            targets[k, :3, 3] = ln.centre + (rel @ ln.direction) * ln.direction + off(ln, rel)
        q_true, reached = self.true_ik(targets, q_plan)
        if every:
            return q_true, reached
        return q_true[reached].reshape(-1, 6), np.asarray(line_ids, int)[reached]

    def true_ik(self, targets: np.ndarray, seeds_deg: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """The joint readings [deg] (N, 6) at which the true TCP (``true_tcp_mm``) stands at the
        positions of ``targets`` (N, 4, 4), the flange at their orientations, and which (N,) the true
        robot reaches (``Robot.ik``). The ``unmodelled`` error (a fraction of a mm, smooth) is taken
        out by re-aiming the table's TCP at the target less that error, ``UNMODELLED_PASSES`` times."""
        q, reached = self.true.ik(targets, seeds_deg)
        aimed = np.array(targets, float)
        for _ in range(UNMODELLED_PASSES if self.unmodelled is not None else 0):
            aimed[:, :3, 3] = targets[:, :3, 3] - (self.true_tcp_mm(q) - self.true.tcp(q))
            q, reached = self.true.ik(aimed, q)
        return q, reached

    def _seed_for(self, ln: GaugeLine) -> np.ndarray:
        """A configuration at the line's centre with the tool along its approach direction: of the
        IK solutions from 40 seeded restarts, the one closest to the working pose."""
        restarts = np.random.default_rng(ln.id).uniform(*self.true.limits_deg.T, (40, 6))
        targets = np.repeat(tool_pose(ln.centre, ln.approach, 0.0)[None], len(restarts), axis=0)
        q, reached = self.true.ik(targets, restarts, iters=200)
        if not reached.any():
            raise RuntimeError(f"gauge line {ln.id} is out of the robot's reach")
        found = q[reached]
        return found[np.argmin(np.linalg.norm(found - WORKING_POSE_DEG, axis=1))]

    def measure(
        self, q_true_deg, line_ids, rng, outlier_fraction: float = 0.0, readings: int = 1
    ) -> SampleSet:
        """Instrument readings at true configurations, with noise, resolution and gross readings;
        ``readings`` (K) drawstring and dial readings per capture, each quantised as the device shows
        it, averaged as ``station sample`` does (the joints read once: the simulated controller's are
        steady, exact where ``Noise.q_deg`` is 0). A gross reading shifts a whole capture."""
        nz = self.noise
        n = q_true_deg.shape[0]
        length = self.true_length_mm(q_true_deg) + rng.normal(0, nz.length_mm, (readings, n))
        dial = self.true_dial_mm(q_true_deg, line_ids) + rng.normal(0, nz.dial_mm, (readings, n))
        exact = q_true_deg if self.joint_error is None else self.joint_error.readings_deg(q_true_deg)
        q_read = exact + rng.normal(0, nz.q_deg, q_true_deg.shape)
        # Gross readings drawn last, so a set with them shares every other draw with one without.
        outliers = np.sort(rng.choice(n, size=int(round(outlier_fraction * n)), replace=False))
        length[:, outliers] += rng.choice([-1.0, 1.0], outliers.size) * rng.uniform(2.0, 5.0, outliers.size)
        return SampleSet(
            q_deg=q_read,
            length_mm=_quantise(length, nz.length_resolution_mm).mean(axis=0),
            dial_mm=_quantise(dial, nz.dial_resolution_mm).mean(axis=0),
            line=np.asarray(line_ids),
            q_true_deg=q_true_deg,
            outliers=outliers,
        )

    def sample_set(
        self, n_per_line: int, rng: np.random.Generator, outlier_fraction: float = 0.0, readings: int = 1
    ) -> SampleSet:
        """A measured session: ``n_per_line`` samples on every line, ``readings`` averaged per capture."""
        q, ids = self.line_configurations(n_per_line, rng)
        return self.measure(q, ids, rng, outlier_fraction, readings)

    def random_configurations(self, n: int, rng: np.random.Generator) -> np.ndarray:
        """Configurations [deg] (n, 6) uniform within the joint limits (the workspace test set)."""
        lim = self.nominal.limits_deg
        return rng.uniform(lim[:, 0], lim[:, 1], (n, 6))


def _quantise(x: np.ndarray, step: float) -> np.ndarray:
    return np.round(x / step) * step
