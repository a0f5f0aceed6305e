"""The report's tables as files: summary.json and summary.csv (one table); index.html is page.py's."""

from __future__ import annotations

import csv
import datetime as dt
import json
import math
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import slipdaq
from slipdaq.report.summary import COLUMNS, Comparison, LogSummary

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


def write_csv(rows: Sequence[dict[str, Any]], path: Path) -> None:
    with open(path, "w", newline="", encoding="utf-8") as f:
        out = csv.writer(f)
        out.writerow(COLUMNS)
        for r in rows:
            out.writerow([_cell(r.get(c)) for c in COLUMNS])


def _json_value(v: Any) -> Any:
    return None if isinstance(v, float) and not math.isfinite(v) else v


PlotTree = dict[str, dict[str, dict[str, str]]]
"""log name -> maneuver key -> plot stem -> a plot's name on the page, or a PNG's path in DIR."""


def write_json(
    logs: Sequence[LogSummary], comparisons: Sequence[Comparison], rows: Sequence[dict[str, Any]],
    plots: PlotTree, pngs: PlotTree, compare_pngs: dict[str, str], path: Path,
    overviews: dict[str, str | None] | None = None, group_sets: dict[str, list[dict[str, Any]]] | None = None,
    differences: Sequence[dict[str, Any]] = (),
) -> None:
    """{version, generated_utc, linearity_rule, columns, rows (= summary.csv), logs, comparison, test_sets,
    differences}. Per maneuver `plots` (stem -> the name of its plot on the page, `data-slipdaq-plot`) and `pngs`
    (stem -> file, `--png`); per comparison `plot` (its name on the page) and `png`; per log its `test_sets`
    (/test_set records), `test_sets` per label group, `differences` between groups (report.sets)."""
    doc = {
        "slipdaq_version": slipdaq.__version__,
        "generated_utc": dt.datetime.now(dt.UTC).isoformat(timespec="seconds"),
        "linearity_rule": RULE_TEXT,
        "columns": list(COLUMNS),
        "rows": [{c: _json_value(r.get(c)) for c in COLUMNS} for r in rows],
        "logs": [
            {
                "log": log.name, "path": log.path, "labels": log.labels, "group": log.group, "mode": log.mode,
                "estimates": log.estimates, "lost_frames": log.lost_frames, "bad_sentences": log.bad_sentences,
                "overview": (overviews or {}).get(log.name),
                "maneuver_records": [{k: _json_value(v) for k, v in r.as_row().items()} for r in log.records],
                "test_sets": [{k: _json_value(v) for k, v in r.items()} for r in log.test_sets],
                "maneuvers": [
                    {"maneuver": m.title, "phase": m.phase, "t_start_s": m.t_start_s, "t_end_s": m.t_end_s,
                     "gps_latency_s": m.gps_latency_s, "plots": plots.get(log.name, {}).get(m.key, {}),
                     "pngs": pngs.get(log.name, {}).get(m.key, {}),
                     "brake": None if m.brake is None else {k: _json_value(v) for k, v in vars(m.brake).items()},
                     "mu_slip": {w: None if ws.mu_slip is None else {
                         k: _json_value(v) for k, v in vars(ws.mu_slip).items()} for w, ws in m.wheels.items()}}
                    for m in log.maneuvers
                ],
            }
            for log in logs
        ],
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
    path.write_text(json.dumps(doc, indent=1, ensure_ascii=False) + "\n", encoding="utf-8")
