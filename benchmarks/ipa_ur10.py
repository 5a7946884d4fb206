"""UR10 on real laser-tracker data (IPA robot-accuracy dataset, Landgraf et al., CASE 2021).

Calibrate on one series, validate on the others. Every series was measured from its own tracker
placement with its own probe mounting, so each held-out series is first *registered*: its
base-to-tracker transform and probe offset are fitted with the table held, the same way for the
nominal table and the corrected one. The figures are the distances |measured - model| [mm] of the
held-out rows after that registration, per series and pooled.

Three models are trained on the same series:

- ``position``: the position model (D-H + base-to-tracker + probe), the main result;
- ``drawstring``: the tracker positions turned into drawstring readings from a chosen anchor
  (0.02 mm noise) and calibrated with the distance model (no lines): what a drawstring station gets;
- ``compliance``: the position model plus one gravity compliance per joint 2 and 3.

Usage: ``python benchmarks/ipa_ur10.py --data DIR [--train B] [--test C D] [--json]``.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from calib.calibrate import calibrate  # noqa: E402
from calib.joint_terms import JointTerms, LinkMasses, compliance_group  # noqa: E402
from calib.kinematics import N_DH  # noqa: E402
from calib.metrics import error_metrics  # noqa: E402
from calib.models import DrawstringFrame, DrawstringLineModel, DrawstringSamples, DrawstringSetup  # noqa: E402
from calib.params import dh_from_degrees  # noqa: E402
from calib.position import PositionModel, PositionSamples, register  # noqa: E402
from sim_fixtures.world import Noise  # noqa: E402
from station.formats.ipa import probe_file_for, read_probe_mm, read_series  # noqa: E402
from station.formats.tables import load_robot  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
SERIES = {
    "A": "Series_A/measurements_grid.csv",
    "B": "Series_B/measurements_joint_configurations.csv",
    "C": "Series_C/measurements_random_poses.csv",
    "D": "Series_D/measurements_iso_cubes.csv",
}
# UR10 (CB3) link masses and centres of mass in their D-H frames, as Universal Robots publishes them
# ("Parameters for calculations of kinematics and dynamics"); the probe's own mass is not known.
UR10_LINKS = LinkMasses(
    mass_kg=np.array([7.1, 12.7, 4.27, 2.0, 2.0, 0.365]),
    com_mm=np.array([[21, 0, 27], [380, 0, 158], [240, 0, 68], [0, 7, 18], [0, 7, 18], [0, 0, -26]], float),
)
# 0-based: joints 2 and 3 carry the arm against gravity. Adding joint 4 (wrist torques are small)
# fitted 589 urad/(N m), helped C and hurt D: overfitting, so it is left out.
COMPLIANT_JOINTS = (1, 2)
DRAWSTRING_SIGMA_MM = Noise().length_mm  # the simulated drawstring's reading noise
ANCHOR_OFFSET_MM = np.array([500.0, 300.0, -1200.0])  # anchor below and beside the workspace centre


def load(data: Path, name: str) -> tuple[PositionSamples, np.ndarray]:
    series = read_series(data / SERIES[name])
    return PositionSamples(series.q_rad, series.position_mm), read_probe_mm(probe_file_for(series.path))


def held_out_errors(tests, dh, compliance=None, values=None) -> dict[str, np.ndarray]:
    """Per test series, the registered position errors [mm] with table ``dh`` (and compliances)."""
    out = {}
    for name, (samples, probe) in tests.items():
        model, fit = register(PositionModel(samples, dh, probe, terms=compliance), dh, values)
        out[name] = model.row_error_mm(fit.x)
    return out


def drawstring_table(train: PositionSamples, position_model: PositionModel, x_before, rng) -> np.ndarray:
    """Simulated drawstring readings from the tracker positions, calibrated with the distance model.
    The rough anchor (base frame) comes from the nominal registration, +-30 mm; the cable is tied at
    the probe point, taken on joint 6's axis at the registered probe length."""
    anchor_tracker = train.position.mean(axis=0) + ANCHOR_OFFSET_MM
    offset = 500.0
    length = np.linalg.norm(train.position - anchor_tracker, axis=1) - offset
    length += rng.normal(0, DRAWSTRING_SIGMA_MM, length.size)
    rot, t = position_model.tracker_from_base(x_before)
    anchor_base = rot.T @ (anchor_tracker - t)
    n = len(train)
    samples = DrawstringSamples(train.q, length, np.full(n, np.nan), np.full(n, -1))
    setup = DrawstringSetup(
        anchor_base + rng.uniform(-30, 30, 3), offset + rng.uniform(-8, 8), DRAWSTRING_SIGMA_MM
    )
    tool = np.array([0.0, 0.0, position_model.probe(x_before)[2]])
    dh0 = position_model.dh0
    model = DrawstringLineModel(
        samples, setup, DrawstringFrame.from_nominal(samples, setup, dh0, tool), dh0, tool
    )
    return model.dh(calibrate(model).x)


def pooled(errors: dict[str, np.ndarray]) -> dict[str, float]:
    return error_metrics(np.concatenate(list(errors.values())))


def fmt(m: dict) -> str:
    return f"{m['rmse_mm']:6.3f} {m['mean_mm']:6.3f} {m['max_mm']:6.3f}"


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--data", type=Path, required=True, help="the ipa-robot-accuracy folder")
    p.add_argument("--train", default="B", choices=sorted(SERIES))
    p.add_argument("--test", nargs="+", default=["C", "D"], choices=sorted(SERIES))
    p.add_argument("--json", action="store_true", help="last stdout line: the pooled figures as JSON")
    args = p.parse_args(argv)
    rng = np.random.default_rng(0)
    nominal = dh_from_degrees(load_robot(ROOT / "configs/robots/ur10.toml").table_deg())
    train, probe = load(args.data, args.train)
    tests = {name: load(args.data, name) for name in args.test}

    t0 = time.perf_counter()
    model = PositionModel(train, nominal, probe)
    cal = calibrate(model)
    t_position = time.perf_counter() - t0
    comp_terms = JointTerms([compliance_group(j).terms[0] for j in COMPLIANT_JOINTS], nominal, UR10_LINKS)
    comp_model = PositionModel(train, nominal, probe, terms=comp_terms)
    comp_cal = calibrate(comp_model)
    compliance = comp_cal.x[N_DH + 9 :]

    results = {
        "nominal": held_out_errors(tests, nominal),
        "position": held_out_errors(tests, model.dh(cal.x)),
        "drawstring": held_out_errors(tests, drawstring_table(train, model, cal.before.x, rng)),
        "compliance": held_out_errors(tests, comp_model.dh(comp_cal.x), comp_terms, compliance),
    }
    train_err = {
        "before": error_metrics(model.row_error_mm(cal.before.x)),
        "after": error_metrics(model.row_error_mm(cal.x)),
        "compliance": error_metrics(comp_model.row_error_mm(comp_cal.x)),
    }

    print(f"UR10, IPA dataset: train {args.train} ({len(train)} rows), test {' '.join(args.test)}")
    print(f"position model: {cal.identified[:N_DH].sum()} table parameters identified in {t_position:.2f} s")
    print(f"train {args.train}: {fmt(train_err['before'])} -> {fmt(train_err['after'])}  (RMSE MEAN MAX mm)")
    heads = ("nominal (before)", "position (after)", "drawstring", "+compliance")
    print(f"{'held-out':10}" + "".join(f"{h:>22}" for h in heads))
    for name in [*args.test, "pooled"]:
        row = [
            fmt(pooled({name: results[k][name]}) if name != "pooled" else pooled(results[k]))
            for k in ("nominal", "position", "drawstring", "compliance")
        ]
        label = f"{name} ({len(tests[name][0])})" if name != "pooled" else "pooled"
        print(f"{label:10}" + "".join(f"{r:>22}" for r in row))
    names = [f"J{j + 1}" for j in COMPLIANT_JOINTS]
    comp_txt = ", ".join(f"{n} {c:.2f}" for n, c in zip(names, compliance, strict=True))
    print(f"compliances [urad/(N m)]: {comp_txt}; train {fmt(train_err['compliance'])}")
    if args.json:
        summary = {
            "before": pooled(results["nominal"]),
            "after": pooled(results["position"]),
            "train": args.train,
            "test": args.test,
            "drawstring_after": pooled(results["drawstring"]),
            "compliance_after": pooled(results["compliance"]),
        }
        print(json.dumps(summary))
    return 0


if __name__ == "__main__":
    sys.exit(main())
