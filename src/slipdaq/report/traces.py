"""The page's figures as Plotly JSON (dicts and lists; plotly.js draws them in the browser, nothing is drawn here):
traces, layouts, numbers rounded for the page, the high-rate columns of a log, and min–max decimation.

A figure is {"data": [trace, ...], "layout": {...}}, as `Plotly.newPlot` takes it. Undefined values are null (a gap
in a line, no marker).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from html import escape
from typing import Any

import numpy as np

from slipdaq import WHEELS
from slipdaq.records.fast_rows import FastRows
from slipdaq.report.style import WHEEL_STYLE

Figure = dict[str, Any]
"""{"data": [...], "layout": {...}}: one plot's Plotly JSON."""

GRID = "#e3e3e3"
NO_DATA = "no defined values in this maneuver"


def nums(values: Any, digits: int) -> np.ndarray:
    """A column for the page: rounded to `digits` decimals, NaN, the infinities and None as null. A float64 array, which
    the page's scripts (page_data: orjson with OPT_SERIALIZE_NUMPY, the only way figures are written) write as the
    same bytes as the list of its values with None for NaN."""
    return np.round(np.asarray(values, dtype=np.float64), digits)


def pairs(rows: Sequence[dict[str, Any]], x: str, y: str) -> tuple[np.ndarray, np.ndarray]:
    """(x, y) of the rows where both are defined."""
    xs = np.array([r.get(x) for r in rows], dtype=np.float64)
    ys = np.array([r.get(y) for r in rows], dtype=np.float64)
    keep = np.isfinite(xs) & np.isfinite(ys)
    return xs[keep], ys[keep]


def hover(name: str, x: str, y: str) -> str:
    """A hover template: the trace's name, then x and y with their units (e.g. "%{x:.2f} % slip")."""
    return f"{escape(name)}<br>{x}<br>{y}<extra></extra>"


def points(w: str, x: Any, y: Any, *, name: str | None = None, xd: int = 3, yd: int = 3, tip: tuple[str, str],
           size: float = 6.0, opacity: float = 0.8, **kw: Any) -> dict[str, Any]:
    """A wheel's markers in its colour and symbol; tip: the hover's x and y parts."""
    st = WHEEL_STYLE[w]
    trace = {"type": "scatter", "mode": "markers", "name": name or w, "legendgroup": w, "x": nums(x, xd),
             "y": nums(y, yd), "marker": {"color": st["color"], "symbol": st["symbol"], "size": size,
                                          "opacity": opacity},
             "hovertemplate": hover(name or w, *tip)}
    return trace | kw


def line(x: Any, y: Any, *, name: str, color: str, dash: str = "solid", width: float = 1.5, xd: int = 3,
         yd: int = 3, tip: tuple[str, str] | None = None, **kw: Any) -> dict[str, Any]:
    """A line (null values break it)."""
    trace = {"type": "scatter", "mode": "lines", "name": name, "x": nums(x, xd), "y": nums(y, yd),
             "line": {"color": color, "dash": dash, "width": width}, "connectgaps": False}
    if tip is None:
        trace["hoverinfo"] = "skip"
    else:
        trace["hovertemplate"] = hover(name, *tip)
    return trace | kw


def axis(title: str, **kw: Any) -> dict[str, Any]:
    return {"title": {"text": title}, "gridcolor": GRID, "zeroline": True, "zerolinecolor": "#999999",
            "automargin": True} | kw


def layout(title: str, subtitle: str, x: str, y: str, *, any_data: bool = True, **kw: Any) -> dict[str, Any]:
    """The common layout: the title (quantity, then the maneuver and log), axes with units, the legend, 'no data'.
    No height: the plot takes its container's (the page's CSS)."""
    out: dict[str, Any] = {
        "title": {"text": f"{escape(title)}<br><span style='font-size:11px'>{escape(subtitle)}</span>",
                  "font": {"size": 14}, "x": 0.01, "xanchor": "left"},
        "xaxis": axis(x), "yaxis": axis(y), "hovermode": "closest", "autosize": True,
        "margin": {"l": 60, "r": 10, "t": 56, "b": 44}, "legend": {"font": {"size": 10}, "groupclick": "toggleitem"},
        "plot_bgcolor": "white", "paper_bgcolor": "white", "font": {"family": "system-ui, sans-serif", "size": 11},
    }
    if not any_data:
        out["annotations"] = [{"text": NO_DATA, "xref": "paper", "yref": "paper", "x": 0.5, "y": 0.5,
                               "showarrow": False, "font": {"color": "#888888", "size": 13}}]
    return out | kw


def figure(data: list[dict[str, Any]], lay: dict[str, Any]) -> Figure:
    return {"data": data, "layout": lay}


# ---- the high-rate rows of a log ----------------------------------------------------------------------------

@dataclass(frozen=True)
class HighRate:
    """A log's /slip/fast rows as columns (log clock, in time order; NaN: undefined)."""

    time_s: np.ndarray
    speed_mps: np.ndarray
    slips: dict[str, np.ndarray]
    wheel_speeds_mps: dict[str, np.ndarray]

    def __len__(self) -> int:
        return len(self.time_s)

    @classmethod
    def of(cls, rows: Sequence[dict[str, Any]]) -> HighRate:
        """From the rows as dicts (a log's), or as columns (FastRows: read as they are)."""
        if isinstance(rows, FastRows):
            b = rows.columns()
            nan = np.full(len(b), np.nan)
            t, speed = b.time_s, b.speed_mps
            slips = {w: b.slip.get(w, nan) for w in WHEELS}
            wheel_speeds = {w: b.wheel_speed_mps.get(w, nan) for w in WHEELS}
        else:
            def col(key: str) -> np.ndarray:
                return np.array([r.get(key) for r in rows], dtype=np.float64)

            t, speed = col("time_s"), col("speed_mps")
            slips = {w: col(f"slip_{w}") for w in WHEELS}
            wheel_speeds = {w: col(f"wheel_speed_{w}_mps") for w in WHEELS}
        order = np.argsort(t, kind="stable") if len(t) > 1 and np.any(np.diff(t) < 0) else slice(None)
        return cls(t[order], speed[order], {w: v[order] for w, v in slips.items()},
                   {w: v[order] for w, v in wheel_speeds.items()})

    def between(self, t_from_s: float, t_to_s: float) -> HighRate:
        """The rows with t_from_s <= time_s <= t_to_s: every one of them."""
        part = slice(int(np.searchsorted(self.time_s, t_from_s, side="left")),
                     int(np.searchsorted(self.time_s, t_to_s, side="right")))
        return HighRate(self.time_s[part], self.speed_mps[part], {w: v[part] for w, v in self.slips.items()},
                        {w: v[part] for w, v in self.wheel_speeds_mps.items()})


EMPTY = HighRate(np.empty(0), np.empty(0), {w: np.empty(0) for w in WHEELS}, {w: np.empty(0) for w in WHEELS})


def minmax_indices(t: np.ndarray, y: np.ndarray, buckets: int) -> np.ndarray:
    """Indices of the points to draw of a time series (t sorted): all when there are at most 2·buckets, else the
    smallest and largest y of each of `buckets` equal time slices (what a line can show at that width), in order."""
    n = len(t)
    if n <= 2 * buckets:
        return np.arange(n)
    width = float(t[-1] - t[0]) or 1.0
    b = np.minimum(((t - t[0]) * (buckets / width)).astype(np.int64), buckets - 1)
    starts = np.flatnonzero(np.r_[True, b[1:] != b[:-1]])
    nan = np.isnan(y)
    low = np.lexsort((np.where(nan, np.inf, y), b))[starts]
    high = np.lexsort((np.where(nan, np.inf, -y), b))[starts]
    return np.unique(np.r_[low, high])


def thin(n: int, most: int) -> slice:
    """Every k-th of n items so that at most `most` remain."""
    return slice(None, None, max(1, -(-n // most)))
