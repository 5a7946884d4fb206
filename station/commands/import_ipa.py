"""``station import-ipa SERIES.csv --out F.csv``: an IPA dataset series as the contract's position CSV."""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING

from errors import InputError

if TYPE_CHECKING:
    import numpy as np

HEADER = "sample,q1_deg,q2_deg,q3_deg,q4_deg,q5_deg,q6_deg,x_mm,y_mm,z_mm"


def register(subparsers) -> None:
    p = subparsers.add_parser(
        "import-ipa",
        help="convert an IPA robot-accuracy series (Landgraf et al. 2021) to a position samples CSV",
    )
    p.add_argument("series", type=Path, help="a series CSV of the dataset (';'-separated, decimal commas)")
    p.add_argument("--out", type=Path, required=True, help="position samples CSV to write")
    p.set_defaults(func=run)


def run(args) -> int:
    from station.formats.ipa import read_series

    series = read_series(args.series)
    write_position_csv(args.out, series.q_rad, series.position_mm)
    print(f"{len(series)} rows -> {args.out}")
    return 0


def write_position_csv(path: Path, q_rad: np.ndarray, position_mm: np.ndarray) -> None:
    """Joints in degrees (1e-9 deg), positions in mm (1e-6 mm); written whole or not at all."""
    import numpy as np

    rows = np.column_stack([np.arange(len(q_rad)), np.degrees(q_rad), position_mm])
    tmp = path.with_name(path.name + ".tmp")
    try:
        np.savetxt(
            tmp, rows, fmt=["%d"] + ["%.9f"] * 6 + ["%.6f"] * 3, delimiter=",", header=HEADER, comments=""
        )
        tmp.replace(path)
    except OSError as exc:
        tmp.unlink(missing_ok=True)
        raise InputError(f"{path}: cannot write ({exc.strerror})") from None
