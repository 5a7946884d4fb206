"""Figures as PNG files (matplotlib, no display needed): the method comparison of the paper's
Fig. 2 (accuracy bars) and Fig. 3 (training curves, time), a measurement plan (Fig. 5a) and a
calibration's residuals with its predicted workspace error. Each draws into the file it is given
(``station.formats.base.write_outputs`` gives a temporary one and renames it with the others)."""

from __future__ import annotations

from pathlib import Path

import matplotlib
import numpy as np

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
    _bars_with_bound(ax_lines, rows, "predicted workspace error [mm RMS]")
    ax_lines.set_title("(b) gauge-line placements")
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def rms_per_placement(errors: np.ndarray, placement: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The placements (ascending ids; -1: rows on no line) and the RMS of ``errors`` [mm] on each."""
    ids = np.unique(placement)
    return ids, np.array([np.sqrt(np.mean(errors[placement == i] ** 2)) for i in ids])


def calibration_figure(data: dict, path: Path) -> None:
    """Three panels from a calibration (``station.jobs.calibration.residual_rows``): (a) each
    sample row's error [mm] before and after, down-weighted rows marked; (b) the RMS error per
    placement (gauge line) before and after; (c) the RMS error of the training and hold-out rows
    before and after next to the predicted workspace error and its 95 % bound."""
    fig, (ax_rows, ax_lines, ax_ws) = plt.subplots(1, 3, figsize=(16, 4.8), width_ratios=(2, 1, 1))
    rows = data["rows"]
    before, after = np.abs(rows["before_mm"]), np.abs(rows["after_mm"])
    placement = np.asarray(rows["placement"])  # -1: rows on no line
    index = np.arange(len(before))
    ax_rows.semilogy(index, before, ".", color="0.6", label="before (nominal table)")
    ax_rows.semilogy(index, after, ".", color="C0", label="after")
    down = np.asarray(data["downweighted"], int)
    if down.size:
        ax_rows.semilogy(down, after[down], "x", color="C3", markersize=9, label="down-weighted")
    ax_rows.set_xlabel("sample row")
    ax_rows.set_ylabel(f"|{data['kind']} error| [mm]")
    ax_rows.set_title("(a) error per sample")
    ax_rows.legend(fontsize=8)
    width, lowest = 0.4, np.inf
    for k, (errors, label, colour) in enumerate(((before, "before", "0.6"), (after, "after", "C0"))):
        ids, rms = rms_per_placement(errors, placement)
        ax_lines.bar(np.arange(len(ids)) + (k - 0.5) * width, rms, width, color=colour, label=label)
        lowest = min(lowest, *rms)
    names = [f"line {i}" if i >= 0 else "no line" for i in ids] if data["kind"] == "drawstring" else ["all"]
    ax_lines.set_xticks(range(len(ids)), names)
    ax_lines.set_yscale("log")
    ax_lines.set_ylim(bottom=lowest / 3)  # a log bar's foot is arbitrary: half a decade below the least
    ax_lines.set_ylabel("RMS error [mm]")
    ax_lines.set_title("(b) error per placement")
    ax_lines.legend(fontsize=8)
    bars = [
        (f"{part} {when}", {"predicted_rmse_mm": data[when][part]["rmse_mm"]})
        for part in ("train", "holdout")
        for when in ("before", "after")
        if part in data[when]
    ]
    bars.append(("workspace predicted", data["workspace"]))
    colours = [{"before": "0.6", "after": "C0"}.get(name.split()[-1], "C1") for name, _ in bars]
    _bars_with_bound(ax_ws, bars, "RMS error [mm]", colours)
    ax_ws.set_title("(c) rows fitted, workspace predicted")
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def _bars_with_bound(ax, rows: list[tuple[str, dict]], ylabel: str, colours: list | None = None) -> None:
    """One bar per ``(label, promise)`` of its ``predicted_rmse_mm`` [mm] (in ``colours`` where
    given, else labelled "expected"), a black mark at its ``predicted_rmse_95_mm`` where it has
    one; log scale."""
    xs = range(len(rows))
    heights = [p["predicted_rmse_mm"] for _, p in rows]
    ax.bar(xs, heights, color=colours, label=None if colours else "expected")
    bounds = [(x, p["predicted_rmse_95_mm"]) for x, (_, p) in enumerate(rows) if "predicted_rmse_95_mm" in p]
    if bounds:
        ax.scatter(*zip(*bounds, strict=True), color="k", marker="_", s=400, label="95 %")
    ax.set_xticks(list(xs), [name for name, _ in rows], rotation=45)
    ax.set_yscale("log")
    ax.set_ylim(bottom=min(heights) / 3)
    ax.set_ylabel(ylabel)
    ax.legend()


VERDICT_COLOURS = {"holds": "C2", "drifted": "C3", "consistent": "C0", "doubtful": "C1", "inconsistent": "C3"}


def verification_figure(data: dict, path: Path) -> None:
    """Two panels from ``station verify`` (``VerifyOutcome.row_errors``): (a) each sample's error
    [mm] with the table held, coloured by gauge line; (b) the RMS error per line, the verdict and the
    parameters most likely moved in the title."""
    fig, (ax_rows, ax_lines) = plt.subplots(1, 2, figsize=(13, 4.8), width_ratios=(2, 1))
    errors, placement = np.asarray(data["error_mm"]), np.asarray(data["placement"])
    lines = data["kind"] == "drawstring"
    names = {i: (f"line {i}" if i >= 0 else "no line") if lines else "all rows" for i in np.unique(placement)}
    size = 5 if len(errors) < 200 else 2
    for k, lid in enumerate(np.unique(placement)):
        rows = np.flatnonzero(placement == lid)
        ax_rows.plot(rows, errors[rows], "o", ms=size, color=f"C{k}", label=names[lid])
    ax_rows.axhline(0.0, color="0.5", lw=0.8)
    ax_rows.set_xlabel("sample row")
    ax_rows.set_ylabel(f"{data['kind']} error, table held [mm]")
    ax_rows.set_title(f"(a) error per sample: RMSE {data['rmse_mm']:.4f} mm")
    ax_rows.legend(fontsize=8)
    ids, rms = rms_per_placement(np.abs(errors), placement)
    ax_lines.bar(range(len(ids)), rms, color=VERDICT_COLOURS[data["verdict"]], label=data["verdict"])
    # what an unchanged robot would leave, in mm: the residual scaled by expected / observed ratio
    unchanged = data["rmse_mm"] * data["expected_ratio"] / data["noise_ratio"]
    ax_lines.axhline(unchanged, color="k", ls="--", label=f"unchanged robot ~{unchanged:.3g} mm")
    ax_lines.legend(fontsize=8)
    ax_lines.set_xticks(range(len(ids)), [names[i] for i in ids])
    ax_lines.set_ylabel("RMS error [mm]")
    ax_lines.set_title(
        f"(b) {data['verdict']}: {data['noise_ratio']:.2f} x stated noise "
        f"({data['expected_ratio']:.2f} expected)"
    )
    likely = ", ".join(f"{p['param']} {p['change']:+.3g} {p['unit']}" for p in data["likely"][:3])
    if likely:
        fig.suptitle(f"most likely moved: {likely}", color="C3")
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def history_figure(robot: str, records: list[dict], moved: list[dict], path: Path) -> None:
    """A robot's history (``station history ROBOT --plot``): each record's RMSE [mm] at its time,
    one series per command (calibrations circles, verifications squares) and verdict (colour), dates
    below as matplotlib's concise date axis; the calibrations that showed a flagged move ringed,
    the latest ``HISTORY_NOTES`` moves listed. Text drawn as given (no mathtext)."""
    import matplotlib.dates as mdates

    fig, ax = plt.subplots(figsize=(11, 4.8))
    when = np.array([_utc(r["time_utc"]) for r in records], dtype="datetime64[s]")
    rmse = np.array([np.nan if r["rmse_mm"] is None else r["rmse_mm"] for r in records], float)
    ms = float(np.clip(10 * np.sqrt(50 / max(len(records), 50)), 3, 10))
    markers = {"calibrate": "o", "verify": "s"}
    for (command, verdict), rows in _series(records).items():
        colour = VERDICT_COLOURS.get(verdict, "0.4")
        ax.plot(when[rows], rmse[rows], markers.get(command, "^"), color=colour, ms=ms, ls="none")
    for command, marker in markers.items():
        if any(r["command"] == command for r in records):
            ax.plot([], [], marker, color="0.4", ls="none", label=command)
    for verdict, colour in VERDICT_COLOURS.items():
        if any(r["verdict"] == verdict for r in records):
            ax.plot([], [], "D", color=colour, ls="none", label=verdict)
    _history_moves(ax, records, moved, when, np.nan_to_num(rmse), ms)
    if when.max() - when.min() < np.timedelta64(1, "h"):  # records of one session: an hour, not years
        middle = when.min() + (when.max() - when.min()) / 2
        ax.set_xlim(middle - np.timedelta64(30, "m"), middle + np.timedelta64(30, "m"))
    locator = mdates.AutoDateLocator()
    ax.xaxis.set_major_locator(locator)
    ax.xaxis.set_major_formatter(mdates.ConciseDateFormatter(locator))
    ax.set_xlabel("time (UTC)")
    ax.set_ylabel("RMSE [mm] (calibrate: training fit; verify: new samples)")
    ax.set_title(f"robot {robot}: {len(records)} records", parse_math=False)
    ax.legend(fontsize=8, loc="upper left", bbox_to_anchor=(1.01, 1.0))
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


HISTORY_NOTES = 8
"""How many flagged moves ``history_figure`` lists (the latest); the others are ringed only."""


def _utc(text: str):
    """An ISO 8601 time as a naive UTC datetime (one without a zone is taken as UTC)."""
    from datetime import datetime, timezone

    t = datetime.fromisoformat(text)
    return t.astimezone(timezone.utc).replace(tzinfo=None) if t.tzinfo else t


def _series(records: list[dict]) -> dict[tuple, np.ndarray]:
    """Row indices of the records per (command, verdict)."""
    keys = [(r["command"], r["verdict"]) for r in records]
    return {key: np.array([k for k, x in enumerate(keys) if x == key]) for key in dict.fromkeys(keys)}


def _history_moves(ax, records: list[dict], moved: list[dict], when, rmse, ms: float) -> None:
    """Ring every calibration that showed a flagged move (one call); list the latest few beside
    the legend (record, date, parameter, change)."""
    from calib.params import display_unit

    index = {r["id"]: k for k, r in enumerate(records)}
    rows = np.array(sorted({index[m["record"]] for m in moved}), int)
    if not len(rows):
        return
    ring = {"mfc": "none", "mec": "C3", "mew": 1.5, "ms": max(9.0, 1.7 * ms), "ls": "none", "zorder": 3}
    ax.plot(when[rows], rmse[rows], "o", label="moved", **ring)
    named = moved[::-1][:HISTORY_NOTES]
    lines = [f"moved (latest {len(named)} of {len(moved)}):" if len(moved) > len(named) else "moved:"]
    lines += [
        f"#{m['record']} {m['time_utc'][:10]} {m['param']} {m['change']:+.3g} {display_unit(m['param'])[1]} "
        f"({m['sigmas']:.1f} sigma)"
        for m in named
    ]
    ax.text(
        1.01,
        0.5,
        "\n".join(lines),
        transform=ax.transAxes,
        va="top",
        fontsize=8,
        color="C3",
        parse_math=False,
    )
