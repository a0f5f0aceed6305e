"""The page's data: a log's figures (page_maneuver, page_mu_brake, page_compare) by plot name, as a script beside
index.html (DIR/<log>/plots.js, loaded when one of its plots comes into view), the comparison's (DIR/compare.js), and
the page's own script and plotly.js, written once into DIR. A script calls `slipdaqReport.add({name: figure, ...})`.

Plot names (each plot's container carries `data-slipdaq-plot="NAME"`): `<log>/<key>-<stem>` per maneuver (stems:
style.PAGE_PLOTS), `<log>/overview`, `compare-<phase>-fx-slip`.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field
from importlib import resources
from pathlib import Path
from typing import Any

import orjson

from slipdaq.maneuver.figures import span_s
from slipdaq.report import page_compare, page_maneuver, page_mu_brake
from slipdaq.report.style import PAGE_PLOTS
from slipdaq.report.summary import Comparison, LogSummary
from slipdaq.report.traces import EMPTY, Figure, HighRate

LOG_SCRIPT = "plots.js"
COMPARE_SCRIPT = "compare.js"
PLOTLY_JS = "plotly.min.js"
PAGE_JS = "slipdaq-report.js"


@dataclass(frozen=True)
class PagePlots:
    """One log's plots on the page: names by maneuver key and stem, its overview's name, and the script that holds
    their figures (the bytes of DIR/<log>/plots.js): small and picklable (a batch task returns it)."""

    plots: dict[str, dict[str, str]]
    overview: str | None
    script: bytes = field(repr=False)


def plot_name(log: str, key: str, stem: str) -> str:
    return f"{log}/{key}-{stem}"


def compare_name(phase: str) -> str:
    return f"compare-{phase}-fx-slip"


def script(figures: dict[str, Figure]) -> bytes:
    """The figures as a script that hands them to the page: compact UTF-8 JSON by orjson (the bytes of `json.dumps`
    with `ensure_ascii=False` and no spaces but for a number below 1e-4, written 0.00001 for 1e-05; a NaN is null, as
    traces.nums writes it)."""
    return b"slipdaqReport.add(" + orjson.dumps(figures, option=orjson.OPT_SERIALIZE_NUMPY) + b");\n"


def maneuver_figures(log: LogSummary, m: Any, hr: HighRate) -> dict[str, Figure]:
    """The page's plots of one maneuver by stem; hr: the log's high-rate rows (every one in the span is drawn)."""
    t_from, t_to = span_s(m.phase, m.rows)
    span = hr.between(t_from, t_to)
    t0 = log.t0_s or 0.0
    x_range = [round(t_from - t0, 3), round(t_to - t0, 3)]
    return {
        "slip-time": page_maneuver.slip_time(log, m, span, x_range),
        "speed-time": page_mu_brake.speed_time(log, m, span, x_range),
        "speed-slip": page_maneuver.speed_slip(log, m),
        "fx-slip": page_maneuver.fx_slip(log, m),
        "re-slip": page_maneuver.re_slip(log, m),
        "cx-slip": page_maneuver.cx_slip(log, m),
        "mu-slip": page_mu_brake.mu_slip(log, m),
    }


class _Script:
    """script() of figures given one at a time, each encoded as it comes (its lists then let go): the bytes of
    script() of the dict of them (a name given again: its new figure in the first one's place)."""

    def __init__(self) -> None:
        self._parts: list[bytes] = []
        self._at: dict[str, int] = {}

    def add(self, name: str, figure: Figure) -> None:
        entry = orjson.dumps(name) + b":" + orjson.dumps(figure, option=orjson.OPT_SERIALIZE_NUMPY)
        if name in self._at:
            self._parts[self._at[name]] = entry
        else:
            self._at[name] = len(self._parts)
            self._parts.append(entry)

    def bytes(self) -> bytes:
        return b"slipdaqReport.add({" + b",".join(self._parts) + b"});\n"


def log_page(log: LogSummary, fast: Sequence[dict[str, Any]] = ()) -> PagePlots:
    """A log's plots on the page, from its summary and its /slip/fast rows (none: no high-rate lines); each
    maneuver's figures encoded as they are made."""
    hr = HighRate.of(fast) if fast else EMPTY
    out = _Script()
    names: dict[str, dict[str, str]] = {}
    over = page_compare.overview(log, hr)
    over_name = f"{log.name}/overview" if over is not None else None
    if over is not None and over_name is not None:
        out.add(over_name, over)
    for m in log.maneuvers:
        made = maneuver_figures(log, m, hr)
        names[m.key] = {}
        for stem, _ in PAGE_PLOTS:
            name = plot_name(log.name, m.key, stem)
            out.add(name, made[stem])
            names[m.key][stem] = name
    return PagePlots(names, over_name, out.bytes())


def compare_script(comparisons: Sequence[Comparison], logs: Sequence[LogSummary]) -> bytes:
    return script({compare_name(c.phase): page_compare.comparison(c.phase, logs) for c in comparisons})


def write_assets(out: Path) -> list[Path]:
    """plotly.js (the plotly package's own file, `plotly.offline.get_plotlyjs`) and the page's script, in out."""
    from plotly.offline import get_plotlyjs

    plotly, page = out / PLOTLY_JS, out / PAGE_JS
    plotly.write_text(get_plotlyjs(), encoding="utf-8")
    page.write_bytes(resources.files("slipdaq.report").joinpath("page.js").read_bytes())
    return [plotly, page]
