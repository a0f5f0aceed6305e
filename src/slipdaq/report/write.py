"""The report's files: index.html (offline, relative image links), summary.json and summary.csv (one table)."""

from __future__ import annotations

import csv
import datetime as dt
import json
import math
from collections.abc import Sequence
from html import escape
from pathlib import Path
from typing import Any

import slipdaq
from slipdaq import WHEELS
from slipdaq.maneuver.figures import ManeuverSummary
from slipdaq.report.labels import format_labels
from slipdaq.report.plots import PLOTS, WHEEL_STYLE
from slipdaq.report.summary import COLUMNS, Comparison, LogSummary
from slipdaq.sinks.maneuver_text import axle_slip_pct, figures_text, verdict

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


def write_json(
    logs: Sequence[LogSummary], comparisons: Sequence[Comparison], rows: Sequence[dict[str, Any]],
    plots: dict[str, dict[str, dict[str, str]]], compare_plots: dict[str, str], path: Path,
) -> None:
    """{version, generated_utc, linearity_rule, columns, rows (= summary.csv), logs, comparison}."""
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
                "maneuver_records": [{k: _json_value(v) for k, v in r.as_row().items()} for r in log.records],
                "maneuvers": [
                    {"maneuver": m.title, "phase": m.phase, "t_start_s": m.t_start_s, "t_end_s": m.t_end_s,
                     "gps_latency_s": m.gps_latency_s, "plots": plots.get(log.name, {}).get(m.key, {}),
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
                "plot": compare_plots.get(c.phase),
                "groups": [
                    {"group": g.group, "logs": list(g.logs), "maneuvers": list(g.titles),
                     "wheels": {w: {k: _json_value(v) for k, v in vars(gw).items()} for w, gw in g.wheels.items()}}
                    for g in c.groups
                ],
            }
            for c in comparisons
        ],
    }
    path.write_text(json.dumps(doc, indent=1, ensure_ascii=False) + "\n", encoding="utf-8")


# ---- html ---------------------------------------------------------------------------------------------------

_CSS = """
body { font-family: system-ui, sans-serif; margin: 1.5em; color: #222; max-width: 1700px; }
table { border-collapse: collapse; margin: 0.5em 0 1em; font-size: 0.9em; }
th, td { border: 1px solid #ccc; padding: 3px 8px; text-align: right; }
th { background: #f2f2f2; } td.l, th.l { text-align: left; }
.sw { display: inline-block; width: 0.9em; height: 0.9em; border-radius: 2px; vertical-align: -1px; margin-right: 4px; }
.plots { display: flex; flex-wrap: wrap; gap: 8px; }
.plots img { width: 400px; height: 300px; border: 1px solid #ddd; }
.note { color: #555; font-size: 0.9em; max-width: 75em; }
h2 { border-bottom: 2px solid #ddd; padding-bottom: 3px; margin-top: 2em; }
"""


def _f(v: Any, scale: float = 1.0, digits: int = 1) -> str:
    if v is None or (isinstance(v, float) and not math.isfinite(v)):
        return "–"
    return f"{v * scale:.{digits}f}"


def _wheel(w: str) -> str:
    return f'<span class="sw" style="background:{WHEEL_STYLE[w]["color"]}"></span>{w}'


def _maneuver_table(log: LogSummary, m: ManeuverSummary) -> str:
    head = ("wheel", "slip samples", "mean slip [%]", "linearity", "peak linear Fx [N]", "slip at peak [%]",
            "fitted Cx [kN]", "Cx conf", "Cx source", "peak Cx [kN]", "slip at peak Cx [%]", "mean Re [mm]",
            "r0 [mm]", "lost frames", "μ peak", "slip at μ peak [%]")
    out = ["<table><tr>" + "".join(f"<th>{escape(h)}</th>" for h in head) + "</tr>"]
    for w in WHEELS:
        ws = m.wheels[w]
        lin = ws.linearity
        cells = (
            _wheel(w), str(ws.slip_samples), _f(ws.mean_slip, 100, 2), escape(lin.verdict),
            _f(lin.peak_fx_n, 1, 0), _f(lin.peak_fx_slip, 100, 2), _f(ws.cx_fit_n, 1e-3, 1),
            _f(ws.cx_fit_conf, 1, 2), escape(ws.cx_fit_source), _f(ws.peak_cx_n, 1e-3, 1),
            _f(ws.peak_cx_slip, 100, 2), _f(ws.mean_re_m, 1000, 2), _f(ws.r0_m, 1000, 2),
            "–" if ws.lost_frames is None else str(ws.lost_frames),
            _f(ws.mu_slip.mu_peak if ws.mu_slip else None, 1, 3),
            _f(ws.mu_slip.slip_at_mu_peak if ws.mu_slip else None, 100, 1),
        )
        out.append("<tr>" + "".join(f'<td{" class=l" if i in (0, 3, 8) else ""}>{c}</td>'
                                     for i, c in enumerate(cells)) + "</tr>")
    out.append("</table>")
    lat = _f(m.gps_latency_s, 1, 3)
    out.append(f'<p class="note">t = {m.t_start_s:.1f}–{m.t_end_s:.1f} s after the log\'s first estimate, '
               f"{len(m.rows)} estimates, speed {m.speed_from_kmh:.1f} → {m.speed_to_kmh:.1f} km/h; "
               f"GPS latency {lat} s ({escape(m.gps_latency_source)}); bad sentences in the log: "
               f"{'–' if log.bad_sentences is None else log.bad_sentences}.</p>")
    b = m.brake
    if b is not None:
        abs_text = f"{b.abs_cycles} ABS cycles at {_f(b.abs_frequency_hz, 1, 1)} Hz ({b.abs_wheel})" \
            if b.abs_cycles else "no ABS cycling"
        out.append(f'<p class="note"><b>Brake test</b>: onset at {b.onset_s - (log.t0_s or 0.0):.2f} s '
                   f"({escape(b.onset_source)}) from {b.brake_speed_kmh:.1f} km/h; stopping distance "
                   f"{_f(b.stopping_distance_m, 1, 2)} m, corrected to {_f(b.nominal_speed_kmh, 1, 0)} km/h: "
                   f"{_f(b.stopping_distance_corrected_m, 1, 2)} m; MFDD {_f(b.mfdd_mps2, 1, 2)} m/s² "
                   f"(0.8·v0 to 0.1·v0); {abs_text}.</p>")
    return "\n".join(out)


def _images(paths: dict[str, str]) -> str:
    titles = dict(PLOTS)
    imgs = [f'<a href="{escape(paths[k])}"><img src="{escape(paths[k])}" alt="{escape(titles.get(k, k))}" '
            f'title="{escape(titles.get(k, k))}"></a>' for k, _ in PLOTS if k in paths]
    return '<div class="plots">' + "".join(imgs) + "</div>"


def _comparison_html(c: Comparison, plot: str | None) -> str:
    metrics = (
        ("fitted Cx [kN]", lambda g: _f(g.cx_fit_n, 1e-3, 1)),
        ("peak linear Fx [N]", lambda g: _f(g.peak_linear_fx_n, 1, 0)),
        ("slip at peak [%]", lambda g: _f(g.peak_linear_fx_slip, 100, 2)),
        ("end of linearity", lambda g: "linear throughout" if g.linear_end_slip is None
         else f"{abs(g.linear_end_slip) * 100:.1f} %"),
        ("mean Re [mm]", lambda g: _f(g.mean_re_m, 1000, 2)),
    )
    out = [f"<h3>{escape(c.phase)}</h3>", "<table><tr><th>wheel</th><th class=l>figure</th>"]
    for g in c.groups:
        logs = "<br>".join(f"{escape(n)}: {escape(t)}" for n, t in zip(g.logs, g.titles))
        out.append(f'<th class=l>{escape(g.group)}<br><span class="note">{logs}</span></th>')
    out.append("</tr>")
    for w in WHEELS:
        for i, (name, get) in enumerate(metrics):
            row = f"<td rowspan={len(metrics)} class=l>{_wheel(w)}</td>" if i == 0 else ""
            row += f"<td class=l>{escape(name)}</td>" + "".join(f"<td>{get(g.wheels[w])}</td>" for g in c.groups)
            out.append(f"<tr>{row}</tr>")
    out.append("</table>")
    if plot:
        out.append(f'<div class="plots"><a href="{escape(plot)}"><img src="{escape(plot)}" '
                   f'alt="Fx against slip, {escape(c.phase)}, by group"></a></div>')
    return "\n".join(out)


def write_html(
    logs: Sequence[LogSummary], comparisons: Sequence[Comparison],
    plots: dict[str, dict[str, dict[str, str]]], compare_plots: dict[str, str], path: Path,
) -> None:
    """index.html; `plots`: log name -> phase -> plot stem -> path relative to the html; `compare_plots`: phase ->
    path of the comparison plot."""
    now = dt.datetime.now(dt.UTC).isoformat(timespec="seconds")
    out = [
        '<!doctype html>\n<html lang="en"><head><meta charset="utf-8"><title>slipdaq report</title>',
        f"<style>{_CSS}</style></head><body>",
        "<h1>slipdaq report</h1>",
        f'<p class="note">{len(logs)} log(s), slipdaq {escape(slipdaq.__version__)}, {now}. Tables: '
        '<a href="summary.csv">summary.csv</a>, <a href="summary.json">summary.json</a>. '
        "Slip s is SAE slip (positive driving, negative braking); Fx is the force per tire; Cx = Fx/s is in kN "
        f"per unit slip. Wheels: {' '.join(_wheel(w) for w in WHEELS)}.</p>",
        f'<p class="note"><b>Linear region:</b> {escape(RULE_TEXT)}</p>',
        "<h2>Logs</h2><table><tr><th class=l>log</th><th class=l>labels</th><th class=l>group</th>"
        "<th class=l>mode</th><th>estimates</th><th class=l>maneuvers</th><th>lost frames</th>"
        "<th>bad sentences</th></tr>",
    ]
    for log in logs:
        lost = ", ".join(f"{w} {n}" for w, n in log.lost_frames.items()) or "–"
        out.append(
            f'<tr><td class=l><a href="#{escape(_anchor(log.name))}">{escape(log.name)}</a></td>'
            f"<td class=l>{escape(format_labels(log.labels)) or '–'}</td><td class=l>{escape(log.group)}</td>"
            f"<td class=l>{escape(log.mode)}</td><td>{log.estimates}</td>"
            f"<td class=l>{escape('; '.join(m.title for m in log.maneuvers)) or 'none'}</td>"
            f"<td>{escape(lost)}</td><td>{'–' if log.bad_sentences is None else log.bad_sentences}</td></tr>"
        )
    out.append("</table>")
    if comparisons:
        out.append("<h2>Comparison by labels</h2>")
        out.append('<p class="note">Logs grouped by their labels (every label but <code>maneuver</code>, unless '
                   "<code>--group-by</code> names the keys); per group the mean fitted Cx, the largest peak linear "
                   "Fx, the earliest end of linearity and the mean Re over its logs.</p>")
        for c in comparisons:
            out.append(_comparison_html(c, compare_plots.get(c.phase)))
    for log in logs:
        out.append(f'<h2 id="{escape(_anchor(log.name))}">{escape(log.title)}</h2>')
        out.append(f'<p class="note">{escape(log.path)} — group {escape(log.group)}, {log.estimates} estimates</p>')
        if not log.maneuvers:
            out.append('<p class="note">No maneuver with a defined slip in this log.</p>')
        if log.records:
            out.append(_records_table(log))
        for m in log.maneuvers:
            out.append(f"<h3>{escape(m.title)}</h3>")
            out.append(_maneuver_table(log, m))
            out.append(_images(plots.get(log.name, {}).get(m.key, {})))
    out.append("</body></html>\n")
    path.write_text("\n".join(out), encoding="utf-8")


def _records_table(log: LogSummary) -> str:
    """The log's accelerate and brake maneuvers as the live /maneuver records give them, in time order."""
    out = ['<table class="records"><tr><th>#</th><th class=l>kind</th><th>from km/h</th><th>to km/h</th>'
           "<th>target km/h</th><th class=l>result</th><th>slip front %</th><th>slip rear %</th>"
           "<th class=l>valid</th></tr>"]
    for r in log.records:
        ax = axle_slip_pct(r)
        out.append(f"<tr><td>{r.index}</td><td class=l>{escape(r.kind)}</td><td>{_f(r.speed_from_kmh)}</td>"
                   f"<td>{_f(r.speed_to_kmh)}</td><td>{_f(r.target_speed_kmh, digits=0)}</td>"
                   f"<td class=l>{escape(figures_text(r))}</td><td>{_f(ax['front'])}</td><td>{_f(ax['rear'])}</td>"
                   f"<td class=l>{escape(verdict(r))}</td></tr>")
    out.append("</table>")
    return "\n".join(out)


def _anchor(name: str) -> str:
    return "log-" + "".join(ch if ch.isalnum() or ch in "-_" else "-" for ch in name)
