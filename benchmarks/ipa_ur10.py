"""UR10 on real laser-tracker data (IPA robot-accuracy dataset, Landgraf et al., CASE 2021).

Every model is trained on one series through the station's own calibration (``calibrate_samples``,
what ``station calibrate`` runs) and validated on the others. Every series was measured from its
own tracker placement with its own probe mounting, so each held-out series is first *registered*:
its base-to-tracker transform and probe offset are fitted with the robot held (table and terms),
the same way for the nominal robot and the corrected one. The figures are the distances
|measured - model| [mm] of the held-out rows after that registration, per series and pooled.

- position path: the tracker positions, each ``--model`` (geometric, compliance, full, auto; auto is
  ``station calibrate``'s default and chooses by cross-validation on the training series alone);
- drawstring path: the tracker positions turned into drawstring readings from a chosen anchor
  (0.02 mm noise), no gauge lines: what a drawstring station gets, same models;
- thermal: a linear thermal expansion of every link length, ``k (T - T_train)``, fitted on the
  training series beside the auto model (one Gauss-Newton step with every unknown) and measured
  on the held-out series, which are registered again with it;
- what is left: the auto model's training residual regressed on the first three harmonics of every
  joint's angle (a ridge fit, ``RIDGE`` of the features' mean square), cross-validated on 5
  interleaved folds of the training rows (every fifth row): how much of it a smooth function of
  the joint angles could still predict among the poses measured. Blocked folds would ask a
  37-coefficient fit to extrapolate to a region it never saw (train D: 1.3e7 mm).

``--all-splits`` runs every "train one series, test the other three" split and prints, after each
split's table, one line per split: every model's pooled held-out RMSE and the terms auto chose.

Usage: ``python benchmarks/ipa_ur10.py --data DIR [--train B] [--test C D | --all-splits] [--json]``.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from calib.calibrate import WithPrior  # noqa: E402
from calib.kinematics import A, D, dh_table, tcp_jacobian  # noqa: E402
from calib.metrics import error_metrics  # noqa: E402
from calib.position import PositionModel, PositionSamples, register  # noqa: E402
from sim_fixtures.world import Noise  # noqa: E402
from station.formats.ipa import IpaSeries, probe_file_for, read_probe_mm, read_series  # noqa: E402
from station.formats.samples import Samples  # noqa: E402
from station.formats.tables import SetupDrawstring, SetupFile, load_robot  # noqa: E402
from station.jobs.calibration import CalibrationOutcome, calibrate_samples  # noqa: E402
from station.jobs.terms import MODELS  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
SERIES = {
    "A": "Series_A/measurements_grid.csv",
    "B": "Series_B/measurements_joint_configurations.csv",
    "C": "Series_C/measurements_random_poses.csv",
    "D": "Series_D/measurements_iso_cubes.csv",
}
DRAWSTRING_SIGMA_MM = Noise().length_mm  # the simulated drawstring's reading noise
ANCHOR_OFFSET_MM = np.array([500.0, 300.0, -1200.0])  # anchor below and beside the workspace centre
DRAWSTRING_MODELS = ("geometric", "compliance", "auto")
HARMONIC_ORDERS = 3
RIDGE = 1e-3
"""Ridge weight of the "what is left" regression, relative to the mean square of its features."""


@dataclass(frozen=True)
class Series:
    """A series as the benchmark uses it: the rows, the probe's start from the dataset's file."""

    ipa: IpaSeries
    probe: np.ndarray

    @property
    def samples(self) -> PositionSamples:
        return PositionSamples(self.ipa.q_rad, self.ipa.position_mm)


def load(data: Path, name: str) -> Series:
    series = read_series(data / SERIES[name])
    return Series(series, read_probe_mm(probe_file_for(series.path)))


def position_set(series: Series) -> Samples:
    """The series as ``station import-ipa`` writes it: a position set."""
    n = len(series.ipa)
    q_deg = np.degrees(series.ipa.q_rad)
    return Samples(
        str(series.ipa.path), "position", q_deg, series.ipa.position_mm, np.full(n, np.nan), np.full(n, -1)
    )


def drawstring_set(train: Series, geometric: CalibrationOutcome, robot, rng):
    """Drawstring readings from the tracker points, a rough setup and the robot with the cable tied
    at the probe (on joint 6's axis at the registered probe length); the anchor's rough place
    (base frame) comes from the nominal registration, +-30 mm."""
    before = geometric.calibration.before.x
    anchor_tracker = train.ipa.position_mm.mean(axis=0) + ANCHOR_OFFSET_MM
    offset = 500.0
    length = np.linalg.norm(train.ipa.position_mm - anchor_tracker, axis=1) - offset
    length += rng.normal(0, DRAWSTRING_SIGMA_MM, length.size)
    rot, t = geometric.model.tracker_from_base(before)
    anchor_base = rot.T @ (anchor_tracker - t) + rng.uniform(-30, 30, 3)
    setup = SetupFile(
        drawstring=SetupDrawstring(
            anchor_mm=list(anchor_base),
            length_offset_mm=offset + rng.uniform(-8, 8),
            sigma_mm=DRAWSTRING_SIGMA_MM,
        )
    )
    n = len(train.ipa)
    samples = Samples(
        "drawstring", "drawstring", np.degrees(train.ipa.q_rad), length, np.full(n, np.nan), np.full(n, -1)
    )
    tool = [0.0, 0.0, float(geometric.model.probe(before)[2])]
    return samples, setup, robot.model_copy(update={"tool_mm": tool})


def held_out_errors(
    tests: dict[str, Series], outcome: CalibrationOutcome | None, nominal
) -> dict[str, np.ndarray]:
    """Per test series, the registered position errors [mm] with the outcome's table and terms held
    (the nominal table without terms where ``outcome`` is None)."""
    out = {}
    for name, series in tests.items():
        if outcome is None:
            model, fit = register(PositionModel(series.samples, nominal, series.probe), nominal)
        else:
            x, terms = outcome.calibration.x, outcome.model.terms
            values = outcome.model.term_values(x)
            model, fit = register(
                PositionModel(series.samples, nominal, series.probe, terms=terms), dh_table(x), values
            )
        out[name] = model.row_error_mm(fit.x)
    return out


# -- thermal -------------------------------------------------------------------------------------
def thermal_field(model: PositionModel, x: np.ndarray, delta_t: np.ndarray) -> np.ndarray:
    """What ``k = 1/K`` of linear thermal expansion of every link length does to each measured point,
    tracker frame [mm] (N, 3): ``R sum_i dp/dl_i l_i (T - T_ref)``, the lengths' columns of the TCP
    Jacobian at the angles the links take."""
    dh = dh_table(x)
    _, jac = tcp_jacobian(dh, model.joints(x), model.probe(x))
    lengths = [4 * j + c for j in range(6) for c in (D, A)]
    rot, _ = model.tracker_from_base(x)
    return (jac[:, :, lengths] @ dh.ravel()[lengths]) @ rot.T * delta_t[:, None]


def thermal_coefficient(outcome: CalibrationOutcome, temperature: np.ndarray) -> tuple[float, float]:
    """The expansion coefficient [1/K] fitted beside every unknown of the calibration (one
    Gauss-Newton step from it, its robust weights), and its standard deviation."""
    model, cal = outcome.model, outcome.calibration
    prior = WithPrior(model, model.x0)
    r, jac = prior.residuals_and_jacobian(cal.x)
    column = np.zeros(r.size)
    column[: 3 * len(model.samples)] = (
        thermal_field(model, cal.x, temperature - temperature.mean()).ravel() / model.sigma
    )
    w = cal.after.weights
    a = np.column_stack([jac[:, cal.identified], column]) * w[:, None]
    step, *_ = np.linalg.lstsq(a, -r * w, rcond=None)
    cov = np.linalg.pinv(a.T @ a) * np.mean((r * w + a @ step) ** 2)
    return float(step[-1]), float(np.sqrt(cov[-1, -1]))


def thermal_held_out(tests, outcome, k: float, t_ref: float) -> dict[str, np.ndarray]:
    """Held-out errors with the expansion ``k`` at each row's temperature: each series registered,
    its measured points corrected by the expansion in that registration's frame, registered again."""
    out = {}
    x, terms = outcome.calibration.x, outcome.model.terms
    values = outcome.model.term_values(x)
    for name, series in tests.items():
        dh0 = outcome.model.dh0
        model, fit = register(
            PositionModel(series.samples, dh0, series.probe, terms=terms), dh_table(x), values
        )
        shift = k * thermal_field(model, fit.x, series.ipa.temperature_c - t_ref)
        corrected = PositionSamples(series.ipa.q_rad, series.ipa.position_mm - shift)
        model, fit = register(PositionModel(corrected, dh0, series.probe, terms=terms), dh_table(x), values)
        out[name] = model.row_error_mm(fit.x)
    return out


# -- what is left ----------------------------------------------------------------------------------
def residual_predictability(outcome: CalibrationOutcome) -> tuple[float, float]:
    """RMS of the training residual (3-D, base frame) [mm], and of what is left of it when each fold
    is predicted by a least-squares fit, on the other folds, of the first ``HARMONIC_ORDERS``
    harmonics of every joint's angle (a ridge fit, interleaved 5-fold: row r in fold r mod 5)."""
    model, x = outcome.model, outcome.calibration.x
    rot, _ = model.tracker_from_base(x)
    e = (model.samples.position - model.predicted_mm(x)) @ rot
    q = model.samples.q
    f = [np.ones(len(q))] + [
        fun(h * q[:, j]) for j in range(6) for h in range(1, HARMONIC_ORDERS + 1) for fun in (np.sin, np.cos)
    ]
    features = np.column_stack(f)
    ridge = RIDGE * np.mean(features**2) * len(q) * np.eye(features.shape[1])
    left = np.empty_like(e)
    for fold in range(5):
        rows = np.arange(fold, len(q), 5)
        fit = np.setdiff1d(np.arange(len(q)), rows)
        a = features[fit]
        coef = np.linalg.solve(a.T @ a + ridge, a.T @ e[fit])
        left[rows] = e[rows] - features[rows] @ coef
    return float(np.sqrt(np.mean(np.sum(e**2, axis=1)))), float(np.sqrt(np.mean(np.sum(left**2, axis=1))))


# -- output ----------------------------------------------------------------------------------------
def pooled(errors: dict[str, np.ndarray]) -> dict[str, float]:
    return error_metrics(np.concatenate(list(errors.values())))


def fmt(m: dict) -> str:
    return f"{m['rmse_mm']:.3f} / {m['mean_mm']:.3f} / {m['max_mm']:.3f}"


def terms_text(outcome: CalibrationOutcome) -> str:
    """The fitted terms with their sigmas and the error poses share the fit was weighted by."""
    terms = ", ".join(f"{n} {e.value:.4g} +- {e.sigma:.2g}" for n, e in outcome.report.terms.items()) or "-"
    d = outcome.calibration.discrepancy
    if d is None:
        return f"{terms}; white"
    return f"{terms}; weighted: {d.length_scale_deg:g} deg x {d.ratio:g}, log-likelihood +{d.loglik_gain:.0f}"


def run_split(data: Path, train_name: str, test_names: list[str], robot) -> dict:
    """Every model trained on ``train_name`` and measured on ``test_names``: the printed table's
    lines and the JSON summary."""
    rng = np.random.default_rng(0)
    train = load(data, train_name)
    tests = {name: load(data, name) for name in test_names}
    train_set = position_set(train)

    rows, outcomes, times = {}, {}, {}
    for kind in MODELS:
        t0 = time.perf_counter()
        outcomes[kind] = calibrate_samples(train_set, robot, None, terms=kind)
        times[kind] = time.perf_counter() - t0
    nominal = outcomes["geometric"].model.dh0
    rows["nominal (before)"] = held_out_errors(tests, None, nominal)
    for kind in MODELS:
        rows[f"position, --model {kind}"] = held_out_errors(tests, outcomes[kind], nominal)
    ds_samples, ds_setup, ds_robot = drawstring_set(train, outcomes["geometric"], robot, rng)
    for kind in DRAWSTRING_MODELS:
        t0 = time.perf_counter()
        outcomes[f"drawstring {kind}"] = calibrate_samples(ds_samples, ds_robot, ds_setup, terms=kind)
        times[f"drawstring {kind}"] = time.perf_counter() - t0
        rows[f"drawstring, --model {kind}"] = held_out_errors(tests, outcomes[f"drawstring {kind}"], nominal)

    auto = outcomes["auto"]
    t_ref = float(train.ipa.temperature_c.mean())
    k, k_sigma = thermal_coefficient(auto, train.ipa.temperature_c)
    rows["position, auto + thermal"] = thermal_held_out(tests, auto, k, t_ref)

    lines = [f"UR10, IPA dataset: train {train_name} ({len(train.ipa)} rows), test {' '.join(test_names)}"]
    lines.append(
        f"{'held-out RMSE / MEAN / MAX [mm]':34}"
        + "".join(f"{n + f' ({len(tests[n].ipa)})':>24}" for n in test_names)
        + f"{'pooled':>24}"
    )
    for label, errs in rows.items():
        cells = [fmt(pooled({n: errs[n]})) for n in test_names] + [fmt(pooled(errs))]
        lines.append(f"{label:34}" + "".join(f"{c:>24}" for c in cells))
    lines.append(f"training fit on {train_name} (RMSE [mm], time [s], terms):")
    for kind, outcome in outcomes.items():
        fit = outcome.report.after.train.rmse_mm
        lines.append(f"  {kind:22} {fit:.3f}  {times[kind]:6.1f} s  {terms_text(outcome)}")
    for kind in ("auto", "drawstring auto"):
        lines.append(f"{kind}: {cv_text(outcomes[kind], train_name)}")
    t_range = np.ptp(train.ipa.temperature_c)
    lines.append(
        f"thermal: k = {k * 1e6:.1f} +- {k_sigma * 1e6:.1f} ppm/K on {train_name} "
        f"(T {t_ref:.2f} deg C, range {t_range:.2f} K); test means "
        + ", ".join(f"{n} {s.ipa.temperature_c.mean():.2f}" for n, s in tests.items())
    )
    raw, left = residual_predictability(auto)
    lines.append(
        f"what is left: auto's residual on {train_name} {raw:.3f} mm RMS; after harmonics "
        f"1-{HARMONIC_ORDERS} of every joint, cross-validated: {left:.3f} mm"
    )
    summary = {
        "before": pooled(rows["nominal (before)"]),
        "after": pooled(rows["position, --model geometric"]),
        "train": train_name,
        "test": test_names,
        "drawstring_after": pooled(rows["drawstring, --model geometric"]),
        "drawstring_compliance_after": pooled(rows["drawstring, --model compliance"]),
        "compliance_after": pooled(rows["position, --model compliance"]),
        "default_after": pooled(rows["position, --model auto"]),
        "default_terms": list(auto.report.terms),
        "full_after": pooled(rows["position, --model full"]),
        "drawstring_default_after": pooled(rows["drawstring, --model auto"]),
        "drawstring_default_terms": list(outcomes["drawstring auto"].report.terms),
        "drawstring_default_warnings": list(outcomes["drawstring auto"].report.warnings),
        "thermal_after": pooled(rows["position, auto + thermal"]),
        "thermal_ppm_per_K": [k * 1e6, k_sigma * 1e6],
        "pooled": {label: pooled(errs)["rmse_mm"] for label, errs in rows.items()},
        "per_series": {
            label: {n: error_metrics(e)["rmse_mm"] for n, e in errs.items()} for label, errs in rows.items()
        },
    }
    return {"lines": lines, "summary": summary}


def cv_text(outcome: CalibrationOutcome, train_name: str) -> str:
    """The auto model's cross-validation in one line: folds, kept steps, the best left out."""
    cv = outcome.report.cross_validation
    if cv is None:
        return "no cross-validation (too few rows)"
    steps = " -> ".join(f"{r.added or 'table'} {r.rmse_mm:.4f}" for r in cv.rows if r.kept)
    last = [r for r in cv.rows if r.round == max(r.round for r in cv.rows) and not r.kept]
    best_left = max(last, key=lambda r: r.gain, default=None)
    rest = f"; best of the last round, not kept: {best_left.added} {best_left.gain:+.2%}" if best_left else ""
    left = "".join(f"; left {r.added}: {r.reason}" for r in cv.rows if r.reason)
    return (
        f"{cv.folds} folds ({cv.scheme}) on {train_name}, nominal {cv.nominal_rmse_mm:.4f}: "
        f"{steps}{rest}{left}"
    )


SPLIT_COLUMNS = {
    "nominal": "nominal (before)",
    "geometric": "position, --model geometric",
    "compliance": "position, --model compliance",
    "full": "position, --model full",
    "auto (default)": "position, --model auto",
    "drawstring geometric": "drawstring, --model geometric",
    "drawstring compliance": "drawstring, --model compliance",
    "drawstring auto (default)": "drawstring, --model auto",
}


def splits_table(results: list[dict]) -> list[str]:
    """The all-splits table (markdown): pooled held-out RMSE [mm] of every model per split, the
    terms auto chose on each path, and the mean over the splits."""
    head = ["train", "test", *SPLIT_COLUMNS, "auto's terms", "drawstring auto's terms"]
    out = ["| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
    means = {c: [] for c in SPLIT_COLUMNS}
    for r in results:
        s = r["summary"]
        cells = []
        for column, label in SPLIT_COLUMNS.items():
            value = s["pooled"][label]
            means[column].append(value)
            cells.append(f"{value:.3f}")
        terms = [_short(s["default_terms"]), _short(s["drawstring_default_terms"])]
        out.append(f"| {s['train']} | {' '.join(s['test'])} | " + " | ".join(cells + terms) + " |")
    out.append("| mean | | " + " | ".join(f"{np.mean(v):.3f}" for v in means.values()) + " | | |")
    return out


def _short(terms: list[str]) -> str:
    """Term names without their units: J2 compliance, J3 sin1, ..."""
    names = [t.replace("_urad_per_Nm", "").replace("_deg", "").replace(".", " ") for t in terms]
    return ", ".join(names) or "none"


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--data", type=Path, required=True, help="the ipa-robot-accuracy folder")
    p.add_argument("--train", default="B", choices=sorted(SERIES))
    p.add_argument("--test", nargs="+", default=["C", "D"], choices=sorted(SERIES))
    p.add_argument("--all-splits", action="store_true", help="train on each series, test on the other three")
    p.add_argument("--json", action="store_true", help="last stdout line: the pooled figures as JSON")
    args = p.parse_args(argv)
    robot = load_robot(ROOT / "configs/robots/ur10.toml")
    if args.all_splits:
        splits = [(t, [n for n in sorted(SERIES) if n != t]) for t in sorted(SERIES)]
    else:
        splits = [(args.train, args.test)]
    results = []
    for train_name, test_names in splits:
        results.append(run_split(args.data, train_name, test_names, robot))
        print("\n".join(results[-1]["lines"]), flush=True)
    if args.all_splits:
        print("pooled held-out RMSE [mm], every split:")
        print("\n".join(splits_table(results)))
    if args.json:
        summaries = [r["summary"] for r in results]
        print(json.dumps({s["train"]: s for s in summaries} if args.all_splits else summaries[0]))
    return 0


if __name__ == "__main__":
    sys.exit(main())
