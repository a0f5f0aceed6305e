"""CSV export: one row per estimate, in the public column order; an empty cell where a value is undefined."""

from __future__ import annotations

import csv
from collections.abc import Iterable
from pathlib import Path
from typing import Any

from slipdaq import WHEELS

COLUMNS: tuple[str, ...] = ("time_s", "speed_mps", "accel_mps2", "force_n") + tuple(
    c for w in WHEELS for c in (f"slip_{w}", f"re_{w}_m", f"r0_{w}_m", f"cx_{w}_n")
)


def _cell(v: Any) -> str:
    if v is None:
        return ""
    return repr(float(v)) if isinstance(v, float) else str(v)


def write_csv(rows: Iterable[dict[str, Any]], path: str | Path) -> int:
    """Write estimate rows (dicts with at least COLUMNS) to path; returns the number of rows."""
    n = 0
    with open(path, "w", newline="", encoding="utf-8") as f:
        out = csv.writer(f)
        out.writerow(COLUMNS)
        for row in rows:
            out.writerow([_cell(row.get(c)) for c in COLUMNS])
            n += 1
    return n
