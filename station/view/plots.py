"""Figures as PNG files (matplotlib, no display needed): the method comparison of the paper's
Fig. 2 (accuracy bars) and Fig. 3 (training curves, time), and a measurement plan (Fig. 5a)."""

from __future__ import annotations

import tempfile
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402  (after choosing the file-only backend)

METRICS = (("rmse_mm", "RMSE"), ("mean_mm", "MEAN"), ("max_mm", "MAX"))


def comparison_figure(report: dict, path: Path, labels: dict[str, str]) -> None:
    """Three panels from a ``station compare`` report: (a) RMSE / MEAN / MAX [mm] per method on the
    hold-out rows (training rows without them), nominal included; (b) each method's cost
    ``|r|^2 / 2`` per iteration (log scale); (c) wall time per method [s]."""
    part = "holdout" if "holdout" in report["before"] else "train"
    rows = [{"name": "before", **report["before"]}] + report["methods"]
    names = [
        labels.get(r["name"], r["name"]).split(" ")[0] if r["name"] != "before" else "nominal" for r in rows
    ]
    fig, (ax_acc, ax_curve, ax_time) = plt.subplots(1, 3, figsize=(16, 4.8))
    width = 0.27
    for k, (key, title) in enumerate(METRICS):
        xs = [i + (k - 1) * width for i in range(len(rows))]
        ax_acc.bar(xs, [r[part][key] for r in rows], width, label=title)
    ax_acc.set_xticks(range(len(rows)), names, rotation=45)
    ax_acc.set_yscale("log")
    ax_acc.set_ylabel(f"drawstring error on {part} rows [mm]")
    ax_acc.set_title("(a) calibration accuracy")
    ax_acc.legend()
    for r in report["methods"]:
        if r["history"]:
            ax_curve.plot(
                range(1, len(r["history"]) + 1), r["history"], label=labels.get(r["name"], r["name"])
            )
    ax_curve.set_xscale("log")
    ax_curve.set_yscale("log")
    ax_curve.set_xlabel("iteration")
    ax_curve.set_ylabel("cost |r|^2 / 2 (whitened)")
    ax_curve.set_title("(b) training curves")
    ax_curve.legend(fontsize=8)
    ax_time.bar(names[1:], [r["time_s"] for r in report["methods"]])
    ax_time.set_ylabel("wall time [s]")
    ax_time.set_title("(c) time cost")
    ax_time.tick_params(axis="x", rotation=45)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def plan_figure(report: dict, path: Path) -> None:
    """Two panels from a ``station plan`` report: (a) the O1 index against the number of
    configurations, the chosen N marked; (b) predicted workspace error per line placement."""
    fig, (ax_index, ax_lines) = plt.subplots(1, 2, figsize=(12, 4.5))
    curve, n = report["selection"]["curve"], report["selection"]["n"]
    ax_index.plot(curve["n"], curve["O1"], "o-")
    ax_index.axvline(n, color="k", linestyle="--", label=f"chosen N = {n}")
    ax_index.set_xlabel("configurations N")
    ax_index.set_ylabel("O1 (best random subsets)")
    ax_index.set_title("(a) observability index")
    ax_index.legend()
    rows = [("+".join(map(str, p["lines"])), p) for p in report["placements"]]
    rows += [(f"+next {k + 1}", p) for k, p in enumerate(report["next"])]
    xs = range(len(rows))
    ax_lines.bar(xs, [p["predicted_rmse_mm"] for _, p in rows], label="expected")
    ax_lines.scatter(
        xs, [p["predicted_rmse_95_mm"] for _, p in rows], color="k", marker="_", s=400, label="95 %"
    )
    ax_lines.set_xticks(list(xs), [name for name, _ in rows], rotation=45)
    ax_lines.set_yscale("log")
    ax_lines.set_ylabel("predicted workspace error [mm RMS]")
    ax_lines.set_title("(b) gauge-line placements")
    ax_lines.legend()
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def write_png(draw, report: dict, path: Path) -> None:
    """``draw(report, file)`` into a temporary file beside ``path``, then rename: a failed plot
    leaves no half file."""
    with tempfile.NamedTemporaryFile(dir=path.parent, suffix=".png", delete=False) as tmp:
        tmp_path = Path(tmp.name)
    try:
        draw(report, tmp_path)
        tmp_path.replace(path)
    finally:
        tmp_path.unlink(missing_ok=True)
