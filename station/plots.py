"""Figures as PNG files (matplotlib, no display needed): the method comparison of the paper's
Fig. 2 (accuracy bars) and Fig. 3 (training curves, time)."""

from __future__ import annotations

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
