"""Parquet export (pyarrow): one row per estimate, the CSV's columns in its order (records.ESTIMATE_COLUMNS, each
with its type: numbers float64 with nulls where undefined, texts strings), then the log's name (`log`) and its labels
(`label_<KEY>`). The values equal the CSV export's: the same float64s."""

from __future__ import annotations

from collections.abc import Iterable, Mapping
from pathlib import Path
from typing import Any

from slipdaq import WHEELS
from slipdaq.export.csv_file import ALL_COLUMNS
from slipdaq.records import ESTIMATE_COLUMNS

_KINDS = {c.key(w) if g.per_wheel else c.name: c.kind for g in ESTIMATE_COLUMNS
          for w in (WHEELS if g.per_wheel else ("",)) for c in g.columns}
"""column name -> its kind ('number', 'number?', 'text', 'enum')."""
LOG_COLUMN = "log"
LABEL_PREFIX = "label_"


def schema(labels: Iterable[str] = ()) -> Any:
    """The pyarrow schema: ALL_COLUMNS, `log`, then one `label_<KEY>` per label."""
    import pyarrow as pa

    fields = [pa.field(c, pa.float64() if _KINDS[c].startswith("number") else pa.string()) for c in ALL_COLUMNS]
    fields += [pa.field(LOG_COLUMN, pa.string())] + [pa.field(LABEL_PREFIX + k, pa.string()) for k in labels]
    return pa.schema(fields)


def estimates_table(rows: Iterable[Mapping[str, Any]], *, log_name: str, labels: Mapping[str, str]) -> Any:
    """The estimate rows (the log's /estimate dicts) as a pyarrow Table of schema(labels)."""
    import pyarrow as pa

    rows = list(rows)
    columns: dict[str, list[Any]] = {c: [None if (v := r.get(c)) is None else (float(v) if _KINDS[c].startswith(
        "number") else str(v)) for r in rows] for c in ALL_COLUMNS}
    columns[LOG_COLUMN] = [log_name] * len(rows)
    for k, v in labels.items():
        columns[LABEL_PREFIX + k] = [v] * len(rows)
    return pa.Table.from_pydict(columns, schema=schema(labels))


def write_parquet(rows: Iterable[Mapping[str, Any]], path: str | Path, *, log_name: str,
                  labels: Mapping[str, str]) -> int:
    """Write the estimate rows to a Parquet file at path (zstd); returns the number of rows."""
    import pyarrow.parquet as pq

    table = estimates_table(rows, log_name=log_name, labels=labels)
    pq.write_table(table, str(path), compression="zstd")
    return int(table.num_rows)
