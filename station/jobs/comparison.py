"""Every calibrator of the paper's Table II on the same samples: the data behind ``station compare``.

One common start for M1-M8: the pipeline's setup-only fit of the nominal table (the contract's
"before") and its identification of the free parameters (``calib.calibrate.calibrate``). Each
method then runs from that point over those parameters on all samples; its ``time_s`` covers only
its own search. M9 (``mcs-lmlc``) is the calibration service's MCS-LMLC
(``station.jobs.calibration.mcs_lmlc``): its time includes the selection and its own setup fit; its
metrics, like everyone's, cover all training rows.
"""

from __future__ import annotations

import time
from dataclasses import dataclass

import numpy as np

from calib.baselines import BaselineOptions, MethodResult, run_method
from calib.calibrate import calibrate
from calib.methods import ALL_METHODS
from station.formats.samples import Samples
from station.formats.tables import RobotFile, SetupFile
from station.jobs.calibration import build_model, check_enough, holdout_model, mcs_lmlc, metrics

LABELS = {
    "pso": "M1 PSO",
    "ekf": "M2 EKF",
    "ukf": "M3 UKF",
    "gn": "M4 LS (Gauss-Newton)",
    "sa": "M5 SA",
    "pf": "M6 PF",
    "de": "M7 DE",
    "lmlc": "M8 LMLC",
    "mcs-lmlc": "M9 MCS-LMLC",
}
COMPARED = ALL_METHODS


@dataclass
class Comparison:
    """The ``report`` (JSON-ready dict), each method's raw result and the common start ``x0``."""

    report: dict
    results: list[MethodResult]
    x0: np.ndarray


def compare(
    samples: Samples,
    robot: RobotFile,
    setup: SetupFile | None,
    *,
    setup_where: str = "setup",
    holdout: Samples | None = None,
    methods: tuple[str, ...] = COMPARED,
    options: BaselineOptions | None = None,
    progress=lambda message: None,
) -> Comparison:
    """Run ``methods`` on ``samples`` from the common start; metrics on training and hold-out rows.
    ``progress(message)`` hears of the common start and of each method as it finishes."""
    options = options or BaselineOptions()
    model = build_model(samples, robot, setup, setup_where)
    check_enough(model, samples.path)
    t0 = time.perf_counter()
    start = calibrate(model, options.calibration)
    progress(f"common start (setup fit, identification): {time.perf_counter() - t0:.1f} s")
    hold_model = holdout_model(model, holdout)
    results = []
    for k, m in enumerate(methods, 1):
        if m == "mcs-lmlc":
            results.append(_mcs_lmlc(model, options))
        else:
            results.append(run_method(m, model, start.before.x, start.identified, options))
        fit = metrics(model, None, results[-1].x).train.rmse_mm
        progress(f"{LABELS[m]} ({k}/{len(methods)}): {results[-1].time_s:.2f} s, training RMSE {fit:.4f} mm")
    free = np.asarray(model.names)[start.identified]
    report = {
        "kind": model.kind,
        "seed": options.seed,
        "before": metrics(model, hold_model, start.before.x).as_json(),
        "free": [robot.param_name(name) for name in free.tolist()],
        "methods": [
            {
                "name": r.method,
                **metrics(model, hold_model, r.x).as_json(),
                "time_s": round(r.time_s, 4),
                "iterations": r.iterations,
                "evaluations": r.nfev,
                "history": [float(c) for c in r.history],
            }
            for r in results
        ],
    }
    return Comparison(report, results, start.before.x)


def _mcs_lmlc(model, options: BaselineOptions) -> MethodResult:
    """M9 as one of the compared methods: the service's MCS-LMLC, timed as a whole."""
    t0 = time.perf_counter()
    _, cal = mcs_lmlc(model, options.calibration)
    elapsed = time.perf_counter() - t0
    r = model.residuals(cal.x)
    history = [it.cost for it in cal.after.history if it.accepted]
    return MethodResult("mcs-lmlc", cal.x, 0.5 * float(r @ r), len(history), np.array(history), 0, elapsed)


def table(report: dict) -> str:
    """The paper's Tables III-IV in one: RMSE / MEAN / MAX [mm] on training and hold-out rows, wall
    time and iterations, one row per method after the "before" row."""
    parts = ("train", "holdout") if "holdout" in report["before"] else ("train",)
    head = f"{'method':22}" + "".join(f"{p + ' RMSE':>14}{'MEAN':>9}{'MAX':>9}" for p in parts)
    lines = [head + f"{'time s':>10}{'iters':>7}"]
    rows = [{"name": "before", **report["before"]}] + report["methods"]
    for row in rows:
        cells = "".join(
            f"{row[p]['rmse_mm']:14.4f} {row[p]['mean_mm']:8.4f} {row[p]['max_mm']:8.4f}" for p in parts
        )
        tail = f"{row['time_s']:10.2f}{row['iterations']:7d}" if "time_s" in row else ""
        lines.append(f"{LABELS.get(row['name'], row['name']):22}{cells}{tail}")
    return "\n".join(lines)
