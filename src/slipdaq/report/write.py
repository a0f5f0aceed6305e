"""The report's tables as files: summary.json and summary.csv (one table); index.html is page.py's."""

from __future__ import annotations

import csv
import datetime as dt
import io
import json
import math
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import slipdaq
from slipdaq.report.summary import COLUMNS, Comparison, LogSummary, table_rows

RULE_TEXT = (
    "Fx = Cx·s is fitted through the origin (least squares) over the force–slip points with "
    "cx_slip_min ≤ |s| ≤ cx_slip_max (0.5–10 % by default; same sign of Fx and s). The points are binned by |s| "
    "in 1 % steps (bins of at least 5 points); linearity ends at the first bin whose median |Fx| is more than "
    "10 % below the line and after which every bin stays below it, over at least two bins "
    "(the line is refitted below that bin when "
    "the bin lay inside the fit range). Peak linear Fx: the largest |Fx| below that bin. No such bin: "
    "“linear throughout”."
)


def _cell(v: Any) -> str:
    if v is None:
        return ""
    if isinstance(v, float):
        return repr(v) if math.isfinite(v) else ""
    return str(v)


def _json_value(v: Any) -> Any:
    return None if isinstance(v, float) and not math.isfinite(v) else v


PlotTree = dict[str, dict[str, dict[str, str]]]
"""log name -> maneuver key -> plot stem -> a plot's name on the page, or a PNG's path in DIR."""
PlotNames = dict[str, dict[str, str]]
"""One log's: maneuver key -> plot stem -> a plot's name, or a PNG's path."""


@dataclass(frozen=True)
class LogPieces:
    """One log's share of the tables, encoded as they stand in the files: its rows of summary.csv, its rows and its
    entry of summary.json's `logs`. Made per log (a batch task makes them beside the log's summary); write_json and
    write_csv join them. `made_for`: what besides the summary they were made from (path, group, plots, PNGs,
    overview); where the report's differ they are made again."""

    made_for: tuple[str, str, PlotNames, PlotNames, str | None]
    csv: str
    json_rows: tuple[str, ...]
    json_log: str


def _encoded(value: Any, depth: int) -> str:
    """value as json.dumps(..., indent=1) writes it `depth` levels down (its lines after the first indented by
    depth; a string's newlines are escaped, so every newline is the encoder's)."""
    return json.dumps(value, indent=1, ensure_ascii=False).replace("\n", "\n" + " " * depth)


def _json_list(items: Sequence[str], depth: int) -> str:
    """A list of items encoded `depth + 1` levels down (_encoded), as json.dumps(..., indent=1) writes it at depth."""
    if not items:
        return "[]"
    inner = "\n" + " " * (depth + 1)
    return "[" + inner + ("," + inner).join(items) + "\n" + " " * depth + "]"


def log_pieces(log: LogSummary, plots: PlotNames, pngs: PlotNames, overview: str | None) -> LogPieces:
    """A log's LogPieces: its table rows (summary.table_rows) as CSV and JSON, its summary.json entry (plots: its
    plots' names by maneuver key and stem; pngs: its PNGs' paths; overview: its overview plot's name)."""
    rows = table_rows([log])
    text = io.StringIO(newline="")
    out = csv.writer(text)
    for r in rows:
        out.writerow([_cell(r.get(c)) for c in COLUMNS])
    entry = {
        "log": log.name, "path": log.path, "labels": log.labels, "group": log.group, "mode": log.mode,
        "estimates": log.estimates, "lost_frames": log.lost_frames, "bad_sentences": log.bad_sentences,
        "overview": overview,
        "maneuver_records": [{k: _json_value(v) for k, v in r.as_row().items()} for r in log.records],
        "test_sets": [{k: _json_value(v) for k, v in r.items()} for r in log.test_sets],
        "maneuvers": [
            {"maneuver": m.title, "phase": m.phase, "t_start_s": m.t_start_s, "t_end_s": m.t_end_s,
             "gps_latency_s": m.gps_latency_s, "plots": plots.get(m.key, {}), "pngs": pngs.get(m.key, {}),
             "brake": None if m.brake is None else {k: _json_value(v) for k, v in vars(m.brake).items()},
             "mu_slip": {w: None if ws.mu_slip is None else {
                 k: _json_value(v) for k, v in vars(ws.mu_slip).items()} for w, ws in m.wheels.items()}}
            for m in log.maneuvers
        ],
    }
    return LogPieces((log.path, log.group, plots, pngs, overview), text.getvalue(),
                     tuple(_encoded({c: _json_value(r.get(c)) for c in COLUMNS}, 2) for r in rows),
                     _encoded(entry, 2))


def pieces_of(logs: Sequence[LogSummary], plots: PlotTree, pngs: PlotTree, overviews: dict[str, str | None],
              made: dict[str, LogPieces] | None = None) -> list[LogPieces]:
    """Each log's LogPieces: the one in `made` where it was made for what the report has, else made here."""
    out = []
    for log in logs:
        ours = (log.path, log.group, plots.get(log.name, {}), pngs.get(log.name, {}), overviews.get(log.name))
        got = (made or {}).get(log.name)
        out.append(got if got is not None and got.made_for == ours else log_pieces(log, *ours[2:]))
    return out


def write_csv(pieces: Sequence[LogPieces], path: Path) -> None:
    """summary.csv: the header (COLUMNS), then each log's rows."""
    head = io.StringIO(newline="")
    csv.writer(head).writerow(COLUMNS)
    with open(path, "w", newline="", encoding="utf-8") as f:
        f.write(head.getvalue() + "".join(p.csv for p in pieces))


def write_json(
    logs: Sequence[LogSummary], comparisons: Sequence[Comparison], pieces: Sequence[LogPieces],
    compare_pngs: dict[str, str], path: Path, group_sets: dict[str, list[dict[str, Any]]] | None = None,
    differences: Sequence[dict[str, Any]] = (),
) -> None:
    """{version, generated_utc, linearity_rule, columns, rows (= summary.csv), logs, comparison, test_sets,
    differences}, as json.dumps(indent=1) writes it, each log's rows and entry from its pieces (log_pieces). Per
    maneuver `plots` (stem -> the name of its plot on the page, `data-slipdaq-plot`) and `pngs` (stem -> file,
    `--png`); per comparison `plot` (its name on the page) and `png`; per log its `test_sets` (/test_set records),
    `test_sets` per label group, `differences` between groups (report.sets)."""
    doc = {
        "slipdaq_version": slipdaq.__version__,
        "generated_utc": dt.datetime.now(dt.UTC).isoformat(timespec="seconds"),
        "linearity_rule": RULE_TEXT,
        "columns": list(COLUMNS),
        "rows": _json_list([r for p in pieces for r in p.json_rows], 1),
        "logs": _json_list([p.json_log for p in pieces], 1),
        "comparison": [
            {
                "phase": c.phase,
                "plot": f"compare-{c.phase}-fx-slip",
                "png": compare_pngs.get(c.phase),
                "groups": [
                    {"group": g.group, "logs": list(g.logs), "maneuvers": list(g.titles),
                     "wheels": {w: {k: _json_value(v) for k, v in vars(gw).items()} for w, gw in g.wheels.items()}}
                    for g in c.groups
                ],
            }
            for c in comparisons
        ],
        "test_sets": {g: [{k: _json_value(v) for k, v in r.items()} for r in rs] for g, rs in (group_sets or {}).items()},
        "differences": [{k: _json_value(v) for k, v in d.items()} for d in differences],
    }
    spliced = ("rows", "logs")  # encoded already
    body = ",\n ".join(f"{json.dumps(k, ensure_ascii=False)}: {v if k in spliced else _encoded(v, 1)}"
                       for k, v in doc.items())
    path.write_text("{\n " + body + "\n}\n", encoding="utf-8")
