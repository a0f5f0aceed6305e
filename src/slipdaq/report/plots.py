"""The report's PNGs (`report --png`, `batch --png`): files of FIG_W_PX x FIG_H_PX pixels, drawn with matplotlib's
Agg canvas (no display). Imported only for them: the page's plots are drawn in the browser (page_*.py).

Per maneuver, six plots with the four wheels in them, each wheel in its colour and marker (WHEEL_STYLE, the same
in every plot): slip against time, speed against slip, tire force Fx against slip (with each wheel's fitted line of
the linear region and the end of linearity marked), effective rolling radius Re against slip (with r0), and
stiffness Cx = Fx/s against slip (with the fitted Cx), and mu = Fx/Fz against the high-rate slip (with the fitted
Burckhardt curve and its peak). Per phase over several logs, Fx against slip with one marker
per label group. Titles name the quantity, the maneuver, the log and its labels.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np
from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.figure import Figure
from matplotlib.lines import Line2D
from matplotlib.typing import LineStyleType

from slipdaq import WHEELS
from slipdaq.maneuver.figures import ManeuverSummary
from slipdaq.report.style import PLOTS, SLIP_LABEL, WHEEL_STYLE
from slipdaq.report.summary import LogSummary

__all__ = ["FIG_H_PX", "FIG_W_PX", "PLOTS", "WHEEL_STYLE", "plot_comparison", "plot_maneuver"]

FIG_W_PX, FIG_H_PX, DPI = 800, 600, 100
GROUP_MARKERS = ("o", "x", "s", "+", "D", "*", "v", "P")
GROUP_LINES: tuple[LineStyleType, ...] = ("--", ":", "-.", (0, (5, 1, 1, 1)))

MU_POINTS_MAX = 2000
"""The μ-slip plot shows at most this many high-rate points per wheel (evenly thinned)."""

GAP_S = 1.0
"""Slip against time is not joined across a gap longer than this (e.g. between two laps' phases)."""


def _figure() -> tuple[Figure, Any]:
    fig = Figure(figsize=(FIG_W_PX / DPI, FIG_H_PX / DPI), dpi=DPI)
    FigureCanvasAgg(fig)
    ax = fig.add_axes((0.11, 0.10, 0.86, 0.76))
    ax.grid(True, color="#dddddd", linewidth=0.8)
    ax.set_axisbelow(True)
    return fig, ax


def _save(fig: Figure, path: Path) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=DPI, format="png")


def _title(fig: Figure, what: str, maneuver: str, log: LogSummary) -> None:
    fig.suptitle(f"{what} — {maneuver}\n{log.title}", fontsize=12, y=0.975)


def _pairs(rows: Sequence[dict[str, Any]], x: str, y: str, scale_x: float = 1.0,
           scale_y: float = 1.0) -> tuple[list[float], list[float]]:
    xs, ys = [], []
    for r in rows:
        a, b = r.get(x), r.get(y)
        if a is not None and b is not None:
            xs.append(a * scale_x)
            ys.append(b * scale_y)
    return xs, ys


def _scatter(ax: Any, w: str, xs: list[float], ys: list[float], label: str | None = None, **kw: Any) -> None:
    st = WHEEL_STYLE[w]
    ax.plot(xs, ys, linestyle="none", marker=st["marker"], color=st["color"], markersize=4.5, alpha=0.75,
            label=label if label is not None else w, **kw)


def _no_data(ax: Any, any_data: bool) -> None:
    if not any_data:
        ax.text(0.5, 0.5, "no defined values in this maneuver", transform=ax.transAxes, ha="center",
                va="center", color="#888888", fontsize=12)


def plot_maneuver(log: LogSummary, m: ManeuverSummary, out_dir: Path) -> dict[str, Path]:
    """The five PNGs of one maneuver in out_dir; returns {plot stem: path}."""
    t0 = log.t0_s or 0.0
    rows = m.rows
    paths: dict[str, Path] = {}
    titles = dict(PLOTS)

    def done(fig, ax, key: str, ylabel: str, any_data: bool, xlabel: str = SLIP_LABEL,
             extra: list[Line2D] | None = None) -> None:
        """Axis labels, legend or 'no data', title; save as DIR/<phase>-<key>.png."""
        ax.set_xlabel(xlabel)
        ax.set_ylabel(ylabel)
        _finish(ax, any_data, extra=extra)
        _title(fig, titles[key], m.title, log)
        paths[key] = out_dir / f"{m.key}-{key}.png"
        _save(fig, paths[key])

    # slip against time
    fig, ax = _figure()
    any_data = False
    for w in WHEELS:
        ts: list[float] = []
        ss: list[float] = []
        for r in rows:
            if r.get(f"slip_{w}") is not None:
                if ts and r["time_s"] - t0 - ts[-1] > GAP_S:  # separate stretches (a later lap): no line across
                    ts.append(math.nan)
                    ss.append(math.nan)
                ts.append(r["time_s"] - t0)
                ss.append(r[f"slip_{w}"] * 100)
        any_data |= bool(ts)
        st = WHEEL_STYLE[w]
        ax.plot(ts, ss, color=st["color"], marker=st["marker"], markersize=3.5, linewidth=1.0, label=w)
    ax.axhline(0.0, color="#888888", linewidth=0.8)
    done(fig, ax, "slip-time", SLIP_LABEL, any_data, xlabel="time since log start [s]")

    # speed against slip
    fig, ax = _figure()
    any_data = False
    for w in WHEELS:
        xs, ys = _pairs(rows, f"slip_{w}", "speed_mps", 100.0, 3.6)
        any_data |= bool(xs)
        _scatter(ax, w, xs, ys)
    done(fig, ax, "speed-slip", "GPS speed V [km/h]", any_data)

    # Fx against slip, with the linear region's line and the end of linearity
    fig, ax = _figure()
    any_data = False
    for w in WHEELS:
        ws = m.wheels[w]
        lin = ws.linearity
        xs, ys = _pairs(rows, f"slip_{w}", f"force_{w}_n", 100.0, 1.0)
        any_data |= bool(xs)
        _scatter(ax, w, xs, ys, label=f"{w}: {lin.verdict}")
        _draw_line_and_end(ax, w, lin, xs)
    ax.axhline(0.0, color="#888888", linewidth=0.8)
    ax.axvline(0.0, color="#888888", linewidth=0.8)
    extra = [Line2D([], [], color="#444444", linestyle="--", label="fitted line Fx = Cx·s (linear region)")]
    if any(m.wheels[w].linearity.end_slip is not None for w in WHEELS):
        extra.append(Line2D([], [], color="#444444", marker="X", markersize=10, linestyle="none",
                            label="end of linearity"))
    extra.append(Line2D([], [], color="#444444", marker="*", markersize=11, linestyle="none",
                        markerfacecolor="none", label="peak linear Fx"))
    done(fig, ax, "fx-slip", "tire force Fx [N]", any_data, extra=extra)

    # Re against slip
    fig, ax = _figure()
    any_data = False
    r0s = set()
    for w in WHEELS:
        xs, ys = _pairs(rows, f"slip_{w}", f"re_{w}_m", 100.0, 1000.0)
        any_data |= bool(xs)
        _scatter(ax, w, xs, ys)
        r0_m = m.wheels[w].r0_m
        if r0_m is not None:
            r0s.add(round(r0_m * 1000.0, 3))
    for r0 in sorted(r0s):
        ax.axhline(r0, color="#555555", linestyle=":", linewidth=1.2, label=f"r0 = {r0:.1f} mm")
    done(fig, ax, "re-slip", "effective rolling radius Re [mm]", any_data)

    # Cx against slip
    fig, ax = _figure()
    any_data = False
    for w in WHEELS:
        ws = m.wheels[w]
        xs, ys = _pairs(rows, f"slip_{w}", f"cx_{w}_n", 100.0, 1e-3)
        any_data |= bool(xs)
        _scatter(ax, w, xs, ys)
        if ws.cx_fit_n is not None and xs:
            conf = f", conf {ws.cx_fit_conf:.2f}" if ws.cx_fit_conf is not None else ""
            ax.axhline(ws.cx_fit_n * 1e-3, color=WHEEL_STYLE[w]["color"], linestyle="--", linewidth=1.2,
                       label=f"{w} fitted Cx {ws.cx_fit_n / 1000:.1f} kN{conf}")
        if ws.linearity.end_slip is not None:
            ax.axvline(ws.linearity.end_slip * 100, color=WHEEL_STYLE[w]["color"], linestyle=":", linewidth=1.2)
    done(fig, ax, "cx-slip", "stiffness Cx = Fx/s [kN per unit slip]", any_data)

    # mu against the high-rate slip, with the fitted curve and its peak
    fig, ax = _figure()
    any_data = False
    for w in WHEELS:
        slip, mu = m.mu_points.get(w, (np.empty(0), np.empty(0)))
        if len(slip) == 0:
            continue
        any_data = True
        step = max(1, len(slip) // MU_POINTS_MAX)
        st = WHEEL_STYLE[w]
        ax.plot(slip[::step] * 100, mu[::step], linestyle="none", marker=st["marker"], markersize=2.5, alpha=0.35,
                color=st["color"])
        fit = m.wheels[w].mu_slip
        label = w
        if fit is not None:
            x = np.linspace(0.0, fit.max_abs_slip, 200) * fit.slip_sign
            ax.plot(x * 100, fit.mu(x), color=st["color"], linewidth=1.6)
            if fit.mu_peak is not None and fit.slip_at_mu_peak is not None:
                ax.plot([fit.slip_sign * fit.slip_at_mu_peak * 100], [fit.slip_sign * fit.mu_peak], marker="*",
                        markersize=14, color=st["color"], markeredgecolor="black", linestyle="none")
                label = f"{w}: μ peak {fit.mu_peak:.2f} at {fit.slip_at_mu_peak * 100:.1f} %"
            else:
                label = f"{w}: peak not reached"
        ax.plot([], [], color=st["color"], marker=st["marker"], label=label)
    ax.axhline(0.0, color="#888888", linewidth=0.8)
    ax.axvline(0.0, color="#888888", linewidth=0.8)
    extra = [Line2D([], [], color="#444444", linewidth=1.6, label="fitted Burckhardt curve")]
    done(fig, ax, "mu-slip", "μ = Fx / Fz", any_data, extra=extra)
    return paths


def _draw_line_and_end(ax: Any, w: str, lin: Any, xs: list[float]) -> None:
    """Fitted line over the slip range of the points (dashed), end of linearity (X), peak linear Fx (star)."""
    if lin.line is None or not xs:
        return
    color = WHEEL_STYLE[w]["color"]
    _line(ax, lin.line, xs, color, "--")
    if lin.end_slip is not None and lin.end_force_n is not None:
        ax.plot([lin.end_slip * 100], [lin.end_force_n], marker="X", markersize=12, color=color,
                markeredgecolor="black", linestyle="none")
        ax.annotate(f"{w} linear to {abs(lin.end_slip) * 100:.1f} %", (lin.end_slip * 100, lin.end_force_n),
                    textcoords="offset points", xytext=(10, -16 - 12 * WHEELS.index(w)), fontsize=9, color=color)
    if lin.peak_fx_n is not None and lin.peak_fx_slip is not None:
        ax.plot([lin.peak_fx_slip * 100], [lin.peak_fx_n], marker="*", markersize=14, markerfacecolor="none",
                markeredgecolor=color, markeredgewidth=1.5, linestyle="none")


def _line(ax: Any, line: Any, xs_pct: list[float], color: str, style: Any) -> None:
    """The fitted line Fx = Cx·(s − s0) (summary.LineFit), over the slip range of the points (slip in %)."""
    lo, hi = min(min(xs_pct), 0.0) * 1.05, max(max(xs_pct), 0.0) * 1.05
    ax.plot([lo, hi], [line.force_n(lo / 100.0), line.force_n(hi / 100.0)], color=color, linestyle=style,
            linewidth=1.4)


def _finish(ax: Any, any_data: bool, extra: list[Line2D] | None = None) -> None:
    _no_data(ax, any_data)
    handles, labels = ax.get_legend_handles_labels()
    if extra and any_data:
        handles += extra
        labels += [h.get_label() for h in extra]
    if handles:
        ax.legend(handles, labels, fontsize=8.5, loc="best", framealpha=0.85)


def plot_comparison(phase: str, logs: Sequence[LogSummary], path: Path) -> Path:
    """Fx against slip of every log's `phase` maneuver: wheel colours, one marker and line style per group."""
    logs = [log for log in logs if any(m.phase == phase for m in log.maneuvers)]
    fig, ax = _figure()
    groups = list(dict.fromkeys(log.group for log in logs))
    any_data = False
    for log in logs:
        gi = groups.index(log.group)
        for m in log.maneuvers:
            if m.phase != phase:
                continue
            for w in WHEELS:
                xs, ys = _pairs(m.rows, f"slip_{w}", f"force_{w}_n", 100.0, 1.0)
                if not xs:
                    continue
                any_data = True
                color = WHEEL_STYLE[w]["color"]
                ax.plot(xs, ys, linestyle="none", marker=GROUP_MARKERS[gi % len(GROUP_MARKERS)], color=color,
                        markersize=4.5, alpha=0.7, markerfacecolor="none" if gi % 2 else color)
                lin = m.wheels[w].linearity
                if lin.line is not None:
                    _line(ax, lin.line, xs, color, GROUP_LINES[gi % len(GROUP_LINES)])
    ax.axhline(0.0, color="#888888", linewidth=0.8)
    ax.axvline(0.0, color="#888888", linewidth=0.8)
    ax.set_xlabel(SLIP_LABEL)
    ax.set_ylabel("tire force Fx [N]")
    handles = [Line2D([], [], color=WHEEL_STYLE[w]["color"], linewidth=3, label=w) for w in WHEELS]
    handles += [Line2D([], [], color="#444444", marker=GROUP_MARKERS[i % len(GROUP_MARKERS)],
                       linestyle=GROUP_LINES[i % len(GROUP_LINES)], markerfacecolor="none" if i % 2 else "#444444",
                       label=f"{g}: points, fitted line") for i, g in enumerate(groups)]
    _no_data(ax, any_data)
    ax.legend(handles=handles, fontsize=8.5, loc="best", framealpha=0.85)
    fig.suptitle(f"tire force Fx against slip — {phase}, {len(logs)} logs by label group\n{' vs '.join(groups)}",
                 fontsize=12, y=0.975)
    _save(fig, path)
    return path
