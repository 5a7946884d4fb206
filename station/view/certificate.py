"""The calibration certificate as one self-contained HTML page (``station report``): its pictures
drawn by matplotlib into PNGs embedded as ``data:`` URIs, its CSS inline (A4 print rules, so that a
browser's "save as PDF" is the PDF), no script, font or request beyond the page. Every text from a
report or the history is escaped (``html.escape``): a robot named ``<script>`` is text."""

from __future__ import annotations

import base64
import functools
import html
import io

import numpy as np

from station.jobs.certificate import CALIBRATION, Certificate, Instrument
from station.view.plots import VERDICT_COLOURS, _bars_with_bound, history_figure, plt

GOOD = {"consistent", "holds"}
"""Verdicts shown in green; any other in red (``doubtful``: amber)."""


def t(value) -> str:
    """Any value as escaped text (None: a dash)."""
    return "&ndash;" if value is None else html.escape(str(value), quote=True)


def when(iso: str | None) -> str:
    """An ISO 8601 time as ``2026-11-27 03:43 UTC`` (as given where it is not one)."""
    from datetime import datetime, timezone

    try:
        moment = datetime.fromisoformat(str(iso))
    except ValueError:
        return t(iso)
    if moment.tzinfo is not None:
        moment = moment.astimezone(timezone.utc)
    return moment.strftime("%Y-%m-%d %H:%M:%S UTC")


def mm(value, digits: int = 3) -> str:
    return "&ndash;" if value is None else f"{value:.{digits}f} mm"


def png_uri(draw) -> str:
    """The PNG ``draw(path_or_file)`` writes, as a ``data:`` URI."""
    buffer = io.BytesIO()
    draw(buffer)
    return "data:image/png;base64," + base64.b64encode(buffer.getvalue()).decode("ascii")


def _save(fig, out) -> None:
    fig.tight_layout()
    fig.savefig(out, format="png", dpi=130)
    plt.close(fig)


# -- the pictures ------------------------------------------------------------------------------
def lines_figure(lines: list[dict], noise_mm: float | None, out) -> None:
    """Each gauge line's residual after the fit (RMSE, mean, max) beside the stated reading noise."""
    fig, ax = plt.subplots(figsize=(7.2, 3.0))
    ids = [drawn(f"line {ln.get('id')}") for ln in lines]
    width = 0.26
    for k, (key, label, colour) in enumerate(
        (("rmse_mm", "RMSE", "C0"), ("mean_mm", "mean", "#7fb2d9"), ("max_mm", "max", "#c9d9e8"))
    ):
        values = [float(ln.get(key) or 0.0) for ln in lines]
        ax.bar(np.arange(len(lines)) + (k - 1) * width, values, width, color=colour, label=label)
    if noise_mm is not None:
        ax.axhline(noise_mm, color="k", ls="--", lw=1, label=f"stated noise {noise_mm:g} mm")
    ax.set_xticks(range(len(lines)), ids)
    ax.set_ylabel("residual after calibration [mm]")
    ax.legend(fontsize=8, loc="upper left", bbox_to_anchor=(1.01, 1.0))
    _save(fig, out)


def before_after_figure(before: dict, after: dict, out) -> None:
    """RMSE of the training and hold-out rows with the nominal table and with the corrected one."""
    parts = [p for p in ("train", "holdout") if before.get(p) and after.get(p)]
    names = {"train": "training rows", "holdout": "hold-out rows"}
    fig, ax = plt.subplots(figsize=(7.2, 3.0))
    width = 0.36
    for k, (fit, label, colour) in enumerate(((before, "nominal table", "0.6"), (after, "corrected", "C0"))):
        xs = np.arange(len(parts)) + (k - 0.5) * width
        values = [fit[p]["rmse_mm"] for p in parts]
        ax.bar(xs, values, width, color=colour, label=label)
        for x, v in zip(xs, values, strict=True):
            ax.annotate(f"{v:.3f}", (x, v), ha="center", va="bottom", fontsize=8)
    ax.set_xticks(range(len(parts)), [names[p] for p in parts])
    ax.set_yscale("log")
    ax.set_ylabel("RMSE [mm] (log)")
    ax.legend(fontsize=8, loc="upper left", bbox_to_anchor=(1.01, 1.0))
    _save(fig, out)


def workspace_figure(nominal_mm: float | None, workspace: dict, out) -> None:
    """The predicted RMS error over the workspace: the nominal table's and the calibrated one's, with
    its 95 % bound (black mark)."""
    fig, ax = plt.subplots(figsize=(7.2, 3.0))
    rows = [("calibrated table", {k: v for k, v in workspace.items() if v is not None})]
    colours = ["C0"]
    if nominal_mm is not None:
        rows.insert(0, ("nominal table", {"predicted_rmse_mm": nominal_mm}))
        colours.insert(0, "0.6")
    _bars_with_bound(ax, rows, "RMS error [mm] (log)", colours)
    ax.set_xlim(-0.8, len(rows) - 0.2)
    ax.tick_params(axis="x", rotation=0)
    for x, (_, p) in enumerate(rows):
        ax.annotate(
            f"{p['predicted_rmse_mm']:.3f}", (x, p["predicted_rmse_mm"]), ha="center", va="bottom", fontsize=8
        )
    ax.legend(fontsize=8, loc="upper left", bbox_to_anchor=(1.01, 1.0))
    _save(fig, out)


def parameters_figure(parameters: dict, out) -> None:
    """Each identified parameter's change from nominal with its 95 % interval (2 sigma), one panel
    per unit (mm, deg, ...)."""
    units = dict.fromkeys(unit_of(n) for n in parameters)
    groups = [(u, [(n, p) for n, p in parameters.items() if unit_of(n) == u]) for u in units]
    height = 0.9 + 0.22 * max(len(rows) for _, rows in groups)
    fig, axes = plt.subplots(1, len(groups), figsize=(7.2, height), squeeze=False)
    for ax, (unit, rows) in zip(axes[0], groups, strict=True):
        names = [drawn(n) for n, _ in rows][::-1]
        delta = [p.delta if p.delta is not None else 0.0 for _, p in rows][::-1]
        sigma = [2 * p.sigma for _, p in rows][::-1]
        ax.errorbar(delta, range(len(rows)), xerr=sigma, fmt="o", ms=4, color="C0", ecolor="C0", capsize=2)
        ax.axvline(0.0, color="0.5", lw=0.8)
        ax.set_yticks(range(len(rows)), names, fontsize=7)
        ax.set_xlabel(f"change from nominal [{drawn(unit)}]")
        ax.grid(axis="x", color="0.9")
    _save(fig, out)


def drawn(text) -> str:
    """Text from a report as matplotlib draws it as given: its ``$`` not mathtext's."""
    return str(text).replace("$", r"\$")


def verification_lines_figure(data, out) -> None:
    """Each gauge line's RMS residual with the table held, against what an unchanged robot leaves."""
    fig, ax = plt.subplots(figsize=(7.2, 3.0))
    ids = [drawn(f"line {ln.get('id')}") if data.kind == "drawstring" else "all rows" for ln in data.lines]
    colour = VERDICT_COLOURS.get(data.verdict, "0.4")
    ax.bar(
        range(len(ids)),
        [float(ln.get("rmse_mm") or 0.0) for ln in data.lines],
        color=colour,
        label=drawn(data.verdict),
        width=0.5,
    )
    pad = max(0.0, (3 - len(ids)) / 2)  # one or two bars centred, as wide as in three
    ax.set_xlim(-0.6 - pad, len(ids) - 0.4 + pad)
    if data.expected_ratio and data.noise_ratio:
        unchanged = data.rmse_mm * data.expected_ratio / data.noise_ratio
        ax.axhline(unchanged, color="k", ls="--", lw=1, label=f"an unchanged robot ~{unchanged:.3g} mm")
    ax.set_xticks(range(len(ids)), ids)
    ax.set_ylabel("RMS residual, table held [mm]")
    ax.legend(fontsize=8, loc="upper left", bbox_to_anchor=(1.01, 1.0))
    _save(fig, out)


# -- the page ----------------------------------------------------------------------------------
def figure(uri: str, caption: str, alt: str) -> str:
    return f'<figure><img src="{uri}" alt="{t(alt)}"><figcaption>{caption}</figcaption></figure>'


def table(head: list[str], rows: list[list[str]], cls: str = "") -> str:
    """An HTML table of already escaped cells."""
    top = "".join(f"<th>{h}</th>" for h in head)
    body = "".join("<tr>" + "".join(f"<td>{c}</td>" for c in row) + "</tr>" for row in rows)
    return f'<table class="{cls}"><thead><tr>{top}</tr></thead><tbody>{body}</tbody></table>'


def facts(pairs: list[tuple[str, str]]) -> str:
    """A two-column list of facts (escaped values)."""
    return '<dl class="facts">' + "".join(f"<dt>{k}</dt><dd>{v}</dd>" for k, v in pairs) + "</dl>"


def verdict_box(what: str, verdict: str | None, meaning: str, next_step: str) -> str:
    """The verdict (``what`` it is of: the fit check, the verification), what it means, what next."""
    tone = "good" if verdict in GOOD else "warn" if verdict == "doubtful" else "bad"
    return (
        f'<div class="verdict {tone}"><p class="word"><span>{what}:</span> {t(verdict or "no verdict")}</p>'
        f"<p>{meaning}</p><p><b>Next:</b> {t(next_step or 'not stated in the report')}</p></div>"
    )


CONVENTIONS = {"dh": "standard Denavit-Hartenberg (dh)", "mdh": "modified (Craig) Denavit-Hartenberg (mdh)"}
UNSTATED = "not stated in the report"


def identity(cert: Certificate) -> str:
    """The robot, the instruments, the samples, the date and the station that made the report."""
    d, robot = cert.data, cert.data.robot
    count = f" ({cert.samples_rows} rows)" if cert.samples_rows is not None else " (row count unknown)"
    pairs = [
        ("Robot", t(robot.name) if robot else UNSTATED),
        (
            "Serial number",
            t(robot.serial) if robot and robot.serial else "not stated (the robot file gives none)",
        ),
        ("Convention", t(CONVENTIONS.get(cert.convention, cert.convention)) if cert.convention else UNSTATED),
        ("Date", when(d.created_utc) if d.created_utc else UNSTATED),
        ("Station version", t(d.station_version) if d.station_version else UNSTATED),
        ("Method", f"{t(d.method)}, model {t(getattr(d, 'model', None) or 'geometric')}")
        if cert.kind == CALIBRATION
        else ("Table judged", judged_table(d)),
        ("Samples", t(d.samples) + count if d.samples else UNSTATED),
        ("Report", t(cert.path)),
    ]
    instruments = instruments_table(cert.instruments, cert.instruments_note)
    return facts(pairs) + "<h3>Instruments and their stated noise</h3>" + instruments


def judged_table(d) -> str:
    """The table a verification judged: its file, kind and calibration date."""
    calibrated = f", calibrated {when(d.table_calibrated_utc)}" if d.table_calibrated_utc else ""
    kind = f"{t(d.table_kind or 'kind unknown')} table{calibrated}"
    return kind if d.table in (None, d.table_kind) else f"{t(d.table)} ({kind})"


def instruments_table(instruments: tuple[Instrument, ...], note: str) -> str:
    if not instruments:
        return f'<p class="unknown">{t(note)}</p>'
    rows = [
        [t(i.name), t("not stated" if i.device is None else i.device or None), t(i.noise or "unknown")]
        for i in instruments
    ]
    return table(["instrument", "device", "stated noise (1 sigma)"], rows) + f'<p class="note">{t(note)}</p>'


def metrics_rows(d) -> list[list[str]]:
    """Before / after per set of rows: RMSE, mean, max."""
    out = []
    names = {"train": "training rows", "holdout": "hold-out rows"}
    for part in ("train", "holdout"):
        for table_name, fit in (("nominal table", d.before), ("corrected table", d.after)):
            m = getattr(fit, part)
            if m is not None:
                out.append([names[part], table_name, mm(m.rmse_mm), mm(m.mean_mm), mm(m.max_mm)])
    return out


SCOPE = {
    "none": "no hold-out: the figures on measured rows say nothing about the rest of the workspace; "
    "the predicted workspace error does",
    "same lines": "the hold-out rows lie on the training's gauge lines: repeatability there, not the "
    "workspace; the predicted workspace error speaks for the workspace",
    "new lines": "the hold-out rows lie on gauge lines the calibration never saw",
    "poses": "the hold-out poses were never fitted",
}


def calibration_results(cert: Certificate, noise_mm: float | None) -> str:
    d = cert.data
    ws = d.workspace
    nominal = (d.fit_check or {}).get("nominal_rmse_mm")
    bound = f" (95 %: below {mm(ws.predicted_rmse_95_mm)})" if ws.predicted_rmse_95_mm is not None else ""
    parts = [
        f'<p class="headline">Predicted workspace error: <b>{mm(ws.predicted_rmse_mm)} RMS</b>{bound}'
        + (f"; the nominal table: {mm(nominal)}" if nominal is not None else "")
        + "</p>",
        figure(
            png_uri(functools.partial(workspace_figure, nominal, ws.model_dump())),
            "Predicted RMS error over the workspace (random poses within the joint limits): the nominal "
            "table and the calibrated one; the black mark is the 95 % bound.",
            "predicted workspace error",
        ),
        "<h3>Before and after, on the measured rows</h3>",
        table(["rows", "table", "RMSE", "mean", "max"], metrics_rows(d)),
        f'<p class="note">{t(SCOPE.get(d.holdout_scope, d.holdout_scope))}</p>',
        figure(
            png_uri(functools.partial(before_after_figure, d.before.model_dump(), d.after.model_dump())),
            "RMSE of the drawstring residuals with the nominal table and with the corrected one.",
            "before and after",
        ),
    ]
    if d.lines:
        parts += [
            "<h3>Per gauge line, after calibration</h3>",
            table(
                ["line", "RMSE", "mean", "max", "held to the edge by"],
                [
                    [
                        t(ln.get("id")),
                        mm(ln.get("rmse_mm")),
                        mm(ln.get("mean_mm")),
                        mm(ln.get("max_mm")),
                        t(ln.get("dial") or "not stated"),
                    ]
                    for ln in d.lines
                ],
            ),
            figure(
                png_uri(functools.partial(lines_figure, d.lines, noise_mm)),
                "Each gauge line's residual after calibration; the dashed line is the drawstring's "
                "stated noise.",
                "residual per gauge line",
            ),
        ]
    return "".join(parts)


def parameters_section(cert: Certificate) -> str:
    d = cert.data
    params = {**d.parameters, **d.terms}
    rows = []
    for name, p in params.items():
        z = abs(p.delta) / p.sigma if p.delta is not None and p.sigma > 0 else None
        rows.append(
            [
                t(name),
                t(unit_of(name)),
                _num(p.nominal),
                _num(p.value),
                _num(p.delta, sign=True),
                _num(p.sigma),
                "&ndash;" if z is None else f"{z:.1f}",
            ]
        )
    parts = ["<h2>Parameters</h2>"]
    if rows:
        parts += [
            table(
                ["parameter", "unit", "nominal", "calibrated", "change", "sigma", "change / sigma"],
                rows,
                "num",
            ),
            figure(
                png_uri(functools.partial(parameters_figure, params)),
                "Each identified parameter's change from the nominal table with its 95 % interval (2 sigma; "
                "where no bar shows, it is narrower than the dot).",
                "parameter changes",
            ),
        ]
    else:
        parts.append("<p>No parameter was identified.</p>")
    parts.append("<h3>Held at the nominal value, and why</h3>" + held_list(d.held))
    return "".join(parts)


def held_list(held: list[dict]) -> str:
    """The held table parameters (each with its reason), then the joint-space terms left out, their
    parameters grouped by reason in smaller print."""
    if not held:
        return "<p>None: every parameter was identified.</p>"
    geometric = [h for h in held if _is_table_parameter(str(h.get("param")))]
    terms = [h for h in held if h not in geometric]
    parts = []
    if geometric:
        rows = [[f"<b>{t(h.get('param'))}</b>", t(h.get("reason", "no reason stated"))] for h in geometric]
        parts.append(table(["D-H parameter", "why it was held"], rows, "held"))
    if terms:
        by_reason: dict[str, list[str]] = {}
        for h in terms:
            by_reason.setdefault(str(h.get("reason", "no reason stated")), []).append(str(h.get("param")))
        rows = [[t(", ".join(names)), t(reason)] for reason, names in by_reason.items()]
        parts.append(f"<p>{len(terms)} joint-space terms were left out of the model:</p>")
        parts.append(table(["terms", "why"], rows, "held small"))
    return "".join(parts)


def _is_table_parameter(name: str) -> bool:
    """A D-H table parameter (``J2.a_mm``), not a joint-space term (``J2.sin1_deg``)."""
    return name.partition(".")[2] in {"theta_deg", "d_mm", "a_mm", "alpha_deg"}


def unit_of(name: str) -> str:
    """A parameter's unit as its name ends (``J2.a_mm``: mm; a compliance: urad/(N m))."""
    from calib.params import display_unit

    try:
        return display_unit(name)[1]
    except (KeyError, ValueError, IndexError):
        return name.rpartition("_")[2]


def _num(value, sign: bool = False) -> str:
    return "&ndash;" if value is None else f"{value:{'+' if sign else ''}.5g}"


def warnings_block(warnings: list[str]) -> str:
    if not warnings:
        return "<p>None.</p>"
    return '<ul class="warnings">' + "".join(f"<li>{t(w)}</li>" for w in warnings) + "</ul>"


def verification_results(cert: Certificate) -> str:
    d = cert.data
    rows = [
        [
            t(ln.get("id")),
            t(ln.get("rows")),
            mm(ln.get("rmse_mm")),
            mm(ln.get("mean_mm")),
            mm(ln.get("max_mm")),
        ]
        for ln in d.lines
    ]
    expected = f", {d.expected_ratio:.2f} expected of an unchanged robot" if d.expected_ratio else ""
    likely = [
        [t(p.get("param")), _num(p.get("change"), sign=True), _num(p.get("sigma")), t(p.get("unit"))]
        for p in d.likely
    ]
    test = [("Rows", t(d.rows)), ("Residual", f"{d.noise_ratio:.2f} x the stated noise{expected}")]
    chi2, dof, p = (getattr(d, k, None) for k in ("chi2", "dof", "p_value"))
    if isinstance(chi2, int | float) and isinstance(dof, int) and isinstance(p, int | float):
        test.append(("Chi-square", f"{chi2:.4g} on {dof} degrees of freedom, p {p:.2g}"))
    missed = getattr(d, "missed", None)
    if isinstance(missed, dict) and missed.get("workspace_mm") is not None:
        test.append(
            (
                "Could miss",
                f"{t(missed.get('param'))} by up to {missed.get('change', 0):.3g} "
                f"{t(missed.get('unit'))} ({missed['workspace_mm']:.2f} mm over the workspace)",
            )
        )
    parts = [
        f'<p class="headline">Residual with the table held: <b>{mm(d.rmse_mm)} RMS</b> '
        f"(mean {mm(d.mean_mm)}, max {mm(d.max_mm)}), {d.noise_ratio:.2f} times the stated noise"
        f"{expected}.</p>",
        facts(test),
        table(["line", "rows", "RMSE", "mean", "max"], rows),
        figure(
            png_uri(functools.partial(verification_lines_figure, d)),
            "Each gauge line's residual with the table held; the dashed line is what an unchanged "
            "robot leaves.",
            "residual per gauge line",
        ),
    ]
    if likely:
        parts += [
            "<h3>Most likely moved</h3>",
            table(["parameter", "change", "sigma", "unit"], likely, "num"),
        ]
    return "".join(parts)


def history_section(cert: Certificate) -> str:
    """The robot's records in the history: over time (two or more), listed, and what moved between
    consecutive calibrations."""
    robot, found = cert.robot_id, list(cert.history)
    if robot is None:
        return "<p>The report names no robot: no history to show.</p>"
    if not found:
        return f"<p>No records of robot {t(robot)} in the history database {t(cert.db)}.</p>"
    parts = [f'<p class="note">{len(found)} record{"s" if len(found) > 1 else ""} in {t(cert.db)}.</p>']
    if len(found) > 1:
        draw = functools.partial(history_figure, robot, found, list(cert.moved))
        caption = (
            "RMSE of every calibration (circles) and verification (squares) over time, coloured by verdict."
        )
        parts.append(figure(png_uri(draw), caption, "history over time"))
    parts.append(
        table(
            ["record", "time", "command", "verdict", "RMSE", "table judged"], history_rows(found), "history"
        )
    )
    return "".join(parts) + moves_block(found, cert.moved)


def history_rows(found: list[dict]) -> list[list[str]]:
    return [
        [
            t(f"#{r['id']}"),
            when(r["time_utc"]),
            t(r["command"]),
            t(r["verdict"]),
            mm(r["rmse_mm"]),
            t(r["judged"]),
        ]
        for r in found
    ]


def moves_block(found: list[dict], moved: tuple[dict, ...]) -> str:
    """The parameters that moved into the latest calibration (``station.history.moves``) as a table;
    earlier moves counted, not listed (a long history would bury the latest under them)."""
    calibrations = [r for r in found if r["command"] == "calibrate"]
    head = "<h3>Parameters that moved in the latest calibration</h3>"
    if len(calibrations) < 2:
        count = "one calibration" if calibrations else "no calibration"
        return head + f"<p>{count.capitalize()} of this robot in the history: none to compare.</p>"
    latest = calibrations[-1]["id"]
    now = [m for m in moved if m["record"] == latest]
    earlier = len(moved) - len(now)
    rows = [
        [
            t(m["param"]),
            f"{m['change']:+.3g} {t(unit_of(m['param']))}",
            f"{m['sigmas']:.1f}",
            when(m["since"]),
        ]
        for m in now
    ]
    body = (
        table(["parameter", "change", "combined sigmas", "since"], rows, "moves")
        if now
        else f"<p>None beyond 3 combined sigmas between records #{calibrations[-2]['id']} and #{latest}.</p>"
    )
    if earlier:
        body += (
            f'<p class="note">{earlier} earlier move{"s" if earlier > 1 else ""} between older calibrations: '
            "<code>station history</code> lists them.</p>"
        )
    return head + f"<p>Record #{latest} against the calibration before it.</p>" + body


def page(cert: Certificate) -> str:
    """The whole certificate, one HTML document."""
    d = cert.data
    calibration = cert.kind == CALIBRATION
    noise = next((i.sigma_mm for i in cert.instruments if i.name.startswith("drawstring")), None)
    if calibration:
        check = d.fit_check or {}
        verdict = check.get("verdict")
        meaning = (
            f"The fit leaves {check['noise_ratio']:.2f} times the instruments' stated noise."
            if isinstance(check.get("noise_ratio"), int | float)
            else "The report carries no fit check."
        )
        body = calibration_results(cert, noise)
    else:
        verdict, meaning, body = (
            d.verdict,
            t(d.meaning[:1].upper() + d.meaning[1:]) + ".",
            verification_results(cert),
        )
    title = "Calibration certificate" if calibration else "Verification certificate"
    name = d.robot.name if d.robot else "robot not named"
    sections = [
        f'<header><h1>{title}</h1><p class="robot">{t(name)}'
        + (f" &middot; serial {t(d.robot.serial)}" if d.robot and d.robot.serial else "")
        + "</p></header>",
        verdict_box("Fit check" if calibration else "Verification", verdict, meaning, d.next),
        identity(cert),
        '<section class="page"><h2>Results</h2>' + body + "</section>",
        '<section class="page">'
        + (
            parameters_section(cert)
            if calibration
            else "<h2>Parameters</h2><p>A verification fits no parameter of the table: only the setup.</p>"
        )
        + "<h3>Warnings</h3>"
        + warnings_block(getattr(d, "warnings", []))
        + "</section>",
        f'<section class="page"><h2>History of robot {t(cert.robot_id or "")}</h2>'
        f"{history_section(cert)}</section>",
    ]
    return DOCUMENT.format(title=t(f"{title}: {name}"), css=CSS, body="\n".join(sections))


DOCUMENT = """<!DOCTYPE html>
<html lang="en"><head><meta charset="utf-8">
<meta http-equiv="Content-Security-Policy"
 content="default-src 'none'; img-src data:; style-src 'unsafe-inline'">
<title>{title}</title><style>{css}</style></head>
<body>{body}
<footer>Written by station report from the files named above; nothing in it was measured or computed
anew.</footer>
</body></html>
"""

CSS = """
@page { size: A4; margin: 14mm 14mm 16mm; }
* { box-sizing: border-box; }
body { font: 10.5pt/1.45 "DejaVu Sans", "Liberation Sans", Arial, sans-serif; color: #1b1b1b;
       max-width: 190mm; margin: 0 auto; padding: 8mm 6mm; }
header { border-bottom: 2px solid #1b1b1b; margin-bottom: 4mm; }
h1 { font-size: 19pt; margin: 0; }
.robot { font-size: 13pt; margin: 1mm 0 2mm; }
h2 { font-size: 14pt; border-bottom: 1px solid #999; padding-bottom: 1mm; margin-top: 6mm; }
h3 { font-size: 11pt; margin: 5mm 0 2mm; }
.verdict { border: 2px solid; border-radius: 3px; padding: 2mm 4mm; margin: 3mm 0; }
.verdict p { margin: 1mm 0; }
.verdict .word { font-size: 15pt; font-weight: bold; text-transform: uppercase; }
.verdict .word span { color: #1b1b1b; text-transform: none; font-weight: normal; }
.good { border-color: #2a7d2e; background: #eef7ee; } .good .word { color: #2a7d2e; }
.warn { border-color: #b86e00; background: #fdf4e6; } .warn .word { color: #b86e00; }
.bad { border-color: #b3261e; background: #fbeceb; } .bad .word { color: #b3261e; }
.facts { display: grid; grid-template-columns: 38mm 1fr; gap: 0.6mm 4mm; margin: 3mm 0; }
.facts dt { font-weight: bold; } .facts dd { margin: 0; overflow-wrap: anywhere; }
table { border-collapse: collapse; width: 100%; margin: 2mm 0; font-size: 9.5pt; }
th, td { border-bottom: 1px solid #ccc; padding: 0.8mm 2mm; text-align: left; vertical-align: top;
         overflow-wrap: anywhere; }
th { background: #f0f0f0; white-space: nowrap; }
table.held td:first-child { width: 38%; } table.small { font-size: 8.5pt; }
table.history td:nth-child(-n+5) { white-space: nowrap; } table.num td:not(:first-child) { text-align: right;
     font-variant-numeric: tabular-nums; }
tr, figure, .verdict, .headline { break-inside: avoid; }
figure { margin: 3mm 0; } img { display: block; width: 100%; height: auto; }
figcaption { font-size: 9pt; color: #444; margin-top: 1mm; }
.note, .unknown { font-size: 9pt; color: #444; } .unknown { font-style: italic; }
.headline { font-size: 11.5pt; }
ul.held li, ul.warnings li { margin-bottom: 1mm; }
footer { margin-top: 8mm; font-size: 8.5pt; color: #666; border-top: 1px solid #ccc; }
@media print {
  body { padding: 0; max-width: none; }
  section.page { break-before: page; }
  h2, h3 { break-after: avoid; }
}
"""
