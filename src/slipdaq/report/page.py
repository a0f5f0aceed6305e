"""index.html: one page, offline, the plots drawn in the browser (plotly.js and the data beside it, page_data.py);
the tables (page_tables.py) and a note make it readable without JavaScript, with the PNGs when `--png` drew them."""

from __future__ import annotations

import datetime as dt
from collections.abc import Sequence
from dataclasses import dataclass, field
from html import escape
from pathlib import Path
from typing import Any

import slipdaq
from slipdaq import WHEELS
from slipdaq.maneuver.figures import ManeuverSummary
from slipdaq.report import page_sets
from slipdaq.report import page_tables as tables
from slipdaq.report.page_data import COMPARE_SCRIPT, LOG_SCRIPT, PAGE_JS, PLOTLY_JS, PagePlots, compare_name
from slipdaq.report.style import PAGE_PLOTS, TIME_PLOTS
from slipdaq.report.summary import Comparison, LogSummary
from slipdaq.report.tires import GroupTires
from slipdaq.report.write import RULE_TEXT


@dataclass(frozen=True)
class LogLinks:
    """What the page shows of one log besides its summary: its plots, and its PNGs (paths relative to DIR)."""

    page: PagePlots
    pngs: dict[str, dict[str, str]] = field(default_factory=dict)
    """maneuver key -> stem -> PNG path."""


CSS = """
body { font-family: system-ui, sans-serif; margin: 1.5em; color: #222; max-width: 1800px; }
table { border-collapse: collapse; margin: 0.5em 0 1em; font-size: 0.9em; }
th, td { border: 1px solid #ccc; padding: 3px 8px; text-align: right; }
th { background: #f2f2f2; } td.l, th.l { text-align: left; }
.sw { display: inline-block; width: 0.9em; height: 0.9em; border-radius: 2px; vertical-align: -1px; margin-right: 4px; }
.note { color: #555; font-size: 0.9em; max-width: 75em; }
.warn { background: #fff4d6; border: 1px solid #e0c060; padding: 0.5em 0.8em; max-width: 75em; }
h2 { border-bottom: 2px solid #ddd; padding-bottom: 3px; margin-top: 2em; }
.plots { display: grid; grid-template-columns: repeat(auto-fill, minmax(520px, 1fr)); gap: 10px; }
.plot { margin: 0; border: 1px solid #ddd; }
.plot.wide { grid-column: 1 / -1; }
.box { height: 360px; } .wide .box { height: 480px; }
.plot figcaption { font-size: 0.8em; color: #555; padding: 2px 6px; }
.plot img { width: 100%; height: auto; }
table[data-slipdaq-table] th[data-sort] { cursor: pointer; user-select: none; }
table[data-slipdaq-table] th[aria-sort=ascending]::after { content: " ▲"; }
table[data-slipdaq-table] th[aria-sort=descending]::after { content: " ▼"; }
table[data-slipdaq-table] tbody tr:hover { background: #eef5ff; cursor: pointer; }
section.maneuver:target > h3 { background: #fff4d6; }
"""
NOSCRIPT_CSS = ".box { display: none; } .plot.nopng { display: none; }"
HOW_TO = ("Plots: hover for the values under the cursor, drag to zoom (double-click: back), click a legend entry to hide "
          "or show it (double-click: it alone); the two time plots of a maneuver zoom together. Each plot's camera "
          "icon saves it as a PNG. The maneuvers table sorts by a click on its heading; a click on a row goes to that "
          "maneuver.")


def _plot(name: str, src: str, title: str, png: str | None = None, link: str | None = None, wide: bool = False) -> str:
    """A plot's container (data-slipdaq-plot), its caption, and its PNG when there is one (shown without JS)."""
    attrs = f'data-slipdaq-plot="{escape(name)}" data-slipdaq-src="{escape(src)}"'
    if link:
        attrs += f' data-slipdaq-link="{escape(link)}"'
    cls = "plot" + (" wide" if wide else "") + ("" if png else " nopng")
    if not png:
        return f'<figure class="{cls}"><div class="box" {attrs}></div></figure>'
    img = f'<noscript><a href="{escape(png)}"><img src="{escape(png)}" alt="{escape(title)}"></a></noscript>'
    cap = f'<figcaption>{escape(title)} · <a href="{escape(png)}">PNG</a></figcaption>'
    return f'<figure class="{cls}"><div class="box" {attrs}></div>{img}{cap}</figure>'


def _maneuver(log: LogSummary, m: ManeuverSummary, links: LogLinks) -> str:
    src = f"{log.name}/{LOG_SCRIPT}"
    names = links.page.plots.get(m.key, {})
    pngs = links.pngs.get(m.key, {})
    group = f"{log.name}/{m.key}"
    plots = [_plot(names[stem], src, title, pngs.get(stem), group if stem in TIME_PLOTS else None)
             for stem, title in PAGE_PLOTS if stem in names]
    plots += [f'<figure class="plot"><figcaption><a href="{escape(p)}">{escape(stem)} (PNG)</a></figcaption></figure>'
              for stem, p in pngs.items() if stem not in names]
    return (f'<section class="maneuver" id="{escape(tables.maneuver_anchor(log, m))}">'
            f"<h3>{escape(m.title)} <small class=note>({escape(log.name)})</small></h3>\n"
            + tables.wheels_table(log, m) + '\n<div class="plots">' + "".join(plots) + "</div></section>")


def _tires(groups: Sequence[GroupTires], files: dict[str, dict[str, str]]) -> list[str]:
    """The tire files' section: per label group a link per wheel, or why it has none."""
    out = ['<h2 id="tires">Tire files (Magic Formula 6.1)</h2>',
           '<p class="note">One <code>.tir</code> per tire and label group: the pure longitudinal force fitted to the '
           "maneuvers' mu-slip points, valid over the slip its data covered (KPUMIN, KPUMAX); where and how, in its "
           "<code>[SLIPDAQ]</code> comment block.</p>",
           '<table><tr><th class="l">group</th>' + "".join(f"<th>{tables.wheel(w)}</th>" for w in WHEELS) + "</tr>"]
    for g in groups:
        cells = []
        for r in g.results:
            href = files.get(g.group, {}).get(r.wheel)
            if href:
                extra = "" if r.fit is None or r.fit.peak_passed else " (peak not passed)"
                cells.append(f'<td class="l"><a href="{escape(href)}">{escape(r.wheel)}.tir</a>{extra}</td>')
            else:
                cells.append(f'<td class="l note">{escape(r.reason)}</td>')
        out.append(f'<tr><td class="l">{escape(g.group)}</td>' + "".join(cells) + "</tr>")
    return [*out, "</table>"]


def write_html(logs: Sequence[LogSummary], comparisons: Sequence[Comparison], links: dict[str, LogLinks],
               compare_pngs: dict[str, str], path: Path,
               tires: tuple[Sequence[GroupTires], dict[str, dict[str, str]]] = ((), {}), *,
               group_sets: dict[str, list[dict[str, Any]]] | None = None,
               differences: Sequence[dict[str, Any]] = ()) -> None:
    """index.html at path; links: per log name its plots and PNGs; compare_pngs: phase -> PNG path; tires: the tire
    files' groups and their paths (report/tires.py); group_sets: per label group its test sets; differences: between
    the groups (report.sets)."""
    now = dt.datetime.now(dt.UTC).isoformat(timespec="seconds")
    any_png = bool(compare_pngs) or any(v.pngs for v in links.values())
    out = [
        '<!doctype html>\n<html lang="en"><head><meta charset="utf-8">'
        '<meta name="viewport" content="width=device-width, initial-scale=1"><title>slipdaq report</title>',
        f"<style>{CSS}</style><noscript><style>{NOSCRIPT_CSS}</style></noscript></head><body>",
        "<h1>slipdaq report</h1>",
        '<noscript><p class="warn">The plots on this page are drawn by JavaScript (plotly.min.js beside it), which '
        "is off: the tables below hold every figure, summary.csv and summary.json all of them"
        + ("; the PNGs are shown in place of the plots" if any_png else "; <code>slipdaq report --png</code> also "
           "writes the plots as PNG files") + ".</p></noscript>",
        f'<p class="note">{len(logs)} log(s), slipdaq {escape(slipdaq.__version__)}, {now}. Tables: '
        '<a href="summary.csv">summary.csv</a>, <a href="summary.json">summary.json</a>. '
        "Slip s is SAE slip (positive driving, negative braking); Fx is the force per tire; Cx = Fx/s is in kN "
        f"per unit slip. Wheels: {' '.join(tables.wheel(w) for w in WHEELS)}.</p>",
        f'<p class="note">{escape(HOW_TO)}</p>',
        f'<p class="note"><b>Linear region:</b> {escape(RULE_TEXT)}</p>',
        '<h2 id="maneuvers">Maneuvers</h2>', tables.maneuvers_table(logs),
        "<h2>Logs</h2>", tables.logs_table(logs),
    ]
    if tires[0]:
        out += _tires(*tires)
    if comparisons:
        out.append("<h2>Comparison by labels</h2>")
        out.append('<p class="note">Logs grouped by their labels (every label but <code>maneuver</code>, unless '
                   "<code>--group-by</code> names the keys); per group the mean fitted Cx, the largest peak linear "
                   "Fx, the earliest end of linearity and the mean Re over its logs.</p>")
        for c in comparisons:
            out.append(f"<h3>{escape(c.phase)}</h3>")
            out.append(tables.comparison_table(c))
            out.append('<div class="plots">' + _plot(compare_name(c.phase), COMPARE_SCRIPT,
                                                     f"Fx against slip, {c.phase}, by label group",
                                                     compare_pngs.get(c.phase), wide=True) + "</div>")
    if len(logs) > 1 and any(group_sets.values() if group_sets else ()):
        out.append("<h2>Test sets by label group</h2>")
        out += [page_sets.sets_table(rs, f": {g}") for g, rs in (group_sets or {}).items() if rs]
    if differences:
        out.append("<h2>Differences between groups</h2>")
        out.append('<p class="note">Each group\'s mean with its 95 % interval (Student t) and the difference of '
                   "the means with its 95 % interval (Welch–Satterthwaite), for each figure of a test set (its "
                   "counted runs) and of every valid maneuver of a kind; in bold where the interval excludes "
                   "zero.</p>")
        out.append(page_sets.differences_table(differences))
    for log in logs:
        lk = links.get(log.name, LogLinks(PagePlots({}, None, b"")))
        out.append(f'<section id="{escape(tables.log_anchor(log))}"><h2>{escape(log.title)}</h2>')
        out.append(f'<p class="note">{escape(log.path)} — group {escape(log.group)}, {log.estimates} estimates</p>')
        if lk.page.overview:
            out.append('<div class="plots">' + _plot(lk.page.overview, f"{log.name}/{LOG_SCRIPT}",
                                                     "the whole log: slip and speed", wide=True) + "</div>")
        if not log.maneuvers:
            out.append('<p class="note">No maneuver with a defined slip in this log.</p>')
        if log.records:
            out.append(tables.records_table(log))
        if log.test_sets:
            out.append(page_sets.sets_table(log.test_sets))
        out += [_maneuver(log, m, lk) for m in log.maneuvers]
        out.append("</section>")
    out.append(f'<script src="{PLOTLY_JS}"></script><script src="{PAGE_JS}"></script>')
    out.append("</body></html>\n")
    path.write_text("\n".join(out), encoding="utf-8")

