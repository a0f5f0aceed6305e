"""The page's plots over a whole log and across logs (Plotly JSON, traces.py), thinned to what a plot can show:
a log's overview (speed and each wheel's high-rate slip over the whole log, the maneuvers shaded; min–max per time
slice, OVERVIEW_BUCKETS slices) and, per phase, Fx against slip of every log by label group (the windows' points, at
most COMPARE_POINTS_MAX per group and wheel, and each maneuver's fitted line)."""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import numpy as np

from slipdaq import WHEELS
from slipdaq.report.style import SLIP_LABEL, TIME_LABEL, WHEEL_STYLE
from slipdaq.report.summary import LogSummary
from slipdaq.report.traces import Figure, HighRate, axis, figure, hover, layout, minmax_indices, nums, pairs, thin

OVERVIEW_BUCKETS = 1000
"""A whole log's series are drawn as the smallest and largest value in each of this many time slices."""
COMPARE_POINTS_MAX = 3000
"""The comparison shows at most this many points per group and wheel (evenly thinned)."""
GROUP_SYMBOLS = ("circle", "x", "square", "cross", "diamond", "star", "triangle-down", "pentagon")
GROUP_DASHES = ("dash", "dot", "dashdot", "longdash")
SHADE = "rgba(120, 120, 120, 0.12)"


def overview(log: LogSummary, hr: HighRate) -> Figure | None:
    """Speed (right axis) and each wheel's slip over the whole log, the maneuvers shaded and named; None without
    high-rate rows."""
    if not len(hr):
        return None
    t0 = log.t0_s if log.t0_s is not None else float(hr.time_s[0])
    t = hr.time_s - t0
    data: list[dict[str, Any]] = []
    for w in WHEELS:
        s = hr.slips[w] * 100.0
        keep = minmax_indices(t, s, OVERVIEW_BUCKETS)
        data.append({"type": "scatter", "mode": "lines", "name": f"{w} slip", "legendgroup": w, "x": nums(t[keep], 3),
                     "y": nums(s[keep], 3), "line": {"color": WHEEL_STYLE[w]["color"], "width": 1},
                     "connectgaps": False, "hovertemplate": hover(f"{w} slip", "t %{x:.2f} s", "%{y:.2f} %")})
    v = hr.speed_mps * 3.6
    keep = minmax_indices(t, v, OVERVIEW_BUCKETS)
    data.append({"type": "scatter", "mode": "lines", "name": "speed", "x": nums(t[keep], 3), "y": nums(v[keep], 2),
                 "yaxis": "y2", "line": {"color": "black", "width": 1.5}, "connectgaps": False,
                 "hovertemplate": hover("speed", "t %{x:.2f} s", "%{y:.1f} km/h")})
    lay = layout("the whole log: slip and speed", f"{log.title} — maneuvers shaded; min and max per "
                 f"1/{OVERVIEW_BUCKETS} of the log", TIME_LABEL, SLIP_LABEL)
    lay["yaxis2"] = axis("speed [km/h]", overlaying="y", side="right", showgrid=False, zeroline=False,
                         rangemode="tozero")
    lay["hovermode"] = "x unified"
    lay["shapes"] = [{"type": "rect", "xref": "x", "yref": "paper", "x0": m.t_start_s, "x1": m.t_end_s, "y0": 0,
                      "y1": 1, "fillcolor": SHADE, "line": {"width": 0}, "layer": "below"} for m in log.maneuvers]
    lay["annotations"] = [{"text": m.title, "xref": "x", "yref": "paper", "x": m.t_start_s, "xanchor": "left",
                           "y": 0.99, "yanchor": "top", "textangle": -90, "showarrow": False,
                           "font": {"size": 9, "color": "#555555"}} for m in log.maneuvers]
    lay["margin"] = lay["margin"] | {"r": 60}
    return figure(data, lay)


def comparison(phase: str, logs: Sequence[LogSummary]) -> Figure:
    """Fx against slip of every log's `phase` maneuvers: wheel colours, a symbol and line dash per label group, a
    legend section per group (each entry toggles on its own)."""
    logs = [log for log in logs if any(m.phase == phase for m in log.maneuvers)]
    groups = list(dict.fromkeys(log.group for log in logs))
    data: list[dict[str, Any]] = []
    for gi, g in enumerate(groups):
        first = True
        for w in WHEELS:
            xs: list[np.ndarray] = []
            ys: list[np.ndarray] = []
            who: list[str] = []
            lx: list[float | None] = []
            ly: list[float | None] = []
            for log in logs:
                if log.group != g:
                    continue
                for m in log.maneuvers:
                    if m.phase != phase:
                        continue
                    x, y = pairs(m.rows, f"slip_{w}", f"force_{w}_n")
                    if not len(x):
                        continue
                    xs.append(x * 100.0)
                    ys.append(y)
                    who += [f"{log.name}: {m.title}"] * len(x)
                    fit = m.wheels[w].linearity.line
                    if fit is not None:
                        lo, hi = min(float(x.min()), 0.0) * 105.0, max(float(x.max()), 0.0) * 105.0
                        lx += [lo, hi, None]
                        ly += [fit.force_n(lo / 100.0), fit.force_n(hi / 100.0), None]
            if not xs:
                continue
            x_all, y_all = np.concatenate(xs), np.concatenate(ys)
            keep = thin(len(x_all), COMPARE_POINTS_MAX)
            color = WHEEL_STYLE[w]["color"]
            group = {"legendgroup": f"group-{gi}"} | ({"legendgrouptitle": {"text": g}} if first else {})
            first = False
            data.append({"type": "scatter", "mode": "markers", "name": f"{w} points", "x": nums(x_all[keep], 3),
                         "y": nums(y_all[keep], 1), "text": who[keep], "marker": {
                             "color": color, "symbol": GROUP_SYMBOLS[gi % len(GROUP_SYMBOLS)], "size": 6,
                             "opacity": 0.75},
                         "hovertemplate": hover(f"{g} {w}", "%{text}<br>slip %{x:.2f} %", "Fx %{y:.0f} N")} | group)
            if lx:
                data.append({"type": "scatter", "mode": "lines", "name": f"{w} fitted lines",
                             "x": [None if v is None else round(v, 3) for v in lx],
                             "y": [None if v is None else round(v, 1) for v in ly],
                             "line": {"color": color, "dash": GROUP_DASHES[gi % len(GROUP_DASHES)], "width": 1.4},
                             "connectgaps": False, "hoverinfo": "skip"} | group)
    lay = layout(f"tire force Fx against slip — {phase}, {len(logs)} logs by label group", " vs ".join(groups),
                 SLIP_LABEL, "tire force Fx [N]", any_data=bool(data))
    return figure(data, lay)
