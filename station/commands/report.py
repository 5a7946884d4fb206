"""``station report REPORT.json|V.json --out certificate.html``: the calibration certificate, one
self-contained HTML page a plant files and a person reads (and prints to PDF)."""

from __future__ import annotations

from pathlib import Path


def register(sub) -> None:
    p = sub.add_parser(
        "report",
        help="a calibration certificate (one self-contained HTML page) from a calibrate or verify report",
    )
    p.add_argument(
        "report",
        type=Path,
        help="REPORT.json (station calibrate --report) or V.json (station verify --report)",
    )
    p.add_argument("--out", type=Path, required=True, help="the certificate's HTML file to write")
    p.add_argument(
        "--db",
        type=Path,
        help="history database with the robot's records (default: $STATION_HISTORY_DB, else the user's "
        "data folder)",
    )
    p.set_defaults(func=run)


def run(args) -> int:
    from station import history
    from station.formats.base import Output, check_writable, write_outputs
    from station.jobs.certificate import gather
    from station.view.certificate import page

    check_writable(args.out, "--out")
    cert = gather(args.report, history.database_path(args.db))
    write_outputs([Output.text(args.out, "--out", page(cert))])
    shown = len(cert.history)
    print(
        f"{cert.kind} certificate of {cert.data.robot.name if cert.data.robot else 'an unnamed robot'}"
        f" ({shown} history record{'s' if shown != 1 else ''}) -> {args.out}"
    )
    return 0
