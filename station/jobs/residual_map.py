"""The residual map (``calib.residual_map``) as the station uses it: fitted by ``station calibrate``
on the calibration's own rows after the fit (``calib.map_rows``: a tracker's rows, or a drawstring
cell's along the cable and across the lines; the angle errors beside what the table absorbed of them,
``calib.absorbed_angles``), stored beside the corrected table
(``station.formats.tables.MapFile``), added to the table's prediction by ``station verify``,
``station compensate`` and the in-session corrected targets.

The map decides itself whether it is used: off where the calibration's rows, predicted from the
other interleaved folds, do not show a gain (a cell of table and noise).
"""

from __future__ import annotations

from dataclasses import asdict, dataclass

import numpy as np

from calib.absorbed_angles import fit_model_map
from calib.angle_errors import FOLDS, MIN_GAIN
from calib.map_rows import model_observations
from calib.residual_map import ResidualMap, fit_rows_map, mapped_readings


@dataclass(frozen=True)
class MapReport:
    """REPORT.json's ``map``: whether the corrected table carries a map (``used``) and ``why``; its
    shared error's size (``shared_mm``, 3-D RMS) and correlation length over joints 1-3
    (``length_deg``), the joint angle errors' size (``angle_deg``, RMS; None where a stage is off),
    the share of the held-out rows' mean square error it takes out (``explained``) and the rows it
    was fitted on."""

    used: bool
    why: str
    rows: int
    shared_mm: float | None = None
    length_deg: float | None = None
    angle_deg: float | None = None
    explained: float | None = None

    def as_json(self) -> dict:
        return asdict(self)

    def text(self) -> str:
        """The summary's line."""
        if not self.used:
            return f"residual map: off ({self.why})"
        return f"residual map: on ({self.why})"


def fit_table_map(
    model, x: np.ndarray, free: np.ndarray | None, enabled: bool = True
) -> tuple[ResidualMap | None, MapReport]:
    """The map of a calibration's ``model`` (its rows) at its solution ``x`` with its ``free``
    unknowns (``calib.absorbed_angles.fit_model_map``; None: of the rows' residuals alone,
    ``calib.residual_map.fit_rows_map``), and what the report says of it; none where ``enabled``
    is false (``--no-map``), too few rows or no held-out gain."""
    rows = len(model.samples)
    if not enabled:
        return None, MapReport(False, "--no-map", rows)
    if rows < 2 * FOLDS:
        return None, MapReport(False, f"{rows} rows: a map needs {2 * FOLDS} or more", rows)
    if free is None:
        found = fit_rows_map(model_observations(model, x), model.dh(x), model.tcp_in_flange(x))
    else:
        found = fit_model_map(model, x, free)
    if found is None:
        why = f"the rows left out in turn show no clear gain of {MIN_GAIN:.0%} over the table alone"
        return None, MapReport(False, why, rows)
    why = (
        f"the rows left out in turn: {found.table_cv_rmse_mm:.3f} mm RMS with the table alone, "
        f"{found.cv_rmse_mm:.3f} mm with the map"
    )
    shared, angles = found.shared, found.angles
    return found, MapReport(
        True,
        why,
        rows,
        shared_mm=None if shared is None else float(np.sqrt(3.0 * shared.shared_mm2)),
        length_deg=None if shared is None else shared.length_scale_deg,
        angle_deg=None if angles is None else angles.sigma_deg,
        explained=found.explained,
    )


def mapped_q_deg(found: ResidualMap | None, q_deg: np.ndarray) -> np.ndarray:
    """Readings [deg] (N, 6) at which the table alone reaches where the table plus the map reach at
    ``q_deg`` (``calib.residual_map.mapped_readings``); ``q_deg`` itself without a map."""
    if found is None:
        return np.asarray(q_deg, float)
    return np.degrees(mapped_readings(found, np.radians(np.asarray(q_deg, float))))
