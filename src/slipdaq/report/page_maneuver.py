"""The page's plots of one maneuver from its estimate rows and its span's high-rate rows (Plotly JSON, traces.py):
slip against time (every high-rate point of the span, and the windows), speed, Fx (with the fitted line, the end of
linearity and the peak linear force), Re (with r0) and Cx (with the fitted Cx) against slip. μ–slip and speed against
time (with the brake-test and launch marks) are page_mu_brake.py's."""

from __future__ import annotations

import numpy as np

from slipdaq import WHEELS
from slipdaq.maneuver.figures import ManeuverSummary
from slipdaq.report.style import SLIP_LABEL, TIME_LABEL, WHEEL_STYLE
from slipdaq.report.summary import LogSummary
from slipdaq.report.traces import Figure, HighRate, figure, layout, line, pairs, points

SLIP_TIP = "slip %{x:.2f} %"


def subtitle(log: LogSummary, m: ManeuverSummary) -> str:
    return f"{m.title} — {log.title}"


def slip_time(log: LogSummary, m: ManeuverSummary, hr: HighRate, x_range: list[float]) -> Figure:
    """Per wheel its high-rate slip (a line through every point of the span) and the windows' slip (markers)."""
    t0 = log.t0_s or 0.0
    data = []
    any_data = False
    for w in WHEELS:
        color = WHEEL_STYLE[w]["color"]
        s = hr.slips[w]
        if np.isfinite(s).any():
            any_data = True
            data.append(line(hr.time_s - t0, s * 100.0, name=f"{w} high-rate", color=color, width=1.2, yd=3,
                             tip=("t %{x:.3f} s", "slip %{y:.2f} %"), legendgroup=w))
        ts, ss = pairs(m.rows, "time_s", f"slip_{w}")
        if len(ts):
            any_data = True
            data.append(points(w, ts - t0, ss * 100.0, name=f"{w} windows", tip=("t %{x:.2f} s", "slip %{y:.2f} %"),
                               size=7, opacity=0.95))
    lay = layout("slip against time", subtitle(log, m), TIME_LABEL, SLIP_LABEL, any_data=any_data)
    lay["xaxis"]["range"] = x_range
    lay["hovermode"] = "x unified"
    return figure(data, lay)


def speed_slip(log: LogSummary, m: ManeuverSummary) -> Figure:
    data = []
    for w in WHEELS:
        xs, ys = pairs(m.rows, f"slip_{w}", "speed_mps")
        if len(xs):
            data.append(points(w, xs * 100.0, ys * 3.6, tip=(SLIP_TIP, "V %{y:.1f} km/h")))
    return figure(data, layout("speed against slip", subtitle(log, m), SLIP_LABEL, "GPS speed V [km/h]",
                               any_data=bool(data)))


def _slip_extent(xs_pct: np.ndarray) -> tuple[float, float]:
    return min(float(xs_pct.min()), 0.0) * 1.05, max(float(xs_pct.max()), 0.0) * 1.05


def fx_slip(log: LogSummary, m: ManeuverSummary) -> Figure:
    """Points, each wheel's fitted line of the linear region (dashed), its end of linearity (✖) and peak linear Fx
    (☆)."""
    data = []
    for w in WHEELS:
        lin = m.wheels[w].linearity
        xs, ys = pairs(m.rows, f"slip_{w}", f"force_{w}_n")
        if not len(xs):
            continue
        color = WHEEL_STYLE[w]["color"]
        data.append(points(w, xs * 100.0, ys, name=f"{w}: {lin.verdict}", yd=1, tip=(SLIP_TIP, "Fx %{y:.0f} N")))
        if lin.line is not None:
            lo, hi = _slip_extent(xs * 100.0)
            fit = lin.line
            data.append(line([lo, hi], [fit.force_n(lo / 100.0), fit.force_n(hi / 100.0)], color=color, dash="dash",
                             name=f"{w} line, Cx {fit.cx_n / 1000:.1f} kN", yd=1, legendgroup=w,
                             tip=(SLIP_TIP, "Fx %{y:.0f} N on the line")))
        if lin.end_slip is not None and lin.end_force_n is not None:
            data.append(points(w, [lin.end_slip * 100.0], [lin.end_force_n], yd=1, size=14, opacity=1.0,
                               name=f"{w} end of linearity {abs(lin.end_slip) * 100:.1f} %",
                               tip=(SLIP_TIP, "Fx %{y:.0f} N"))
                        | {"marker": {"color": color, "symbol": "x", "size": 14, "line": {"color": "black",
                                                                                          "width": 1}}})
        if lin.peak_fx_n is not None and lin.peak_fx_slip is not None:
            data.append(points(w, [lin.peak_fx_slip * 100.0], [lin.peak_fx_n], yd=1, size=16, opacity=1.0,
                               name=f"{w} peak linear Fx {lin.peak_fx_n:.0f} N", tip=(SLIP_TIP, "Fx %{y:.0f} N"))
                        | {"marker": {"color": color, "symbol": "star-open", "size": 16, "line": {"width": 2}}})
    return figure(data, layout("tire force Fx against slip", subtitle(log, m), SLIP_LABEL, "tire force Fx [N]",
                               any_data=bool(data)))


def re_slip(log: LogSummary, m: ManeuverSummary) -> Figure:
    """Points and each wheel's r0 (dotted)."""
    data = []
    extent: list[float] = []
    for w in WHEELS:
        xs, ys = pairs(m.rows, f"slip_{w}", f"re_{w}_m")
        if len(xs):
            data.append(points(w, xs * 100.0, ys * 1000.0, tip=(SLIP_TIP, "Re %{y:.2f} mm")))
            extent += _slip_extent(xs * 100.0)
    for w in WHEELS:
        r0 = m.wheels[w].r0_m
        if r0 is not None and extent:
            data.append(line([min(extent), max(extent)], [r0 * 1000.0] * 2, name=f"{w} r0 {r0 * 1000:.1f} mm",
                             color=WHEEL_STYLE[w]["color"], dash="dot", legendgroup=w, tip=(SLIP_TIP, "r0 %{y:.2f} mm")))
    return figure(data, layout("effective rolling radius Re against slip", subtitle(log, m), SLIP_LABEL,
                               "effective rolling radius Re [mm]", any_data=bool(extent)))


def cx_slip(log: LogSummary, m: ManeuverSummary) -> Figure:
    """Points (the estimator's windowed Fx/s), each wheel's fitted Cx (dashed) and end of linearity (dotted)."""
    data = []
    for w in WHEELS:
        ws = m.wheels[w]
        color = WHEEL_STYLE[w]["color"]
        xs, ys = pairs(m.rows, f"slip_{w}", f"cx_{w}_n")
        if not len(xs):
            continue
        data.append(points(w, xs * 100.0, ys * 1e-3, tip=(SLIP_TIP, "Cx %{y:.1f} kN")))
        lo, hi = _slip_extent(xs * 100.0)
        if ws.cx_fit_n is not None:
            conf = f", conf {ws.cx_fit_conf:.2f}" if ws.cx_fit_conf is not None else ""
            data.append(line([lo, hi], [ws.cx_fit_n * 1e-3] * 2, color=color, dash="dash", legendgroup=w,
                             name=f"{w} fitted Cx {ws.cx_fit_n / 1000:.1f} kN{conf}", tip=(SLIP_TIP, "Cx %{y:.1f} kN")))
        if ws.linearity.end_slip is not None:
            y = ys * 1e-3
            data.append(line([ws.linearity.end_slip * 100.0] * 2, [float(y.min()), float(y.max())], color=color,
                             dash="dot", legendgroup=w, name=f"{w} end of linearity",
                             tip=(SLIP_TIP, "Cx %{y:.1f} kN")))
    return figure(data, layout("stiffness Cx against slip", subtitle(log, m), SLIP_LABEL,
                               "stiffness Cx = Fx/s [kN per unit slip]", any_data=bool(data)))
