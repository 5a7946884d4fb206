"""The contract's robot model and setup files (TOML), validated at load.

Every problem becomes an ``InputError`` whose one line names the file, the key, and what is wrong.
Values stay in the contract's units (mm, degrees).
"""

from __future__ import annotations

import hashlib
import io
from pathlib import Path
from typing import Annotated, Literal

import numpy as np
from pydantic import Field, NonNegativeFloat, model_validator

from calib.conventions import com_from_mdh, controller_joints, dh_from_mdh, dh_name, mdh_name, model_joints
from calib.joint_terms import TERM_KINDS, JointTerms, LinkMasses, Term
from calib.params import DH_KEYS, DH_NAMES, dh_from_degrees, display_factor
from calib.residual_map import ResidualMap, map_arrays, map_from_arrays
from calib.robot_model import RobotModel
from errors import InputError
from station.formats.base import (
    MAX_LENGTH_MM,
    Angle,
    Direction,
    Id,
    JointAngle,
    Length,
    PositiveLength,
    Sigma,
    Strict,
    Vec3,
    read_toml,
    validate,
)
from station.formats.units import check_positions_in_mm, check_robot_units

Mass = Annotated[float, Field(ge=0, le=1e4)]  # kg: a link or a payload, up to 10 t
Compliance = Annotated[float, Field(ge=-1e6, le=1e6)]  # urad/(N m)


class Joint(Strict):
    """One D-H joint; optionally its link's mass and centre of mass (in D-H frame i) for the
    gravity torques, and the joint-space terms a calibration identified (``calib.joint_terms``)."""

    alpha_deg: Angle
    a_mm: Length
    d_mm: Length
    theta_deg: Angle
    q_min_deg: JointAngle = -180.0
    q_max_deg: JointAngle = 180.0
    mass_kg: Mass | None = None
    com_mm: Vec3 | None = None
    compliance_urad_per_Nm: Compliance | None = None
    sin1_deg: Angle | None = None
    cos1_deg: Angle | None = None
    sin2_deg: Angle | None = None
    cos2_deg: Angle | None = None
    sigma: dict[str, NonNegativeFloat] | None = None  # written by a calibration: per-parameter sigma

    @model_validator(mode="after")
    def _limits_ordered(self) -> Joint:
        if not self.q_min_deg < self.q_max_deg:
            raise ValueError(f"q_min_deg {self.q_min_deg:g} must be below q_max_deg {self.q_max_deg:g}")
        return self


class Payload(Strict):
    """What the flange carries: mass [kg] and centre of mass [mm] in the flange frame."""

    mass_kg: Mass
    com_mm: Vec3 = [0.0, 0.0, 0.0]


class Flange(Strict):
    """A modified (``mdh``) table's flange after joint 6: what a standard table's last row holds as
    a and alpha (a corrected table writes the calibrated values; a robot's own file leaves it out)."""

    a_mm: Length = 0.0
    alpha_deg: Angle = 0.0


JointSign = Literal[1, -1]


class Controller(Strict):
    """How the robot's controller numbers its joints (contract: ``[controller]``): the model's joint
    is ``joint_sign * reading + joint_offset_deg``, joint by joint (KUKA's A1, A4 and A6 turn
    against the usual D-H axes: sign -1)."""

    joint_sign: Annotated[list[JointSign], Field(min_length=6, max_length=6)] = [1] * 6
    joint_offset_deg: Annotated[list[Angle], Field(min_length=6, max_length=6)] = [0.0] * 6

    @property
    def identity(self) -> bool:
        return all(s == 1 for s in self.joint_sign) and not any(self.joint_offset_deg)

    def model_deg(self, reading_deg) -> np.ndarray:
        """The model's joints [deg] (..., 6) of controller readings (..., 6) [deg]."""
        return model_joints(reading_deg, self.joint_sign, self.joint_offset_deg)

    def controller_deg(self, q_deg) -> np.ndarray:
        """The controller's readings [deg] (..., 6) of the model's joints (..., 6) [deg]."""
        return controller_joints(q_deg, self.joint_sign, self.joint_offset_deg)

    def model_speed(self, reading_deg_s) -> np.ndarray:
        """The model's joint speeds (..., 6) of the controller's (offsets do not move)."""
        return np.asarray(self.joint_sign, float) * np.asarray(reading_deg_s, float)


MAP_SUFFIX = ".map.npz"
"""A corrected table ``T.toml``'s residual map is ``T.map.npz`` beside it."""


class MapFile(Strict):
    """A corrected table's ``[map]``: its residual map (``calib.residual_map.map_arrays``, NumPy's
    ``.npz``) in ``file`` (beside the table, its name relative to the table's folder), written with
    the table as one (``station calibrate``), its ``sha256`` (a map of another calibration is
    refused), the ``rows`` it was fitted on and the share of the held-out rows' mean square error
    it takes out (``explained``)."""

    file: str
    sha256: Annotated[str, Field(pattern=r"^[0-9a-f]{64}$")]
    rows: Annotated[int, Field(ge=1)]
    explained: float


class RobotFile(Strict):
    """A robot model (contract: robot model TOML); a corrected table adds ``calibration``, where it
    identified compliances the ``payload`` they were identified with, and where it carries a
    residual map its ``map`` (``MapFile``, ``load_map``). ``convention``
    ``mdh``: Craig's modified D-H (``calib.conventions``), everything else computes with its
    standard equivalent (:meth:`table_deg`)."""

    name: str
    serial: str | None = None  # the robot's identity in the calibration history (else its name)
    convention: Literal["dh", "mdh"] = "dh"
    tool_mm: Vec3 = [0.0, 0.0, 0.0]
    joints: Annotated[list[Joint], Field(min_length=6, max_length=6)]
    flange: Flange | None = None
    payload: Payload | None = None
    calibration: dict | None = None
    controller_hash: str | None = None  # the controller's factory-calibration id (UR: ``hash``)
    controller: Controller = Controller()  # the controller's joint convention (default: the identity)
    map: MapFile | None = None

    @model_validator(mode="after")
    def _serial_names_a_robot(self) -> RobotFile:
        if self.serial is not None and not self.serial.strip():
            raise ValueError("serial: blank: give the robot's serial number, or leave the key out")
        if not self.name.strip():
            raise ValueError("name: blank: give the robot's name (its history identity without a serial)")
        return self

    @model_validator(mode="after")
    def _noise_scale(self) -> RobotFile:
        """A corrected table's ``[calibration] noise_scale``: what an unchanged robot leaves on
        verification, per residual group in stated noises; a calibration leaving ``MAX_NOISE_SCALE``
        or more is refused, so no table it writes carries more."""
        given = (self.calibration or {}).get("noise_scale")
        if given is None:
            return self
        ok = isinstance(given, list) and all(
            isinstance(v, int | float) and not isinstance(v, bool) and 0 <= v < MAX_NOISE_SCALE for v in given
        )
        if not ok:
            raise ValueError(
                f"calibration.noise_scale: expected a list of numbers from 0 to below {MAX_NOISE_SCALE:g} "
                "(the noise each instrument left, in stated noises), as station calibrate writes it"
            )
        return self

    @model_validator(mode="after")
    def _convention_keys(self) -> RobotFile:
        if self.convention == "dh":
            if self.flange is not None:
                raise ValueError('flange: only under convention = "mdh" (a standard table has it in joint 6)')
            return self
        first = self.joints[0]
        if first.alpha_deg != 0.0 or first.a_mm != 0.0:
            raise ValueError(
                f'joints.0: alpha_deg {first.alpha_deg:g} and a_mm {first.a_mm:g} under convention = "mdh": '
                "a table whose row 1 holds a twist or an offset is likely standard D-H: then set "
                'convention = "dh"; a modified table gives 0 for both (the station\'s base frame is '
                "joint 1's)"
            )
        return self

    def file_table_deg(self) -> np.ndarray:
        """(6, 4) table as the file writes it (its ``convention``), display units, columns as
        ``calib.params.DH_KEYS``."""
        return np.array([[getattr(j, key) for key in DH_KEYS] for j in self.joints])

    def table_deg(self) -> np.ndarray:
        """(6, 4) standard D-H table in display units, columns as ``calib.params.DH_KEYS`` (theta_deg,
        d_mm, a_mm, alpha_deg): the file's own, or a modified one's standard equivalent."""
        table = self.file_table_deg()
        if self.convention == "dh":
            return table
        flange = self.flange or Flange()
        return dh_from_mdh(table, (flange.a_mm, flange.alpha_deg))

    def param_name(self, name: str) -> str:
        """A standard table parameter's name (``J2.a_mm``) as this file's convention names it."""
        return mdh_name(name) if self.convention == "mdh" else name

    def limits_deg(self) -> np.ndarray:
        return np.array([[j.q_min_deg, j.q_max_deg] for j in self.joints])

    def link_masses(self, payload: Payload | None = None) -> LinkMasses | None:
        """The links' masses with ``payload`` (default: the file's own) lumped into link 6, each
        centre of mass in its standard D-H frame (a modified table's are given in Craig's frames);
        None unless every joint gives ``mass_kg`` and ``com_mm``."""
        if any(j.mass_kg is None or j.com_mm is None for j in self.joints):
            return None
        com = np.array([j.com_mm for j in self.joints], float)
        if self.convention == "mdh":  # given in Craig's frames, at the joints
            com = com_from_mdh(com, dh_from_degrees(self.table_deg()))
        links = LinkMasses(np.array([j.mass_kg for j in self.joints]), com)
        payload = payload or self.payload
        return links if payload is None else links.with_payload(payload.mass_kg, payload.com_mm)

    def terms(self) -> list[Term]:
        """The joint-space terms the file carries (``calib.joint_terms``), joint by joint."""
        return [
            Term(j, key)
            for j, joint in enumerate(self.joints)
            for key in TERM_KINDS
            if getattr(joint, key) is not None
        ]

    def model(self) -> RobotModel:
        """The robot model the maths uses (internal units: rad, mm), with the terms it carries."""
        dh, terms = dh_from_degrees(self.table_deg()), self.terms()
        values = np.array([getattr(self.joints[t.joint], t.key) for t in terms], float)
        values /= display_factor([t.name for t in terms])
        return RobotModel(
            dh,
            np.array(self.tool_mm),
            np.radians(self.limits_deg()),
            JointTerms(terms, dh, self.link_masses()),
            values,
        )

    def covariance(self, where: str) -> np.ndarray | None:
        """The calibration's covariance of the robot's parameters, the table and then the terms in
        ``model()``'s order, in internal units (rad, mm, urad/(N m)), as a corrected table carries it
        (``[calibration] covariance`` in display units, rows named by ``covariance_parameters``);
        None if it has none."""
        data = (self.calibration or {}).get("covariance")
        if data is None:
            return None
        expected = list(DH_NAMES) + [t.name for t in self.terms()]
        names = (self.calibration or {}).get("covariance_parameters", list(DH_NAMES))
        if not isinstance(names, list) or not all(isinstance(name, str) for name in names):
            raise InputError(f"{where}: calibration.covariance_parameters: expected a list of names")
        if self.convention == "mdh":
            names = [dh_name(name) for name in names]
        try:
            cov = np.array(data, float)
        except (TypeError, ValueError):
            raise InputError(f"{where}: calibration.covariance: not a table of numbers") from None
        n = len(expected)
        if sorted(names) != sorted(expected) or cov.shape != (n, n) or not np.isfinite(cov).all():
            raise InputError(
                f"{where}: calibration.covariance: expected {n} x {n} finite numbers, one per name of "
                "calibration.covariance_parameters: J1.theta_deg, J1.d_mm, ... and each term the joints carry"
            )
        if not _is_covariance(cov):
            raise InputError(
                f"{where}: calibration.covariance: not a covariance: it must be symmetric, without "
                f"negative variances (eigenvalues), every entry within {MAX_COVARIANCE:g} in display units"
            )
        order = [names.index(name) for name in expected]
        factor = display_factor(expected)
        return cov[np.ix_(order, order)] / np.outer(factor, factor)


MAX_COVARIANCE = MAX_LENGTH_MM**2  # mm^2, deg^2: a standard deviation of 100 m


def _is_covariance(cov: np.ndarray) -> bool:
    """Symmetric and positive semi-definite (to rounding), entries within ``MAX_COVARIANCE``."""
    scale = np.abs(cov).max()
    if scale > MAX_COVARIANCE:
        return False
    tol = 1e-9 * scale
    return bool(np.allclose(cov, cov.T, rtol=0, atol=tol) and np.linalg.eigvalsh(cov).min() >= -tol)


class SetupDrawstring(Strict):
    anchor_mm: Vec3
    length_offset_mm: Length
    sigma_mm: Sigma = 0.02


class SetupDial(Strict):
    axis: Direction | None = None
    sigma_mm: Sigma = 0.002


class SetupLine(Strict):
    """One gauge-block placement; ``point_mm``, ``direction`` (base frame), usable ``length_mm`` and
    the tool ``approach`` direction are needed only to plan measurements (``station plan``)."""

    id: Id
    dial_axis: Direction | None = None
    point_mm: Vec3 | None = None
    direction: Direction | None = None
    length_mm: PositiveLength = 400.0
    approach: Direction | None = None


class Box(Strict):
    """An axis-aligned box in the base frame: its ``min_mm`` and ``max_mm`` corners [mm]."""

    min_mm: Vec3
    max_mm: Vec3

    @model_validator(mode="after")
    def _corners_ordered(self) -> Box:
        if not all(lo < hi for lo, hi in zip(self.min_mm, self.max_mm, strict=True)):
            lo, hi = list(self.min_mm), list(self.max_mm)
            raise ValueError(f"min_mm {lo} must lie below max_mm {hi} on each axis")
        return self

    def contains(self, points: np.ndarray) -> np.ndarray:
        """Which of ``points`` (N, 3) [mm] lie inside (N,)."""
        p = np.atleast_2d(points)
        return np.all((p >= self.min_mm) & (p <= self.max_mm), axis=1)


class SetupCell(Strict):
    """Where a suggested gauge-line placement may go (``station plan``'s next placements, the
    running calibration's): wholly inside the ``reach`` box, its line and the tool coming onto it
    clear of every ``keep_out`` box, the tool at most ``max_tilt_from_down_deg`` from pointing
    straight down (None: any way)."""

    reach: Box | None = None
    keep_out: list[Box] = []
    max_tilt_from_down_deg: Annotated[float, Field(ge=0, le=180)] | None = None


class SetupFile(Strict):
    """Station geometry as measured roughly (contract: setup TOML). ``line_sigma_mm``: how well the
    tool sits on the gauge edge (joint-reading noise at the TCP included); ``contact_sigma_mm``: how
    far off the edge it may sit where no dial read the row (a dial-less cell, a row without a
    reading; a row read on a line without a ``dial_axis`` is held to its reading); ``rho``: line-term weight;
    ``payload``: what the flange carried while measuring (for the gravity torques)."""

    drawstring: SetupDrawstring | None = None
    dial: SetupDial | None = None
    payload: Payload | None = None
    lines: list[SetupLine] = []
    cell: SetupCell | None = None
    line_sigma_mm: Sigma = 0.01
    contact_sigma_mm: Sigma = 0.2
    rho: Annotated[float, Field(ge=1e-6, le=1e6)] = 1.0

    @model_validator(mode="after")
    def _line_ids_unique(self) -> SetupFile:
        ids = [line.id for line in self.lines]
        if len(set(ids)) != len(ids):
            raise ValueError(f"line id {next(i for i in ids if ids.count(i) > 1)} appears twice in [[lines]]")
        return self


MAX_NOISE_SCALE = 100.0
"""A calibration whose residual is this many times the stated noise is refused (``station.jobs.
fit_check.OVERWHELMING_RATIO``), so a table's ``noise_scale`` lies below it."""
SAME_ROBOT_MM, SAME_ROBOT_DEG = 50.0, 10.0
"""Largest table difference between a calibrated robot and its nominal model: beyond it the two
files describe different robots."""


def check_same_robot(table: RobotFile, table_where: str, nominal: RobotFile, nominal_where: str) -> None:
    """Bad input unless ``table`` (a calibration of) and ``nominal`` are the same robot: the same
    ``serial`` where both name one, the same ``[controller]``, every D-H parameter within
    ``SAME_ROBOT_MM`` / ``SAME_ROBOT_DEG``."""
    if table.serial and nominal.serial and table.serial != nominal.serial:
        raise InputError(
            f"{table_where}: serial {table.serial!r} is not {nominal_where}'s {nominal.serial!r}: a table "
            "calibrated for another robot of the same type"
        )
    if table.controller != nominal.controller:
        raise InputError(
            f"{table_where}: [controller] {_convention(table)} is not {nominal_where}'s "
            f"{_convention(nominal)}: programs and samples would read its joints another way; give both "
            "files the controller's convention"
        )
    diff = np.abs(table.table_deg() - nominal.table_deg())
    limit = np.array([SAME_ROBOT_DEG, SAME_ROBOT_MM, SAME_ROBOT_MM, SAME_ROBOT_DEG])
    if (diff > limit).any():
        j, k = np.argwhere(diff > limit)[0]
        key = ("theta_deg", "d_mm", "a_mm", "alpha_deg")[k]
        raise InputError(
            f"{table_where}: joints.{j}.{key} differs from {nominal_where}'s by {diff[j, k]:.1f}: "
            "not a calibration of that robot"
        )


def _convention(robot: RobotFile) -> str:
    c = robot.controller
    if c.identity:
        return "(none: the identity)"
    return f"joint_sign {c.joint_sign}, joint_offset_deg {c.joint_offset_deg}"


def check_same_tool(table: RobotFile, table_where: str, nominal: RobotFile, nominal_where: str) -> None:
    """Bad input unless both robot files put the TCP at the same ``tool_mm``."""
    if not np.allclose(table.tool_mm, nominal.tool_mm, atol=1e-6):
        raise InputError(
            f"{table_where}: tool_mm {table.tool_mm} differs from {nominal_where}'s {nominal.tool_mm}: "
            "the program's TCP must be the same in both"
        )


def load_robot(path) -> RobotFile:
    robot = validate(RobotFile, read_toml(path), str(path))
    check_robot_units(str(path), robot.table_deg(), robot.limits_deg())
    compliant = [j for j, joint in enumerate(robot.joints) if joint.compliance_urad_per_Nm is not None]
    if compliant and robot.link_masses() is None:
        raise InputError(
            f"{path}: joints.{compliant[0]}.compliance_urad_per_Nm needs mass_kg and com_mm on every joint"
        )
    return robot


def load_setup(path) -> SetupFile:
    setup = validate(SetupFile, read_toml(path), str(path))
    points = {f"lines.{k}.point_mm": ln.point_mm for k, ln in enumerate(setup.lines) if ln.point_mm}
    check_positions_in_mm(str(path), points)
    return setup


def map_entry(found: ResidualMap, rows: int, table_path) -> tuple[dict, Path, bytes]:
    """What a corrected table at ``table_path`` stores of the map ``found`` fitted on ``rows`` rows:
    its ``[map]`` block, the map file's path (``MAP_SUFFIX`` beside the table) and content."""
    buffer = io.BytesIO()
    np.savez(buffer, **map_arrays(found))
    data = buffer.getvalue()
    path = Path(table_path).with_suffix(MAP_SUFFIX)
    entry = {
        "file": path.name,
        "sha256": hashlib.sha256(data).hexdigest(),
        "rows": int(rows),
        "explained": float(found.explained),
    }
    return entry, path, data


def load_map(table: RobotFile, where) -> ResidualMap | None:
    """The residual map a corrected table read from ``where`` names in its ``[map]`` (None where it
    names none); ``InputError`` naming the table and the file where it is missing, is not the one
    the table was written with, or cannot be read."""
    if table.map is None:
        return None
    path = Path(where).parent / table.map.file
    try:
        data = path.read_bytes()
    except OSError as exc:
        raise InputError(
            f"{where}: map.file {table.map.file}: cannot read {path} ({exc.strerror or exc}); "
            "keep the map file beside its table (station calibrate writes both)"
        ) from None
    if hashlib.sha256(data).hexdigest() != table.map.sha256:
        raise InputError(
            f"{where}: map.file {path} is not the map this table was written with (sha256 differs); "
            "calibrate again, or remove the table's [map] to use the table alone"
        )
    try:
        with np.load(io.BytesIO(data), allow_pickle=False) as arrays:
            return map_from_arrays({key: arrays[key] for key in arrays.files})
    except (ValueError, KeyError, OSError) as exc:
        raise InputError(f"{where}: map.file {path}: not a residual map ({exc})") from None
