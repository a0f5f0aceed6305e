"""The page's μ–slip plot (every high-rate point the fit used, the fitted Burckhardt curve and its peak) and speed
against time over a maneuver's span (the fused speed and each wheel's at high rate, the windows' GPS speed), with the
brake test's marks (onset and its speed, standstill, the MFDD's 0.8·v0 and 0.1·v0) or an acceleration's launch and
top speed. Plotly JSON (traces.py)."""

from __future__ import annotations

from typing import Any

import numpy as np

from slipdaq import WHEELS
from slipdaq.maneuver.figures import ManeuverSummary
from slipdaq.report.page_maneuver import SLIP_TIP, subtitle
from slipdaq.report.style import SLIP_LABEL, TIME_LABEL, WHEEL_STYLE
from slipdaq.report.summary import LogSummary
from slipdaq.report.traces import Figure, HighRate, figure, layout, line, pairs, points

MARK = "#444444"
CURVE_POINTS = 200


def mu_slip(log: LogSummary, m: ManeuverSummary) -> Figure:
    data: list[dict[str, Any]] = []
    for w in WHEELS:
        slip, mu = m.mu_points.get(w, (np.empty(0), np.empty(0)))
        if len(slip) == 0:
            continue
        color = WHEEL_STYLE[w]["color"]
        fit = m.wheels[w].mu_slip
        data.append(points(w, slip * 100.0, mu, name=f"{w} high-rate", yd=4, size=4, opacity=0.45,
                           tip=(SLIP_TIP, "μ %{y:.3f}")))
        if fit is None:
            continue
        x = np.linspace(0.0, fit.max_abs_slip, CURVE_POINTS) * fit.slip_sign
        data.append(line(x * 100.0, fit.mu(x), name=f"{w} fitted {fit.model}", color=color, width=2, yd=4,
                         legendgroup=w, tip=(SLIP_TIP, "μ %{y:.3f} fitted")))
        if fit.mu_peak is not None and fit.slip_at_mu_peak is not None:
            data.append(points(w, [fit.slip_sign * fit.slip_at_mu_peak * 100.0], [fit.slip_sign * fit.mu_peak],
                               name=f"{w} μ peak {fit.mu_peak:.2f} at {fit.slip_at_mu_peak * 100:.1f} %", yd=4,
                               tip=(SLIP_TIP, "μ peak %{y:.3f}"))
                        | {"marker": {"color": color, "symbol": "star", "size": 16, "line": {"color": "black",
                                                                                             "width": 1}}})
    return figure(data, layout("friction coefficient μ = Fx/Fz against slip (high-rate)", subtitle(log, m),
                               SLIP_LABEL, "μ = Fx / Fz", any_data=bool(data)))


def _mark(t_s: float, top_kmh: float, name: str, dash: str = "dash") -> dict[str, Any]:
    """A vertical line at t_s from 0 to top_kmh (a trace: it has a hover and a legend entry)."""
    return line([t_s, t_s], [0.0, top_kmh], name=name, color=MARK, dash=dash, width=1.5,
                tip=("t %{x:.2f} s", ""))


def speed_time(log: LogSummary, m: ManeuverSummary, hr: HighRate, x_range: list[float]) -> Figure:
    t0 = log.t0_s or 0.0
    data: list[dict[str, Any]] = []
    speeds = [hr.speed_mps * 3.6]
    if np.isfinite(hr.speed_mps).any():
        data.append(line(hr.time_s - t0, hr.speed_mps * 3.6, name="speed (fused, high-rate)", color="black",
                         width=2, yd=3, tip=("t %{x:.3f} s", "V %{y:.2f} km/h")))
    for w in WHEELS:
        v = hr.wheel_speeds_mps[w] * 3.6
        if np.isfinite(v).any():
            speeds.append(v)
            data.append(line(hr.time_s - t0, v, name=f"{w} wheel", color=WHEEL_STYLE[w]["color"], width=1,
                             yd=3, legendgroup=w, tip=("t %{x:.3f} s", "wheel %{y:.2f} km/h")))
    ts, vs = pairs(m.rows, "time_s", "speed_mps")
    if len(ts):
        speeds.append(vs * 3.6)
        data.append(points("FL", ts - t0, vs * 3.6, name="windows (GPS speed)", tip=("t %{x:.2f} s", "V %{y:.1f} km/h"))
                    | {"marker": {"color": "#777777", "symbol": "diamond", "size": 7}, "legendgroup": "windows"})
    finite = [float(np.nanmax(v)) for v in speeds if np.isfinite(v).any()]
    top = max(finite, default=0.0) * 1.05 or 1.0
    b = m.brake
    if b is not None:
        data.append(_mark(b.onset_s - t0, top, f"brake onset ({b.onset_source}) at {b.brake_speed_kmh:.1f} km/h"))
        if b.stop_s is not None:
            dist = "" if b.stopping_distance_m is None else f" after {b.stopping_distance_m:.1f} m"
            data.append(_mark(b.stop_s - t0, top, f"standstill{dist}"))
        if b.mfdd_mps2 is not None:
            v0 = b.brake_speed_kmh
            for k in (0.8, 0.1):
                data.append(line(list(x_range), [k * v0] * 2, name=f"MFDD {b.mfdd_mps2:.2f} m/s² between 0.8·v0 "
                                 "and 0.1·v0", color=MARK, dash="dot", width=1, legendgroup="mfdd",
                                 showlegend=k == 0.8, tip=("t %{x:.2f} s", f"{k}·v0 %{{y:.1f}} km/h")))
    if m.launch_s is not None:
        data.append(_mark(m.launch_s - t0, top, "launch (last standstill)"))
    if m.top_speed_s is not None:
        data.append(_mark(m.top_speed_s - t0, top, "top speed", dash="dot"))
    lay = layout("speed against time", subtitle(log, m), TIME_LABEL, "speed [km/h]", any_data=bool(finite))
    lay["xaxis"]["range"] = x_range
    lay["hovermode"] = "x unified"
    return figure(data, lay)
