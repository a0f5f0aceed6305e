"""The day's maneuvers as text for the live view: one line per maneuver (the status stream), and a table, newest
first (the terminal view); a line per test set (its /test_set record)."""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

from rich.table import Table

from slipdaq.maneuver.record import Maneuver
from slipdaq.maneuver.test_set import MAIN_FIGURE

AXLES = (("front", ("FL", "FR")), ("rear", ("RL", "RR")))


def _num(v: float | None, spec: str, scale: float = 1.0) -> str:
    return "—" if v is None else format(v * scale, spec)


def axle_slip_pct(m: Maneuver) -> dict[str, float | None]:
    """Mean slip per axle (%): the mean of its wheels' mean slips (None without)."""
    out: dict[str, float | None] = {}
    for axle, wheels in AXLES:
        vals = [s for w in wheels if w in m.wheels for s in (m.wheels[w].mean_slip,) if s is not None]
        out[axle] = 100.0 * sum(vals) / len(vals) if vals else None
    return out


def figures_text(m: Maneuver) -> str:
    """Braking: brake speed, stopping distance (corrected), MFDD, ABS; accelerating: time to speed; coasting: the road
    loads."""
    if m.kind == "coast":
        return (f"road loads F0 {_num(m.road_load_f0_n, '.1f')} N, F1 {_num(m.road_load_f1_n_per_mps, '+.2f')} N/(m/s), "
                f"F2 {_num(m.road_load_f2_n_per_mps2, '.3f')} N/(m/s)² ({m.coast_runs_paired or 0} runs paired)")
    if m.kind == "brake":
        abs_ = f", ABS {m.abs_cycles} cycles at {m.abs_frequency_hz:.1f} Hz" if m.abs_cycles and m.abs_frequency_hz \
            else ""
        return (f"from {_num(m.brake_speed_kmh, '.1f')} km/h: {_num(m.stopping_distance_m, '.2f')} m "
                f"({_num(m.stopping_distance_corrected_m, '.2f')} m corrected), MFDD {_num(m.mfdd_mps2, '.2f')} m/s²"
                + abs_)
    target = f" to {m.target_speed_kmh:g} km/h" if m.target_speed_kmh is not None else ""
    return f"{_num(m.time_to_speed_s, '.2f')} s{target}"


def verdict(m: Maneuver) -> str:
    return "valid" if m.valid else "INVALID: " + "; ".join(m.invalid_reasons)


def maneuver_line(m: Maneuver) -> str:
    """One line: '#3 brake 80.1→0.4 km/h | from 80.0 km/h: 34.60 m (...), MFDD 7.51 m/s² | slip front -6.2 % ...'."""
    ax = axle_slip_pct(m)
    return (f"maneuver #{m.index} {m.kind} {m.speed_from_kmh:.1f}→{m.speed_to_kmh:.1f} km/h | {figures_text(m)} | "
            f"slip front {_num(ax['front'], '+.1f')} % rear {_num(ax['rear'], '+.1f')} % | {verdict(m)}")


def maneuver_table(ms: Sequence[Maneuver], rows: int = 8) -> Table:
    """The latest maneuvers, newest first."""
    t = Table(title="maneuvers", expand=False)
    for col in ("#", "kind", "km/h", "result", "slip front %", "slip rear %", "valid"):
        t.add_column(col, justify="right" if col in ("#", "slip front %", "slip rear %") else "left")
    for m in list(reversed(ms))[:rows]:
        ax = axle_slip_pct(m)
        t.add_row(str(m.index), m.kind, f"{m.speed_from_kmh:.0f}→{m.speed_to_kmh:.0f}", figures_text(m),
                  _num(ax["front"], "+.1f"), _num(ax["rear"], "+.1f"), verdict(m),
                  style="" if m.valid else "yellow")
    return t


MAIN_UNIT = {"brake": "m", "accelerate": "s", "coast": "N"}


def test_set_line(record: dict[str, Any]) -> str:
    """'brake 100-0: 4 of 5, 36.42 m ± 0.31 (CV 0.9 %)': the runs counted, the main figure's mean ± the half width
    of its 95 % interval and its CV; then the runs excluded, and ok or why not once complete."""
    main = MAIN_FIGURE[record["kind"]]
    text = f"{record['procedure']}: {record['runs_valid']} of {record['runs_required']}"
    mean, hi, cv = record.get(f"{main}_mean"), record.get(f"{main}_ci_hi"), record.get(f"{main}_cv_percent")
    if mean is not None:
        text += f", {mean:.2f} {MAIN_UNIT[record['kind']]}"
        if hi is not None:
            text += f" ± {hi - mean:.2f}"
        if cv is not None:
            text += f" (CV {cv:.1f} %)"
    if record["excluded"]:
        text += f", {len(record['excluded'])} excluded"
    if record["complete"]:
        text += ", ok" if record["ok"] else ", NOT OK: " + "; ".join(record["reasons"])
    return text
