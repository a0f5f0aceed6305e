"""CSV export: one row per estimate (or per high-rate slip row, or per maneuver), in the public column order; an
empty cell where a value is undefined."""

from __future__ import annotations

import csv
from collections.abc import Iterable
from pathlib import Path
from typing import Any

from slipdaq import WHEELS
from slipdaq.maneuver.record import MANEUVER_COLUMNS
from slipdaq.records.columns import ESTIMATE_COLUMNS, FAST_SLIP_COLUMNS, column_names

COLUMNS: tuple[str, ...] = column_names(ESTIMATE_COLUMNS, WHEELS, csv="contract")
"""The public contract's columns, in order."""
EXTRA_COLUMNS: tuple[str, ...] = column_names(ESTIMATE_COLUMNS, WHEELS, csv="extra")
"""Appended after the contract's columns (extensions keep the contract's columns where they are)."""
ALL_COLUMNS = COLUMNS + EXTRA_COLUMNS
FAST_COLUMNS: tuple[str, ...] = column_names(FAST_SLIP_COLUMNS, WHEELS, csv="contract")
"""`export --fast-csv`: time_s, speed_mps, slip_FL, slip_FR, slip_RL, slip_RR."""
MANEUVER_CSV_COLUMNS: tuple[str, ...] = column_names(MANEUVER_COLUMNS, WHEELS, csv="contract")
"""`export --maneuvers-csv`: the /maneuver record's fields, the per-wheel ones flattened (mean_slip_FL, ...)."""
IMU_CSV_COLUMNS: tuple[str, ...] = ("time_s", "accel_mps2")
"""`export --imu-csv`: the forward acceleration the estimator took from the IMU, one row per sample."""


def _cell(v: Any) -> str:
    """Empty for undefined; floats as repr (exact); true/false; a list of texts joined by '; '."""
    if v is None:
        return ""
    if isinstance(v, bool):
        return "true" if v else "false"
    if isinstance(v, list):
        return "; ".join(str(x) for x in v)
    return repr(float(v)) if isinstance(v, float) else str(v)


def write_csv(rows: Iterable[dict[str, Any]], path: str | Path, columns: tuple[str, ...] = ALL_COLUMNS) -> int:
    """Write rows (dicts with at least the contract's columns) to path; returns the number of rows."""
    n = 0
    with open(path, "w", newline="", encoding="utf-8") as f:
        out = csv.writer(f)
        out.writerow(columns)
        for row in rows:
            out.writerow([_cell(row.get(c)) for c in columns])
            n += 1
    return n
