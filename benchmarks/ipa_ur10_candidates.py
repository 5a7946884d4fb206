"""Physical terms tried beyond the J2/J3 compliances on the real UR10 (IPA dataset, issue 23).

The default model (J2 and J3 yielding under gravity) leaves 0.48 mm on series C that C's narrow
poses cannot separate from the table, and C's table extrapolates to 0.698 mm on A, B and D. This
script asks whether a physically grounded term (not a curve fit) expresses part of that error: it
trains ``--model compliance`` on each series, as ``benchmarks/ipa_ur10.py`` does
(``calibrate_samples``; the same rows, start and reference), then the same model with one candidate
freed beside it under its prior (``calib.calibrate.calibrate``), and registers the other three
series with each table held (``held_out`` below, ``ipa_ur10.held_out_errors``'s way). None of these
terms is in the station: a candidate's values must agree between the four series of one robot and
cut the held-out error on every split before it could be.

Each candidate is a small displacement linear in its value, computed at the readings with the
nominal table and UR's link masses (``configs/robots/ur10.toml``), like the compliances' torques:

- a joint deflection (``Deflection.joint`` set): the joint turns by ``basis(arm)`` per unit value;
- a rotation (``joint`` None): everything beyond ``pivot(arm)`` turns by ``rotation(arm)`` per unit
  value (a base or bearing tilting, two nominally parallel axes not quite parallel).

Two more rows are not model terms: a probe's mass added to the arm's (a payload), and the
compliances held at another series' values (which the benchmark may not do: it uses held-out data)
to show how much of C's failure is its compliance estimate.

``--orientation`` trains ``--model compliance`` on the positions and the T-Mac's orientations together
(the dataset's ``measurement_rx, ry, rz``: intrinsic x-y-z Euler angles [deg] of the T-Mac in the
tracker frame, the convention that fits the nominal robot to 0.04 deg where the others leave
0.9-1.5 deg) and prints the held-out figures, positions only, as the rest.

``--table-prior F [F ...]`` trains ``--model compliance`` with the table's manufacturing tolerance
(``calib.identifiability.tolerance``) divided by each F, a stronger pull towards the nominal table
where the rows say little, and prints the held-out figures.

``--spectrum`` prints, per series, the orders (cycles per turn) of J1-J3's angle error that take most
of the compliance model's residual; ``--own-frequency LO HI`` trains each series with J2's and J3's
cyclic error at the frequencies where its own residual's spectrum peaks in [LO, HI] (the other
series never looked at) and prints the held-out figures.

Usage: ``python benchmarks/ipa_ur10_candidates.py --data DIR [--train A B C D] [--spectrum |
--own-frequency LO HI | --orientation | --table-prior F [F ...]]``
"""

from __future__ import annotations

import argparse
import dataclasses
import sys
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from scipy.optimize import least_squares
from scipy.spatial.transform import Rotation

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from benchmarks.ipa_ur10 import ROOT, SERIES, Series, load, position_set  # noqa: E402
from calib.calibrate import CalibrationOptions, calibrate  # noqa: E402
from calib.joint_terms import (  # noqa: E402
    COMPLIANCE_PRIOR,
    G_MS2,
    HARMONIC_PRIOR_DEG,
    MICRO,
    JointTerms,
    LinkMasses,
    gravity_torques,
)
from calib.kinematics import N_DH, base_from_frames, dh_table, tcp_position  # noqa: E402
from calib.position import N_SETUP, PositionModel, register  # noqa: E402
from station.formats.tables import Payload, load_robot  # noqa: E402
from station.jobs.calibration import calibrate_samples  # noqa: E402

SPECTRUM_ORDERS = range(1, 41)
"""Orders (cycles per joint turn) of the residual's spectrum (``--spectrum``)."""
LOST_MOTION_PRIOR_URAD = 300.0
"""A strain-wave gear's lost motion, 1 sigma [urad]: about one arc minute."""
BETA_PRIOR_URAD = 2000.0
"""Two nominally parallel axes' misalignment, 1 sigma [urad] (0.1 deg)."""
PROBE_PAYLOAD = (1.5, [0.0, 0.0, 60.0])
"""A tracker probe's mass [kg] and centre [mm] in the flange frame, assumed (not in the dataset)."""
UP = np.array([0.0, 0.0, 1.0])


class Arm:
    """What the candidates are computed from, at readings ``q`` (N, 6) [rad] with table ``dh``:
    the D-H frames (N, 7, 4, 4), the moment (N, 6, 3) [N m] of the weights beyond each joint about
    its frame's origin (base frame) and each joint's gravity torque (N, 6) [N m]."""

    def __init__(self, dh: np.ndarray, q: np.ndarray, links: LinkMasses):
        self.frames = base_from_frames(dh, q)
        com = np.einsum("nkij,kj->nki", self.frames[:, 1:, :3, :3], links.com_mm) + self.frames[:, 1:, :3, 3]
        force = links.mass_kg[:, None] * G_MS2 * np.asarray(links.gravity, float)
        origin = self.frames[:, :6, :3, 3]
        arm = com[:, None, :, :] - origin[:, :, None, :]  # (N, joint, link, 3)
        beyond = np.triu(np.ones((6, 6)))[None, :, :, None]  # link k >= joint j
        self.moment = (np.cross(arm, force[None, None]) * beyond).sum(axis=2) * 1e-3
        self.torque = np.einsum("nji,nji->nj", self.moment, self.axis)
        self.dh, self.q, self.links = dh, q, links

    @property
    def axis(self) -> np.ndarray:
        """Each joint's axis (N, 6, 3), base frame."""
        return self.frames[:, :6, :3, 2]

    def origin(self, frame: int) -> np.ndarray:
        """D-H frame ``frame``'s origin (N, 3) [mm]."""
        return self.frames[:, frame, :3, 3]

    def bearing_moment(self, joint: int) -> np.ndarray:
        """The moment (N, 3) [N m] joint ``joint``'s bearing carries across its axis."""
        m, z = self.moment[:, joint], self.axis[:, joint]
        return m - np.einsum("ni,ni->n", m, z)[:, None] * z

    def own_torque(self, joint: int) -> np.ndarray:
        """The gravity torque (N,) [N m] about ``joint`` of its own link's weight alone."""
        mass = np.zeros(6)
        mass[joint] = self.links.mass_kg[joint]
        own = LinkMasses(mass, self.links.com_mm, self.links.gravity)
        return gravity_torques(self.dh, self.q, own, [joint])[:, 0]


@dataclass(frozen=True)
class Deflection:
    """One candidate term: its ``label``, the ``prior`` (1 sigma, its unit) and either the
    ``joint`` (0-based) it turns by ``basis(arm)`` rad per unit (N,), or, with ``joint`` None, the
    rotation ``rotation(arm)`` rad per unit (N, 3) of everything beyond ``pivot(arm)`` (N, 3) [mm]."""

    label: str
    prior: float
    joint: int | None = None
    basis: Callable[[Arm], np.ndarray] | None = None
    rotation: Callable[[Arm], np.ndarray] | None = None
    pivot: Callable[[Arm], np.ndarray] | None = None
    shift: Callable[[Arm], np.ndarray] | None = None

    def field(self, arm: Arm, p: np.ndarray) -> np.ndarray:
        """What one unit of the candidate moves the TCPs ``p`` (N, 3) by [mm], base frame."""
        if self.shift is not None:
            return self.shift(arm)
        return np.cross(self.rotation(arm), p - self.pivot(arm))


class CandidateTerms(JointTerms):
    """``base``'s terms (the compliances) followed by the candidates ``extra``."""

    def __init__(self, base: JointTerms, extra: tuple[Deflection, ...]):
        super().__init__(base.terms, base.dh, base.links)
        self.base, self.extra = base, extra
        self.names = base.names + tuple(d.label for d in extra)
        self.joints = np.concatenate([base.joints, [d.joint or 0 for d in extra]]).astype(int)

    def __len__(self) -> int:
        return len(self.names)

    def prior_sigma(self) -> np.ndarray:
        return np.concatenate([self.base.prior_sigma(), [d.prior for d in self.extra]])

    def basis(self, q: np.ndarray) -> np.ndarray:
        """The base terms' basis, the joint candidates' and zero for a rotation (its field is added
        in ``tcp_jacobian``)."""
        arm = Arm(self.dh, q, self.links)
        extra = [d.basis(arm) if d.joint is not None else np.zeros(len(q)) for d in self.extra]
        return np.column_stack([self.base.basis(q), *extra])

    def tcp_jacobian(self, dh, q, tool, c, basis):
        p, jac_table, jac_terms = super().tcp_jacobian(dh, q, tool, c, basis)
        rotations = [k for k, d in enumerate(self.extra, len(self.base)) if d.joint is None]
        if rotations:
            arm, p = Arm(self.dh, q, self.links), p.copy()
            for k in rotations:
                jac_terms[:, :, k] = self.extra[k - len(self.base)].field(arm, p)
            p += np.einsum("nik,k->ni", jac_terms[:, :, rotations], c[rotations])
        return p, jac_table, jac_terms


class CandidateModel(PositionModel):
    """A position model whose TCP comes from its terms' ``tcp_jacobian`` in every path (a rotation
    candidate moves it where the joint angles alone do not)."""

    def tcp(self, x: np.ndarray) -> np.ndarray:
        return self.terms.tcp_jacobian(
            self.dh(x), self.samples.q, self.probe(x), self.term_values(x), self._basis
        )[0]

    def predicted_mm(self, x: np.ndarray) -> np.ndarray:
        rot, t = self.tracker_from_base(x)
        return self.tcp(x) @ rot.T + t

    def residuals_and_jacobian(self, x: np.ndarray, jacobian: bool = True):
        if jacobian:
            return self._evaluate(x, True)
        return ((self.predicted_mm(x) - self.samples.position) / self.sigma).ravel(), None

    def residuals(self, x: np.ndarray) -> np.ndarray:
        return self.residuals_and_jacobian(x, False)[0]

    def with_start(self, dh0: np.ndarray, probe0: np.ndarray) -> CandidateModel:
        return CandidateModel(self.samples, dh0, probe0, None, self.sigma, self.terms)


def _joint(label: str, joint: int, basis: Callable[[Arm], np.ndarray], prior: float) -> Deflection:
    return Deflection(label, prior, joint=joint, basis=basis)


def _tilt(label: str, rotation, pivot, prior: float = COMPLIANCE_PRIOR) -> Deflection:
    return Deflection(label, prior, rotation=rotation, pivot=pivot)


def _lost_motion(joint: int, torque_nm: float) -> Deflection:
    """A gear's lost motion (or its soft zone): ``+-half`` of it as the gravity torque changes sign
    over ``torque_nm``."""
    return _joint(
        f"J{joint + 1} lost motion ({torque_nm:g} N m) [urad]",
        joint,
        lambda arm: MICRO * 0.5 * np.tanh(arm.torque[:, joint] / torque_nm),
        LOST_MOTION_PRIOR_URAD,
    )


def _base_tilt(depth_mm: float) -> Deflection:
    """The pedestal tilting about a point ``depth_mm`` below the base under the moment of every
    link's weight (isotropic)."""
    return _tilt(
        f"base tilt, pivot {depth_mm:g} mm below the base [urad/(N m)]",
        lambda arm: MICRO * arm.moment[:, 0],
        lambda arm: arm.origin(0) - depth_mm * UP,
    )


def _bearing_tilt(joint: int) -> Deflection:
    """Joint ``joint``'s bearing tilting under the moment across its axis (out of the arm's plane:
    the wrist's lateral offsets d4, d5 twist the upper arm and forearm)."""
    return _tilt(
        f"J{joint + 1} bearing tilt [urad/(N m)]",
        lambda arm: MICRO * arm.bearing_moment(joint),
        lambda arm: arm.origin(joint),
    )


def _beta(joint: int) -> Deflection:
    """Hayati's beta: the next axis turned about frame ``joint + 1``'s y axis (axes 2, 3, 4 are
    nominally parallel; a D-H table cannot hold a small misalignment of them)."""
    return _tilt(
        f"J{joint + 1} beta (Hayati) [urad]",
        lambda arm: MICRO * arm.frames[:, joint + 1, :3, 1],
        lambda arm: arm.origin(joint + 1),
        BETA_PRIOR_URAD,
    )


def _harmonic(joint: int, order: float) -> tuple[Deflection, Deflection]:
    """Joint ``joint``'s angle error repeating ``order`` times a turn (sine and cosine)."""
    return tuple(
        _joint(
            f"J{joint + 1} {name}{order:g} [rad]",
            joint,
            lambda arm, fun=fun: fun(order * arm.q[:, joint]),
            np.radians(HARMONIC_PRIOR_DEG),
        )
        for fun, name in ((np.sin, "sin"), (np.cos, "cos"))
    )


CANDIDATES: dict[str, tuple[Deflection, ...]] = {
    "base tilt, pivot at the base": (_base_tilt(0.0),),
    "base tilt, pivot 300 mm below": (_base_tilt(300.0),),
    "base tilt, pivot 800 mm below": (_base_tilt(800.0),),
    "J2, J3 bearing tilt (out-of-plane bending, torsion)": (_bearing_tilt(1), _bearing_tilt(2)),
    "J4 compliance": (
        _joint("J4 compliance [urad/(N m)]", 3, lambda arm: MICRO * arm.torque[:, 3], COMPLIANCE_PRIOR),
    ),
    "J2, J3 lost motion (5 N m)": (_lost_motion(1, 5.0), _lost_motion(2, 5.0)),
    "J3 lost motion (5 N m)": (_lost_motion(2, 5.0),),
    "J2, J3 soft zone (30 N m)": (_lost_motion(1, 30.0), _lost_motion(2, 30.0)),
    "J2 by J3's torque, J3 by J2's (coupled compliance)": (
        _joint("J2 by tau3 [urad/(N m)]", 1, lambda arm: MICRO * arm.torque[:, 2], COMPLIANCE_PRIOR),
        _joint("J3 by tau2 [urad/(N m)]", 2, lambda arm: MICRO * arm.torque[:, 1], COMPLIANCE_PRIOR),
    ),
    "J2 under the upper arm's own weight (beam bending)": (
        _joint("J2 own link [urad/(N m)]", 1, lambda arm: MICRO * arm.own_torque(1), COMPLIANCE_PRIOR),
    ),
    "J2, J3 beta (non-parallel axes)": (_beta(1), _beta(2)),
    "J2, J3 first harmonic (encoder eccentricity)": _harmonic(1, 1) + _harmonic(2, 1),
    "J2, J3 17th harmonic (order picked from every series' spectrum)": _harmonic(1, 17) + _harmonic(2, 17),
}


def held_out(tests: dict[str, Series], terms: JointTerms, nominal: np.ndarray, x: np.ndarray) -> dict:
    """Per test series, the registered position errors [mm] with the table and terms in ``x`` held."""
    out = {}
    for name, series in tests.items():
        model = CandidateModel(series.samples, nominal, series.probe, terms=terms)
        model, fit = register(model, dh_table(x), x[N_DH + N_SETUP :])
        out[name] = model.row_error_mm(fit.x)
    return out


def pooled_rmse(errors: dict[str, np.ndarray]) -> float:
    return float(np.sqrt(np.mean(np.concatenate(list(errors.values())) ** 2)))


def with_compliance_held(series: Series, values: np.ndarray, dh: np.ndarray, links: LinkMasses) -> Series:
    """The series with J2's and J3's yield at ``values`` [urad/(N m)] folded into its readings."""
    q = series.ipa.q_rad.copy()
    q[:, 1:3] += MICRO * values * gravity_torques(dh, q, links, [1, 2])
    return Series(dataclasses.replace(series.ipa, q_rad=q), series.probe)


def run_train(data: Path, train_name: str, robot, held_values: dict[str, np.ndarray]) -> dict[str, tuple]:
    """Every row's (pooled held-out RMSE [mm], candidate values text) for training on ``train_name``."""
    train = load(data, train_name)
    tests = {n: load(data, n) for n in sorted(SERIES) if n != train_name}
    outcome = calibrate_samples(position_set(train), robot, None, terms="compliance")
    base = outcome.model
    nominal = base.dh0
    rows = {
        "compliance (the default)": (
            pooled_rmse(held_out(tests, base.terms, nominal, outcome.calibration.x)),
            "",
        )
    }
    held_values[train_name] = outcome.calibration.x[N_DH + N_SETUP :]
    for label, extra in CANDIDATES.items():
        terms = CandidateTerms(base.terms, extra)
        model = CandidateModel(base.samples, nominal, base.probe0, base.reference, base.sigma, terms)
        cal = calibrate(model, CalibrationOptions())
        k = N_DH + N_SETUP + len(base.terms)
        values = ", ".join(f"{v:.3g} +- {s:.2g}" for v, s in zip(cal.x[k:], cal.sigma[k:], strict=True))
        rows[label] = (pooled_rmse(held_out(tests, terms, nominal, cal.x)), values)
    heavy = robot.model_copy(update={"payload": Payload(mass_kg=PROBE_PAYLOAD[0], com_mm=PROBE_PAYLOAD[1])})
    probe = calibrate_samples(position_set(train), heavy, None, terms="compliance")
    x = probe.calibration.x
    rows[f"a {PROBE_PAYLOAD[0]:g} kg probe on the flange"] = (
        pooled_rmse(held_out(tests, probe.model.terms, nominal, x)),
        ", ".join(f"{v:.3g}" for v in x[N_DH + N_SETUP :]),
    )
    return rows


def held_compliance_rows(data: Path, train_name: str, robot, held_values: dict[str, np.ndarray]) -> dict:
    """Training ``--model geometric`` with the compliances held at each other series' values."""
    links, rows = robot.link_masses(), {}
    for other, values in held_values.items():
        if other == train_name:
            continue
        dh = robot.model().dh
        train = with_compliance_held(load(data, train_name), values, dh, links)
        tests = {
            n: with_compliance_held(load(data, n), values, dh, links)
            for n in sorted(SERIES)
            if n != train_name
        }
        outcome = calibrate_samples(position_set(train), robot, None, terms="geometric")
        errors = held_out(tests, JointTerms(), outcome.model.dh0, outcome.calibration.x)
        rows[other] = pooled_rmse(errors)
    return rows


def residual_spectrum(outcome, joint: int, orders) -> list[tuple[float, float, float, float]]:
    """Per order k of ``orders`` (cycles per turn): the share of the calibration ``outcome``'s
    residual (its part the identified unknowns cannot take) that an angle error ``a sin(k q) +
    b cos(k q)`` of joint ``joint`` takes alone, its amplitude [arcsec] and phase ``atan2(b, a)``
    [deg]."""
    model, cal = outcome.model, outcome.calibration
    r, jac = model.residuals_and_jacobian(cal.x)
    basis, _ = np.linalg.qr(jac[:, cal.identified])
    left = r - basis @ (basis.T @ r)
    q = model.joints(cal.x)
    frames = base_from_frames(model.dh(cal.x), q)
    p = tcp_position(model.dh(cal.x), q, model.probe(cal.x))
    rot, _ = model.tracker_from_base(cal.x)
    turn = np.cross(frames[:, joint, :3, 2], p - frames[:, joint, :3, 3]) @ rot.T / model.sigma
    out = []
    for k in orders:
        waves = [fun(k * model.samples.q[:, joint]) for fun in (np.sin, np.cos)]
        cols = np.column_stack([(turn * w[:, None]).ravel() for w in waves])
        cols -= basis @ (basis.T @ cols)
        (a, b), *_ = np.linalg.lstsq(cols, left, rcond=None)
        share = 1.0 - np.sum((left - cols @ [a, b]) ** 2) / np.sum(left**2)
        out.append(
            (k, float(share), float(np.degrees(np.hypot(a, b)) * 3600), float(np.degrees(np.arctan2(b, a))))
        )
    return out


def own_frequency(data: Path, train_name: str, robot, band: tuple[float, float]) -> tuple[list[float], float]:
    """Train on ``train_name`` with J2's and J3's cyclic error at the frequencies [cycles per turn]
    where the training residual's spectrum peaks within ``band`` (steps of 0.1; nothing else looked
    at): those frequencies and the pooled held-out RMSE [mm] on the other series."""
    train = load(data, train_name)
    tests = {n: load(data, n) for n in sorted(SERIES) if n != train_name}
    outcome = calibrate_samples(position_set(train), robot, None, terms="compliance")
    grid = np.arange(band[0], band[1] + 1e-9, 0.1)
    freqs = [max(residual_spectrum(outcome, j, grid), key=lambda t: t[1])[0] for j in (1, 2)]
    base = outcome.model
    terms = CandidateTerms(base.terms, _harmonic(1, freqs[0]) + _harmonic(2, freqs[1]))
    model = CandidateModel(base.samples, base.dh0, base.probe0, base.reference, base.sigma, terms)
    cal = calibrate(model, CalibrationOptions())
    return [float(f) for f in freqs], pooled_rmse(held_out(tests, terms, base.dh0, cal.x))


class TighterTable(PositionModel):
    """A position model whose table prior is its manufacturing tolerance divided by ``factor``."""

    factor: float = 1.0

    def prior_sigma(self) -> np.ndarray:
        sigma = super().prior_sigma()
        sigma[:N_DH] /= self.factor
        return sigma


def with_table_prior(data: Path, train_name: str, robot, factors) -> list[float]:
    """Pooled held-out RMSE [mm] of ``--model compliance`` trained on ``train_name`` with the
    table's prior tightened by each of ``factors``."""
    tests = {n: load(data, n) for n in sorted(SERIES) if n != train_name}
    base = calibrate_samples(position_set(load(data, train_name)), robot, None, terms="compliance").model
    out = []
    for factor in factors:
        model = TighterTable(base.samples, base.dh0, base.probe0, base.reference, base.sigma, base.terms)
        model.factor = factor
        cal = calibrate(model, CalibrationOptions())
        out.append(pooled_rmse(held_out(tests, base.terms, base.dh0, cal.x)))
    return out


def tmac_orientation(series: Series) -> Rotation:
    """The T-Mac's measured orientations in the tracker frame, from the series file's
    ``measurement_rx, ry, rz`` [deg] (intrinsic x-y-z)."""
    lines = series.ipa.path.read_text(encoding="utf-8-sig").splitlines()
    header = [h.strip() for h in lines[0].split(";")]
    cols = [header.index(f"measurement_r{axis}") for axis in "xyz"]
    rows = [line.split(";") for line in lines[1:] if line.strip()]
    angles = np.array([[float(row[c].replace(",", ".")) for c in cols] for row in rows])
    return Rotation.from_euler("XYZ", angles, degrees=True)


def with_orientation(data: Path, train_name: str, robot) -> tuple[float, float, list[float], str]:
    """Train ``--model compliance`` on ``train_name``'s positions and orientations together (the
    flange-to-T-Mac rotation free, every group weighted by its own RMS, re-estimated three times;
    the table and compliances under their priors): the pooled held-out RMSE [mm] of the compliance
    model without and with the orientations, the compliances [urad/(N m)] and the residuals."""
    train = load(data, train_name)
    tests = {n: load(data, n) for n in sorted(SERIES) if n != train_name}
    outcome = calibrate_samples(position_set(train), robot, None, terms="compliance")
    model, x0 = outcome.model, outcome.calibration.x
    measured, n = tmac_orientation(train), len(train.ipa)
    prior = model.prior_sigma()
    bounded = np.isfinite(prior)

    def flange(x):
        rot, _ = model.tracker_from_base(x)
        return Rotation.from_matrix(rot @ base_from_frames(model.dh(x), model.joints(x))[:, -1, :3, :3])

    y0 = (flange(x0).inv() * measured).mean().as_rotvec()

    def residuals(v, sigma_mm, sigma_rad):
        x, y = v[:-3], Rotation.from_rotvec(v[-3:])
        position = model.residuals_and_jacobian(x, False)[0] * model.sigma / sigma_mm
        orientation = ((flange(x) * y).inv() * measured).as_rotvec().ravel() / sigma_rad
        return np.concatenate([position, orientation, (x - model.x0)[bounded] / prior[bounded]])

    v, sigma_mm, sigma_rad = np.concatenate([x0, y0]), 0.3, np.radians(0.03)
    for _ in range(3):
        v = least_squares(residuals, v, args=(sigma_mm, sigma_rad), x_scale="jac").x
        r = residuals(v, 1.0, 1.0)
        sigma_mm, sigma_rad = np.sqrt(np.mean(r[: 3 * n] ** 2)), np.sqrt(np.mean(r[3 * n : 6 * n] ** 2))
    x = v[:-3]
    before = pooled_rmse(held_out(tests, model.terms, model.dh0, x0))
    after = pooled_rmse(held_out(tests, model.terms, model.dh0, x))
    left = f"residual {sigma_mm * np.sqrt(3):.3f} mm, {np.degrees(sigma_rad):.4f} deg per axis"
    return before, after, list(model.term_values(x)), left


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--data", type=Path, required=True, help="the ipa-robot-accuracy folder")
    p.add_argument("--train", nargs="+", default=sorted(SERIES), choices=sorted(SERIES))
    p.add_argument("--spectrum", action="store_true", help="only the residual's spectrum in J1-J3's angles")
    p.add_argument(
        "--own-frequency",
        nargs=2,
        type=float,
        metavar=("LO", "HI"),
        help="only: J2's and J3's cyclic error at the training series' own spectral peak in [LO, HI]",
    )
    p.add_argument(
        "--orientation",
        action="store_true",
        help="only: compliance trained on the T-Mac's orientations too",
    )
    p.add_argument(
        "--table-prior",
        nargs="+",
        type=float,
        metavar="F",
        help="only: the table's tolerance / each F",
    )
    args = p.parse_args(argv)
    robot = load_robot(ROOT / "configs/robots/ur10.toml")
    if args.table_prior:
        rows = {name: with_table_prior(args.data, name, robot, args.table_prior) for name in args.train}
        print("| table prior | " + " | ".join(args.train) + " | mean |")
        print("|---|" + "---|" * (len(args.train) + 1))
        for k, factor in enumerate(args.table_prior):
            figures = [rows[n][k] for n in args.train]
            cells = " | ".join(f"{f:.3f}" for f in figures)
            print(f"| tolerance / {factor:g} | {cells} | {np.mean(figures):.3f} |")
        return 0
    if args.orientation:
        figures = []
        for name in args.train:
            before, after, values, left = with_orientation(args.data, name, robot)
            figures.append((before, after))
            text = ", ".join(f"{v:.1f}" for v in values)
            print(f"train {name}: positions {before:.3f}, with orientations {after:.3f}", end=" ")
            print(f"(compliances {text}; {left})")
        print("mean: positions {:.3f}, with orientations {:.3f}".format(*np.mean(figures, axis=0)))
        return 0
    if args.own_frequency:
        figures = []
        for name in args.train:
            freqs, rmse = own_frequency(args.data, name, robot, tuple(args.own_frequency))
            figures.append(rmse)
            print(
                f"train {name}: J2 {freqs[0]:.1f}, J3 {freqs[1]:.1f} cycles per turn: {rmse:.3f}", flush=True
            )
        print(f"mean {np.mean(figures):.3f}")
        return 0
    if args.spectrum:
        for name in args.train:
            outcome = calibrate_samples(position_set(load(args.data, name)), robot, None, terms="compliance")
            for joint in range(3):
                top = sorted(residual_spectrum(outcome, joint, SPECTRUM_ORDERS), key=lambda t: -t[1])[:5]
                text = "; ".join(
                    f'{k}: {share:.1%}, {amp:.0f}" at {phase:.0f} deg' for k, share, amp, phase in top
                )
                print(f"{name} J{joint + 1}, orders taking most of the residual: {text}", flush=True)
        return 0
    results, held_values = {}, {}
    for name in args.train:
        results[name] = run_train(args.data, name, robot, held_values)
        for label, (rmse, values) in results[name].items():
            print(f"train {name}: {label:52} {rmse:.3f}  {values}", flush=True)
    print("pooled held-out RMSE [mm], compliance + candidate, train one series, test the other three:")
    print("| candidate | " + " | ".join(args.train) + " | mean |")
    print("|---|" + "---|" * (len(args.train) + 1))
    for label in results[args.train[0]]:
        figures = [results[n][label][0] for n in args.train]
        print(f"| {label} | " + " | ".join(f"{f:.3f}" for f in figures) + f" | {np.mean(figures):.3f} |")
    for name in args.train:
        rows = held_compliance_rows(args.data, name, robot, held_values)
        text = ", ".join(f"at {o}'s {rmse:.3f}" for o, rmse in rows.items())
        print(f"train {name}, compliances held at another series' values (uses held-out data): {text}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
