"""The paper's experiment (Tables III-IV) on the simulated HSR-JR680, with the workspace error the
paper could not measure.

Per seed: a world with one gauge-block line (``World.create(seed, n_lines=1)``), 200 training and
50 hold-out samples on that line, the rough setup a person would measure; every method of
``calib.baselines`` from the common start (``station.jobs.comparison.compare``, default budgets), then
the workspace error: distance between each method's and the true TCP over 1,000 random
configurations within the joint limits, after re-registering the base (``aligned_errors``).
Figures are means over the seeds with their standard errors.

    python benchmarks/paper_reproduction.py [--seeds 5] [--out benchmarks/RESULTS-compare.md]
"""

from __future__ import annotations

import argparse
import sys
import tempfile
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from calib.kinematics import dh_table, tcp_position  # noqa: E402
from calib.metrics import aligned_errors  # noqa: E402
from sim_fixtures.scenario import write_scenario  # noqa: E402
from station.formats.samples import load_samples
from station.formats.tables import (
    load_robot,
    load_setup,  # noqa: E402
)
from station.jobs.comparison import COMPARED, LABELS, compare  # noqa: E402

# The paper's Table III (RMSE, MEAN, MAX [mm]) and Table IV (time [s], iterations): a real robot.
PAPER = {
    "before": (2.58, 2.49, 4.50, None, None),
    "pso": (0.72, 0.65, 1.53, 52.53, 50),
    "ekf": (0.91, 0.81, 1.81, 16.0, 12),
    "ukf": (0.87, 0.78, 1.73, 22.3, 20),
    "gn": (0.62, 0.53, 1.27, 65.19, 70),
    "sa": (0.76, 0.65, 1.46, 66.96, 65),
    "pf": (0.81, 0.70, 1.61, 18.2, 16),
    "de": (0.66, 0.56, 1.38, 61.56, 56),
    "lmlc": (0.60, 0.51, 1.10, 36.32, 10),
    "mcs-lmlc": (0.56, 0.46, 0.91, 32.31, 2),
}


def one_seed(seed: int, folder: Path, methods: tuple[str, ...]) -> dict[str, dict]:
    """Per method: hold-out RMSE/MEAN/MAX, workspace RMS/max [mm], time [s], iterations."""
    sc = write_scenario(folder, seed=seed, n_lines=1, n_per_line=200, n_holdout_per_line=50)
    robot = load_robot(sc.robot)
    comp = compare(
        load_samples(sc.samples),
        robot,
        load_setup(sc.setup),
        setup_where=str(sc.setup),
        holdout=load_samples(sc.holdout),
        methods=methods,
    )
    q_deg = sc.world.random_configurations(1000, np.random.default_rng(seed + 7))
    p_true = sc.world.true_tcp_mm(q_deg)
    tool = np.asarray(robot.tool_mm, float)

    def workspace(x):
        err = aligned_errors(tcp_position(dh_table(x), np.radians(q_deg), tool), p_true)
        return float(np.sqrt(np.mean(err**2))), float(err.max())

    rows = [("before", comp.report["before"], comp.x0)]
    rows += [(e["name"], e, r.x) for e, r in zip(comp.report["methods"], comp.results, strict=True)]
    out = {}
    for name, entry, x in rows:
        ws_rms, ws_max = workspace(x)
        out[name] = {
            "rmse": entry["holdout"]["rmse_mm"],
            "mean": entry["holdout"]["mean_mm"],
            "max": entry["holdout"]["max_mm"],
            "ws_rms": ws_rms,
            "ws_max": ws_max,
            "time": entry.get("time_s", np.nan),
            "iters": entry.get("iterations", np.nan),
        }
    return out


def mean_se(values) -> tuple[float, float]:
    v = np.asarray(values, float)
    return float(v.mean()), float(v.std(ddof=1) / np.sqrt(v.size)) if v.size > 1 else float("nan")


def fmt(values, digits=3) -> str:
    m, se = mean_se(values)
    return "n/a" if np.isnan(m) else f"{m:.{digits}f} ± {se:.{digits}f}"


def tables(runs: list[dict], seeds: list[int]) -> str:
    """Markdown: ours (simulation) beside the paper's (a real robot), then the done-criterion check."""
    names = list(runs[0])
    head = (
        "| method | ours: hold-out RMSE | MEAN | MAX | workspace RMS | workspace MAX | time s | iterations "
        "| paper (real robot): RMSE | MEAN | MAX | time s | iterations |\n|" + "---|" * 13
    )
    lines = [head]
    for n in names:
        col = {k: [r[n][k] for r in runs] for k in runs[0][n]}
        paper = " | ".join("" if v is None else f"{v}" for v in PAPER[n])
        lines.append(
            f"| {LABELS.get(n, n)} | {fmt(col['rmse'])} | {fmt(col['mean'])} | {fmt(col['max'])} "
            f"| {fmt(col['ws_rms'])} | {fmt(col['ws_max'])} | {fmt(col['time'], 2)} | {fmt(col['iters'], 0)} "
            f"| {paper} |"
        )
    lines.append("")
    lines.append(
        "Done-criterion (LMLC at least as accurate on hold-out as each baseline within two standard errors;"
    )
    lines.append("paired differences baseline - LMLC of hold-out RMSE over the seeds, mm):")
    lines.append("")
    for n in names:
        if n in ("before", "lmlc", "mcs-lmlc"):
            continue
        diff = [r[n]["rmse"] - r["lmlc"]["rmse"] for r in runs]
        m, se = mean_se(diff)
        verdict = "holds" if m > -2 * se else "FAILS: the baseline is better"
        lines.append(f"- {LABELS[n]}: {m:+.4f} ± {se:.4f} -> {verdict}")
    lines.append("")
    lines.append(f"Seeds {seeds}.")
    return "\n".join(lines)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", type=int, default=5)
    ap.add_argument("--out", type=Path, help="append the markdown here")
    ap.add_argument("--methods", default=",".join(COMPARED), help="comma-separated subset (lmlc required)")
    args = ap.parse_args()
    methods = tuple(args.methods.split(","))
    seeds = list(range(args.seeds))
    runs = []
    with tempfile.TemporaryDirectory() as tmp:
        for seed in seeds:
            runs.append(one_seed(seed, Path(tmp) / f"seed{seed}", methods))
            print(f"seed {seed} done: lmlc hold-out {runs[-1]['lmlc']['rmse']:.4f} mm", flush=True)
    text = "## Paper reproduction (simulated JR680, one line, 200 samples)\n\n" + tables(runs, seeds)
    print(text)
    if args.out:
        with args.out.open("a") as fh:
            fh.write(text + "\n\n")


if __name__ == "__main__":
    main()
