"""The report's names and colours, shared by the page (interactive plots) and the PNGs (`--png`); no plotting here."""

from __future__ import annotations

WHEEL_STYLE: dict[str, dict[str, str]] = {
    "FL": {"color": "#1f77b4", "marker": "o", "symbol": "circle"},
    "FR": {"color": "#ff7f0e", "marker": "^", "symbol": "triangle-up"},
    "RL": {"color": "#2ca02c", "marker": "s", "symbol": "square"},
    "RR": {"color": "#d62728", "marker": "v", "symbol": "triangle-down"},
}
"""Per wheel: its colour, matplotlib marker and Plotly symbol, the same in every plot."""

PLOTS: tuple[tuple[str, str], ...] = (
    ("slip-time", "slip against time"),
    ("speed-slip", "speed against slip"),
    ("fx-slip", "tire force Fx against slip"),
    ("re-slip", "effective rolling radius Re against slip"),
    ("cx-slip", "stiffness Cx against slip"),
    ("mu-slip", "friction coefficient μ = Fx/Fz against slip (high-rate)"),
)
"""(stem, title) of the six figures of a maneuver, in report order: the PNGs of `--png`."""

PAGE_PLOTS: tuple[tuple[str, str], ...] = (
    PLOTS[0],
    ("speed-time", "speed against time"),
    *PLOTS[1:],
)
"""(stem, title) of the page's plots of a maneuver: the six and speed against time (its time axis linked to slip's)."""

TIME_PLOTS = ("slip-time", "speed-time")
"""The plots of a maneuver whose time axes move together on the page."""

SLIP_LABEL = "slip s [%]"
TIME_LABEL = "time since log start [s]"
