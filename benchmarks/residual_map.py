"""The residual map (``calib.residual_map``) on the real UR10 (IPA robot-accuracy dataset).

Each table is the default ``station calibrate`` (``--model auto``, ``calibrate_samples``); the map
is fitted on that calibration's own rows (their residuals, base frame) and decides itself whether
it is used (cross-validated on interleaved folds of those rows).

- ``--split holdout``: series B with every 5th pose held out (row ``i`` with ``i mod 5 == 4``), the
  rest trained on; the held-out rows evaluated with the training fit's tracker placement and probe
  (the contract's ``--holdout``), table alone and table + map, and how many held-out rows lie
  inside the map's 95 % bound (``ResidualMap.predict``'s variance, chi-square with 3 degrees).
- ``--split series``: train on one series, test on the other three (registered with the robot held,
  as ``benchmarks/ipa_ur10.py``); with the map, each test series is registered, its points corrected
  by the map's prediction in that registration's frame, and registered again. Far from the training
  rows the map predicts nothing and the table stands alone.
- ``--split time``: the map's fit (cross-validation included) and a prediction at every row, on
  series A's 11,911 rows (the geometric table's residuals: the cost does not depend on them).

Usage: ``python benchmarks/residual_map.py --data DIR [--split holdout|series|time|all] [--json]``.
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import time
from pathlib import Path

for _key in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_key, "1")  # as ``station`` sets them (``station.cli.BLAS_THREADS``)

import numpy as np  # noqa: E402

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from benchmarks.ipa_ur10 import ROOT, SERIES, Series, load, position_set  # noqa: E402
from calib.kinematics import dh_table  # noqa: E402
from calib.position import PositionModel, PositionSamples, register  # noqa: E402
from calib.residual_map import ResidualMap, fit_map  # noqa: E402
from calib.shared_error import rms3  # noqa: E402
from station.formats.samples import Samples  # noqa: E402
from station.formats.tables import load_robot  # noqa: E402
from station.jobs.calibration import CalibrationOutcome, calibrate_samples  # noqa: E402

CHI2_3_95 = 7.8147
"""95 % quantile of the chi-square distribution with 3 degrees of freedom."""


def subset(samples: Samples, rows: np.ndarray) -> Samples:
    """The sample rows ``rows`` (a boolean mask) of ``samples``."""
    return Samples(
        samples.path, samples.kind, samples.q_deg[rows], samples.measured[rows], samples.dial_mm[rows],
        samples.line[rows],
    )  # fmt: skip


def base_residuals(model: PositionModel, x: np.ndarray) -> np.ndarray:
    """Measured minus modelled position (N, 3) [mm], turned into the base frame."""
    rot, _ = model.tracker_from_base(x)
    return (model.samples.position - model.predicted_mm(x)) @ rot


def residual_map_of(outcome: CalibrationOutcome) -> tuple[ResidualMap | None, float]:
    """The map of a calibration's own rows and the time [s] its fit took."""
    t0 = time.perf_counter()
    model, x = outcome.model, outcome.calibration.x
    found = fit_map(model.samples.q, base_residuals(model, x), dh_table(x), model.tcp_in_flange(x))
    return found, time.perf_counter() - t0


def map_text(found: ResidualMap | None, seconds: float) -> str:
    if found is None:
        return f"map off ({seconds:.2f} s)"
    angles, shared = found.angles, found.shared
    stages = [
        "angle errors off"
        if angles is None
        else f"angle errors of J1-J3 {angles.sigma_deg:g} deg over {angles.length_deg:g} deg",
        "shared error off"
        if shared is None
        else f"shared error {np.sqrt(3 * shared.shared_mm2):.3f} mm over {shared.length_scale_deg:g} deg",
    ]
    return (
        f"map: {'; '.join(stages)}; "
        f"cross-validated {found.table_cv_rmse_mm:.3f} -> {found.cv_rmse_mm:.3f} mm "
        f"({found.explained:.0%} of the mean square); fit {seconds:.2f} s"
    )


def holdout_split(data: Path, robot) -> dict:
    """Series B, every 5th pose held out: table alone and table + map on the held-out rows."""
    series = load(data, "B")
    samples = position_set(series)
    test = np.arange(len(samples)) % 5 == 4
    outcome = calibrate_samples(subset(samples, ~test), robot, None, terms="auto")
    found, seconds = residual_map_of(outcome)
    held = outcome.model.with_samples(PositionSamples(series.ipa.q_rad[test], series.ipa.position_mm[test]))
    error = base_residuals(held, outcome.calibration.x)
    out = {
        "rows": int(test.sum()),
        "table_mm": rms3(error),
        "map_mm": rms3(error),
        "map": map_text(found, seconds),
    }
    if found is not None:
        mean, variance = found.predict(held.samples.q)
        left = np.linalg.norm(error - mean, axis=1)
        out["map_mm"] = rms3(error - mean)
        out["inside_95"] = float(np.mean(left**2 <= CHI2_3_95 * variance))
    return out


def registered(series: Series, outcome: CalibrationOutcome, found: ResidualMap | None) -> np.ndarray:
    """A test series' position errors [mm] with the outcome's table and terms held; with a map, its
    points corrected by the map's prediction in the first registration's frame, then registered
    again."""
    x, terms = outcome.calibration.x, outcome.model.terms
    values, dh0 = outcome.model.term_values(x), outcome.model.dh0
    model, fit = register(PositionModel(series.samples, dh0, series.probe, terms=terms), dh_table(x), values)
    if found is None:
        return model.row_error_mm(fit.x)
    rot, _ = model.tracker_from_base(fit.x)
    shift = found.predict(series.ipa.q_rad)[0] @ rot.T
    corrected = PositionSamples(series.ipa.q_rad, series.ipa.position_mm - shift)
    model, fit = register(PositionModel(corrected, dh0, series.probe, terms=terms), dh_table(x), values)
    return model.row_error_mm(fit.x)


def series_split(data: Path, robot, train_name: str) -> dict:
    """Train on one series, test on the other three: pooled held-out RMSE [mm], table and map."""
    train = load(data, train_name)
    outcome = calibrate_samples(position_set(train), robot, None, terms="auto")
    found, seconds = residual_map_of(outcome)
    tests = [load(data, n) for n in sorted(SERIES) if n != train_name]
    table = np.concatenate([registered(s, outcome, None) for s in tests])
    mapped = np.concatenate([registered(s, outcome, found) for s in tests])
    rms = lambda e: float(np.sqrt(np.mean(e**2)))  # noqa: E731
    return {
        "train": train_name,
        "table_mm": rms(table),
        "map_mm": rms(mapped),
        "map": map_text(found, seconds),
    }


def timing(data: Path, robot) -> dict:
    """The map's fit and a prediction at every row on series A (geometric table's residuals)."""
    series = load(data, "A")
    outcome = calibrate_samples(position_set(series), robot, None, terms="geometric")
    error = base_residuals(outcome.model, outcome.calibration.x)
    x = outcome.calibration.x
    t0 = time.perf_counter()
    found = fit_map(series.ipa.q_rad, error, dh_table(x), outcome.model.tcp_in_flange(x))
    t1 = time.perf_counter()
    if found is not None:
        found.predict(series.ipa.q_rad)
    t2 = time.perf_counter()
    return {
        "rows": len(series.ipa),
        "fit_s": t1 - t0,
        "predict_all_s": t2 - t1,
        "map": map_text(found, t1 - t0),
    }


def holdout_lines(h: dict) -> list[str]:
    inside = h.get("inside_95", float("nan"))
    return [
        f"B, every 5th pose held out ({h['rows']} rows): table {h['table_mm']:.3f} mm, "
        f"table + map {h['map_mm']:.3f} mm, inside the 95 % bound {inside:.1%}",
        f"  {h['map']}",
    ]


def series_lines(splits: list[dict]) -> list[str]:
    out = []
    for s in splits:
        others = " ".join(n for n in sorted(SERIES) if n != s["train"])
        out.append(
            f"train {s['train']}, test {others}: table {s['table_mm']:.3f} mm, "
            f"table + map {s['map_mm']:.3f} mm"
        )
        out.append(f"  {s['map']}")
    table, mapped = (np.mean([s[k] for s in splits]) for k in ("table_mm", "map_mm"))
    return [*out, f"mean over the splits: table {table:.3f} mm, table + map {mapped:.3f} mm"]


def time_lines(t: dict) -> list[str]:
    return [
        f"A ({t['rows']} rows): map fit {t['fit_s']:.2f} s, "
        f"prediction at every row {t['predict_all_s']:.2f} s",
        f"  {t['map']}",
    ]


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--data", type=Path, required=True, help="the ipa-robot-accuracy folder")
    p.add_argument("--split", default="all", choices=("holdout", "series", "time", "all"))
    p.add_argument("--json", action="store_true", help="last stdout line: the figures as JSON")
    args = p.parse_args(argv)
    robot = load_robot(ROOT / "configs/robots/ur10.toml")
    out = {}
    if args.split in ("holdout", "all"):
        out["holdout"] = holdout_split(args.data, robot)
        print("\n".join(holdout_lines(out["holdout"])), flush=True)
    if args.split in ("series", "all"):
        out["series"] = [series_split(args.data, robot, name) for name in sorted(SERIES)]
        print("\n".join(series_lines(out["series"])), flush=True)
    if args.split in ("time", "all"):
        out["time"] = timing(args.data, robot)
        print("\n".join(time_lines(out["time"])), flush=True)
    if args.json:
        print(json.dumps(out))
    return 0


if __name__ == "__main__":
    sys.exit(main())
