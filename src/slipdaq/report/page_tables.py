"""The page's tables (HTML, readable without JavaScript): the logs, every maneuver (sortable on the page; a row goes
to its maneuver's plots), per maneuver its wheels, per log its /maneuver records, and the comparison by labels."""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from html import escape
from typing import Any

from slipdaq import WHEELS
from slipdaq.maneuver.figures import ManeuverSummary
from slipdaq.maneuver.record import Maneuver
from slipdaq.report.labels import format_labels
from slipdaq.report.style import WHEEL_STYLE
from slipdaq.report.summary import Comparison, LogSummary
from slipdaq.sinks.maneuver_text import axle_slip_pct, figures_text, verdict


def fmt(v: Any, scale: float = 1.0, digits: int = 1) -> str:
    """A number for a cell ("–" when undefined)."""
    if v is None or (isinstance(v, float) and not math.isfinite(v)):
        return "–"
    return f"{v * scale:.{digits}f}"


def wheel(w: str) -> str:
    return f'<span class="sw" style="background:{WHEEL_STYLE[w]["color"]}"></span>{w}'


def log_anchor(log: LogSummary) -> str:
    return f"log-{log.name}"


def maneuver_anchor(log: LogSummary, m: ManeuverSummary) -> str:
    """The id of a maneuver's section (its tables and plots)."""
    return f"maneuver-{log.name}/{m.key}"


def logs_table(logs: Sequence[LogSummary]) -> str:
    out = ["<table><thead><tr><th class=l>log</th><th class=l>labels</th><th class=l>group</th>"
           "<th class=l>mode</th><th>estimates</th><th class=l>maneuvers</th><th>lost frames</th>"
           "<th>bad sentences</th></tr></thead><tbody>"]
    for log in logs:
        lost = ", ".join(f"{w} {n}" for w, n in log.lost_frames.items()) or "–"
        out.append(
            f'<tr><td class=l><a href="#{escape(log_anchor(log))}">{escape(log.name)}</a></td>'
            f"<td class=l>{escape(format_labels(log.labels)) or '–'}</td><td class=l>{escape(log.group)}</td>"
            f"<td class=l>{escape(log.mode)}</td><td>{log.estimates}</td>"
            f"<td class=l>{escape('; '.join(m.title for m in log.maneuvers)) or 'none'}</td>"
            f"<td>{escape(lost)}</td><td>{'–' if log.bad_sentences is None else log.bad_sentences}</td></tr>")
    out.append("</tbody></table>")
    return "\n".join(out)


def record_of(log: LogSummary, m: ManeuverSummary) -> Maneuver | None:
    """The /maneuver record of an accelerate or brake maneuver (None for cruise)."""
    return next((r for r in log.records if r.kind == m.phase and abs(r.t_start_s - m.t_start_s) < 1e-6), None)


def _best(values: list[float | None], key: Callable[[float], float] = abs) -> float | None:
    got = [v for v in values if v is not None]
    return max(got, key=key) if got else None


ManeuverCell = tuple[str, str, Callable[[LogSummary, ManeuverSummary], Any], Callable[[Any], str]]
MANEUVER_COLUMNS: tuple[ManeuverCell, ...] = (
    ("log", "l", lambda log, m: log.name, str),
    ("labels", "l", lambda log, m: format_labels(log.labels) or "–", str),
    ("phase", "l", lambda log, m: m.phase, str),
    ("start [s]", "", lambda log, m: m.t_start_s, lambda v: fmt(v, 1, 1)),
    ("end [s]", "", lambda log, m: m.t_end_s, lambda v: fmt(v, 1, 1)),
    ("from [km/h]", "", lambda log, m: m.speed_from_kmh, fmt),
    ("to [km/h]", "", lambda log, m: m.speed_to_kmh, fmt),
    ("max |slip| [%]", "", lambda log, m: _best([ws.max_abs_slip for ws in m.wheels.values()]),
     lambda v: fmt(v, 100, 2)),
    ("fitted Cx, mean [kN]", "", lambda log, m: _mean([ws.cx_fit_n for ws in m.wheels.values()]),
     lambda v: fmt(v, 1e-3, 1)),
    ("μ peak", "", lambda log, m: _best([ws.mu_slip.mu_peak if ws.mu_slip else None for ws in m.wheels.values()]),
     lambda v: fmt(v, 1, 3)),
    ("brake speed [km/h]", "", lambda log, m: m.brake.brake_speed_kmh if m.brake else None, fmt),
    ("stopping distance [m]", "", lambda log, m: m.brake.stopping_distance_m if m.brake else None,
     lambda v: fmt(v, 1, 2)),
    ("MFDD [m/s²]", "", lambda log, m: m.brake.mfdd_mps2 if m.brake else None, lambda v: fmt(v, 1, 2)),
    ("valid", "l", lambda log, m: verdict(r) if (r := record_of(log, m)) else "–", str),
)
"""(heading, class, value, text) of the maneuvers table's columns after the maneuver's name."""


def _mean(values: list[float | None]) -> float | None:
    got = [v for v in values if v is not None]
    return sum(got) / len(got) if got else None


def maneuvers_table(logs: Sequence[LogSummary]) -> str:
    """One row per maneuver of summary.json, in its order; the name links to the maneuver's section."""
    head = '<th class="l" data-sort="text">maneuver</th>' + "".join(
        f'<th class="{c}" data-sort="{"text" if c else "num"}">{escape(h)}</th>' for h, c, _, _ in MANEUVER_COLUMNS)
    out = ['<table class="maneuvers" data-slipdaq-table="maneuvers"><thead><tr>' + head + "</tr></thead><tbody>"]
    for log in logs:
        for m in log.maneuvers:
            href = "#" + maneuver_anchor(log, m)
            cells = [f'<td class="l"><a href="{escape(href)}">{escape(m.title)}</a></td>']
            for _, c, get, text in MANEUVER_COLUMNS:
                v = get(log, m)
                sort = "" if c or v is None else f' data-v="{float(v):.9g}"'
                cells.append(f'<td class="{c}">{escape(text(v))}</td>' if c else f"<td{sort}>{escape(text(v))}</td>")
            out.append(f'<tr data-href="{escape(href)}">' + "".join(cells) + "</tr>")
    out.append("</tbody></table>")
    return "\n".join(out)


def wheels_table(log: LogSummary, m: ManeuverSummary) -> str:
    """A maneuver's figures per wheel, its span and GPS latency, and its brake test."""
    head = ("wheel", "slip samples", "mean slip [%]", "linearity", "peak linear Fx [N]", "slip at peak [%]",
            "fitted Cx [kN]", "Cx conf", "Cx source", "peak Cx [kN]", "slip at peak Cx [%]", "mean Re [mm]",
            "r0 [mm]", "lost frames", "μ peak", "slip at μ peak [%]")
    out = ["<table><thead><tr>" + "".join(f"<th>{escape(h)}</th>" for h in head) + "</tr></thead><tbody>"]
    for w in WHEELS:
        ws = m.wheels[w]
        lin = ws.linearity
        cells = (
            wheel(w), str(ws.slip_samples), fmt(ws.mean_slip, 100, 2), escape(lin.verdict),
            fmt(lin.peak_fx_n, 1, 0), fmt(lin.peak_fx_slip, 100, 2), fmt(ws.cx_fit_n, 1e-3, 1),
            fmt(ws.cx_fit_conf, 1, 2), escape(ws.cx_fit_source), fmt(ws.peak_cx_n, 1e-3, 1),
            fmt(ws.peak_cx_slip, 100, 2), fmt(ws.mean_re_m, 1000, 2), fmt(ws.r0_m, 1000, 2),
            "–" if ws.lost_frames is None else str(ws.lost_frames),
            fmt(ws.mu_slip.mu_peak if ws.mu_slip else None, 1, 3),
            fmt(ws.mu_slip.slip_at_mu_peak if ws.mu_slip else None, 100, 1),
        )
        out.append("<tr>" + "".join(f'<td{" class=l" if i in (0, 3, 8) else ""}>{c}</td>'
                                     for i, c in enumerate(cells)) + "</tr>")
    out.append("</tbody></table>")
    lat = fmt(m.gps_latency_s, 1, 3)
    out.append(f'<p class="note">t = {m.t_start_s:.1f}–{m.t_end_s:.1f} s after the log\'s first estimate, '
               f"{len(m.rows)} estimates, speed {m.speed_from_kmh:.1f} → {m.speed_to_kmh:.1f} km/h; "
               f"GPS latency {lat} s ({escape(m.gps_latency_source)}); bad sentences in the log: "
               f"{'–' if log.bad_sentences is None else log.bad_sentences}.</p>")
    b = m.brake
    if b is not None:
        abs_text = f"{b.abs_cycles} ABS cycles at {fmt(b.abs_frequency_hz, 1, 1)} Hz ({b.abs_wheel})" \
            if b.abs_cycles else "no ABS cycling"
        out.append(f'<p class="note"><b>Brake test</b>: onset at {b.onset_s - (log.t0_s or 0.0):.2f} s '
                   f"({escape(b.onset_source)}) from {b.brake_speed_kmh:.1f} km/h; stopping distance "
                   f"{fmt(b.stopping_distance_m, 1, 2)} m, corrected to {fmt(b.nominal_speed_kmh, 1, 0)} km/h: "
                   f"{fmt(b.stopping_distance_corrected_m, 1, 2)} m; MFDD {fmt(b.mfdd_mps2, 1, 2)} m/s² "
                   f"(0.8·v0 to 0.1·v0); {escape(abs_text)}.</p>")
    return "\n".join(out)


def records_table(log: LogSummary) -> str:
    """The log's accelerate and brake maneuvers as the live /maneuver records give them, in time order."""
    out = ['<table class="records"><thead><tr><th>#</th><th class=l>kind</th><th>from km/h</th><th>to km/h</th>'
           "<th>target km/h</th><th class=l>result</th><th>slip front %</th><th>slip rear %</th>"
           "<th class=l>valid</th></tr></thead><tbody>"]
    for r in log.records:
        ax = axle_slip_pct(r)
        out.append(f"<tr><td>{r.index}</td><td class=l>{escape(r.kind)}</td><td>{fmt(r.speed_from_kmh)}</td>"
                   f"<td>{fmt(r.speed_to_kmh)}</td><td>{fmt(r.target_speed_kmh, digits=0)}</td>"
                   f"<td class=l>{escape(figures_text(r))}</td><td>{fmt(ax['front'])}</td><td>{fmt(ax['rear'])}</td>"
                   f"<td class=l>{escape(verdict(r))}</td></tr>")
    out.append("</tbody></table>")
    return "\n".join(out)


def comparison_table(c: Comparison) -> str:
    """Per wheel and group: mean fitted Cx, largest peak linear Fx and its slip, earliest end of linearity, mean Re."""
    metrics: tuple[tuple[str, Callable[[Any], str]], ...] = (
        ("fitted Cx [kN]", lambda g: fmt(g.cx_fit_n, 1e-3, 1)),
        ("peak linear Fx [N]", lambda g: fmt(g.peak_linear_fx_n, 1, 0)),
        ("slip at peak [%]", lambda g: fmt(g.peak_linear_fx_slip, 100, 2)),
        ("end of linearity", lambda g: "linear throughout" if g.linear_end_slip is None
         else f"{abs(g.linear_end_slip) * 100:.1f} %"),
        ("mean Re [mm]", lambda g: fmt(g.mean_re_m, 1000, 2)),
    )
    out = ["<table><thead><tr><th>wheel</th><th class=l>figure</th>"]
    for g in c.groups:
        logs = "<br>".join(f"{escape(n)}: {escape(t)}" for n, t in zip(g.logs, g.titles))
        out.append(f'<th class=l>{escape(g.group)}<br><span class="note">{logs}</span></th>')
    out.append("</tr></thead><tbody>")
    for w in WHEELS:
        for i, (name, get) in enumerate(metrics):
            row = f"<td rowspan={len(metrics)} class=l>{wheel(w)}</td>" if i == 0 else ""
            row += f"<td class=l>{escape(name)}</td>" + "".join(f"<td>{get(g.wheels[w])}</td>" for g in c.groups)
            out.append(f"<tr>{row}</tr>")
    out.append("</tbody></table>")
    return "\n".join(out)
