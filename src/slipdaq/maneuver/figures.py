"""One maneuver's figures from its estimate rows and the high-rate rows over its span. Pure: rows in, dataclasses out;
the one definition for the live `/maneuver` record and the report.

Per wheel and maneuver
    mean and largest |slip| of the windows; the linear region and its line (linearity.py) against the latest cruise
    windows known when it closed (detector.ANCHOR_WINDOWS); mean Re: mean of `re_W_m`; r0: the reference radius
    `r0_W_m`; peak Cx: the largest median |`cx_W_n`| (the estimator's windowed Fx/s) over the same 1 % slip bins of at
    least 5 values, with that bin's median slip (a single window's Fx/s at low slip is too noisy to take its maximum);
    fitted Cx and its confidence: the online `cx_fit_W_n` / `cx_fit_W_conf` of the maneuver's row with the highest
    confidence when the rows have them, else Cx_line with confidence max(0, 1 − 2·SE(Cx_line)/|Cx_line|) (1 − the
    relative half width of a ~95 % interval). GPS latency: median `gps_latency_s` of the maneuver's rows when present
    (source: their most common `latency_source`), else the log config's fixed `gps.latency_s` (0 for "auto").

The tire's mu-slip curve (per wheel and maneuver; tire_limit.py), from the high-rate slip (/slip/fast) over the
maneuver's span (`span_s`: its first window's start - SPAN_BEFORE_S to its last window's end, + SPAN_AFTER_S braking):
by the hydraulic split or the joint fit over every wheel at once, whichever explains the total force better; Fz with
the load transfer M*a*h/L (vehicle.wheelbase_m, cg_height_m, front_axle_load_share); mu_peak and slip_at_mu_peak
when the data pass the peak and it is plausible (else none, and mu_flag says why).

Brake-test figures (per brake maneuver; brake_test.py): the onset from the receiver's time mark of the brake-light
switch ([brake] source = "gps-timemark") when one lies in the span, else from the brake signal on CAN ([brake],
nonzero = pressed; between the last released and the first pressed sample) when the log has one, else from the onset
of deceleration; the speed there, the stopping distance to
standstill, corrected to the nominal speed (ISO 21994), the MFDD (ECE R13-H) and the ABS cycles of the high-rate slip.

Start and end: an acceleration from standstill starts at its launch, the last high-rate instant at standstill (fused
speed <= brake_test.STANDSTILL_MPS) before the span's top speed; a stop ends where the speed fell to standstill
(brake_test); speed_from_kmh / speed_to_kmh are the fused speed there (else the windows' speeds).
"""

from __future__ import annotations

import dataclasses
import statistics
from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from slipdaq import WHEELS
from slipdaq.config import TestConfig, TireConfig, VehicleConfig
from slipdaq.maneuver import fallback
from slipdaq.maneuver.brake_noise import brake_intervals
from slipdaq.maneuver.brake_test import STANDSTILL_MPS, BrakeFigures, brake_figures
from slipdaq.maneuver.events import maneuver_title
from slipdaq.maneuver.fast_span import FastSpan
from slipdaq.maneuver.linearity import Linearity, LinearityRule, analyse_linearity, peak_binned
from slipdaq.maneuver.mu_slip import MuSlipFit
from slipdaq.maneuver.test_set import mfdd_window_mps, procedure_for
from slipdaq.maneuver.tire_limit import tire_curves
from slipdaq.records.fast_rows import FastSlipBatch

SPAN_BEFORE_S = 1.5
"""The high-rate rows of a maneuver start this long before its first window (a brake's onset precedes the first
window that the phase classifies as braking)."""
SPAN_AFTER_S = 1.5
"""... and, braking, end this long after its last window (a stop ends below the estimates' minimum speed)."""
BRAKE_SIGNAL_BEFORE_S = 5.0
"""The brake signal's samples are taken from this long before the span (the released sample before the press)."""


@dataclass(frozen=True)
class WheelSummary:
    wheel: str
    slip_samples: int
    mean_slip: float | None
    max_abs_slip: float | None
    linearity: Linearity
    mean_re_m: float | None
    r0_m: float | None
    peak_cx_n: float | None
    peak_cx_slip: float | None
    cx_fit_n: float | None
    cx_fit_conf: float | None
    cx_fit_source: str
    lost_frames: int | None
    mu_slip: MuSlipFit | None = None
    """The tire's mu-slip curve over the maneuver (high-rate slip), or None without enough points."""


@dataclass(frozen=True)
class ManeuverSummary:
    phase: str
    title: str
    key: str
    """Unique in its log: the phase, or the phase and its number ("accelerate-2") when the log has several."""
    rows: tuple[dict[str, Any], ...] = field(repr=False, compare=False)
    t_start_s: float
    """Seconds since the log's first estimate."""
    t_end_s: float
    speed_from_kmh: float
    speed_to_kmh: float
    gps_latency_s: float | None
    gps_latency_source: str
    wheels: dict[str, WheelSummary]
    mu_points: dict[str, tuple[np.ndarray, np.ndarray]] = field(default_factory=dict, repr=False, compare=False)
    """Per wheel: (slip, mu) of the high-rate rows the mu-slip fit used."""
    mu_loads: dict[str, np.ndarray] = field(default_factory=dict, repr=False, compare=False)
    """Per wheel: the normal load Fz (N) of each of those rows."""
    brake: BrakeFigures | None = None
    launch_s: float | None = None
    """Accelerating: the last high-rate instant at standstill before the top speed (None: a rolling start)."""
    top_speed_s: float | None = None
    """Accelerating: the first high-rate instant at the span's top speed."""
    speed_at: tuple[np.ndarray, np.ndarray] = field(default=(np.empty(0), np.empty(0)), repr=False, compare=False)
    """(time_s, fused speed) of the span's high-rate rows (time to a target speed)."""


def _mean(values: Sequence[float]) -> float | None:
    return sum(values) / len(values) if values else None


def summarize_wheel(
    rows: Sequence[dict[str, Any]], wheel: str, rule: LinearityRule, lost_frames: int | None,
    anchors: Sequence[dict[str, Any]] = (),
) -> WheelSummary:
    """anchors: the cruise rows known when it closed (linearity rule step 2)."""
    slips = [r.get(f"slip_{wheel}") for r in rows]
    defined = [s for s in slips if s is not None]
    lin = analyse_linearity(slips, [r.get(f"force_{wheel}_n") for r in rows], rule,
                            [(r.get(f"slip_{wheel}"), r.get(f"force_{wheel}_n")) for r in anchors],
                            [r.get("speed_mps") for r in rows], [r.get("speed_mps") for r in anchors])
    peak_cx = peak_binned(
        [(r[f"slip_{wheel}"], r[f"cx_{wheel}_n"]) for r in rows
         if r.get(f"cx_{wheel}_n") is not None and r.get(f"slip_{wheel}") is not None], rule)
    r0s = [r[f"r0_{wheel}_m"] for r in rows if r.get(f"r0_{wheel}_m") is not None]
    line_cx = lin.line.cx_n if lin.line else None
    line_conf = lin.line.confidence if lin.line else None
    cx_fit, cx_conf, source = fallback.fitted_cx(rows, wheel, line_cx, line_conf)
    return WheelSummary(
        wheel=wheel,
        slip_samples=len(defined),
        mean_slip=_mean(defined),
        max_abs_slip=max((abs(s) for s in defined), default=None),
        linearity=lin,
        mean_re_m=_mean([r[f"re_{wheel}_m"] for r in rows if r.get(f"re_{wheel}_m") is not None]),
        r0_m=statistics.median(r0s) if r0s else None,
        peak_cx_n=peak_cx[0],
        peak_cx_slip=peak_cx[1],
        cx_fit_n=cx_fit,
        cx_fit_conf=cx_conf,
        cx_fit_source=source,
        lost_frames=lost_frames,
    )




def span_s(phase: str, rows: Sequence[dict[str, Any]]) -> tuple[float, float]:
    """(from, to): the time span of a maneuver's high-rate rows (module docstring)."""
    half = 0.5 * float(rows[0].get("window_s") or 0.5)
    return (rows[0]["time_s"] - half - SPAN_BEFORE_S,
            rows[-1]["time_s"] + half + (SPAN_AFTER_S if phase == "brake" else 0.0))


def summarize_maneuver(
    phase: str, rows: Sequence[dict[str, Any]], *, t0_s: float, cfg_latency_s: float | None, rule: LinearityRule,
    anchors: Sequence[dict[str, Any]] = (), fast: FastSlipBatch | Sequence[Any] | FastSpan = (),
    brake: Sequence[tuple[float, float]] = (), vehicle: VehicleConfig | None = None,
    lost_frames: dict[str, int] | None = None, mu_max: float = TireConfig().mu_max, test: TestConfig | None = None,
    marks: Sequence[float] = (),
) -> ManeuverSummary:
    """One event's maneuver. t0_s: the time its times count from; anchors: the cruise rows known when it closed;
    fast: the high-rate rows over its span (`span_s`; /slip/fast dicts, FastSlip records, their batch or their FastSpan); brake:
    (time, value) of the brake signal from BRAKE_SIGNAL_BEFORE_S before the span to its end; mu_max: tire.mu_max
    (tire_limit); test: its procedures (a brake's MFDD over its procedure's window); marks: the times of the brake's
    press by the receiver's time mark, on the host's clock."""
    prow = tuple(rows)
    title, v_from, v_to = maneuver_title(phase, [r["speed_mps"] for r in prow])
    lat = [r["gps_latency_s"] for r in prow if r.get("gps_latency_s") is not None]
    if lat:
        srcs = [r["latency_source"] for r in prow if r.get("latency_source")]
        latency: float | None = float(statistics.median(lat))
        lat_src = f"estimates ({statistics.mode(srcs)})" if srcs else "estimates"
    else:
        latency, lat_src = cfg_latency_s, "config"
    lost = lost_frames or {}
    m = ManeuverSummary(
        phase=phase, title=title, key=phase, rows=prow,
        t_start_s=prow[0]["time_s"] - t0_s, t_end_s=prow[-1]["time_s"] - t0_s,
        speed_from_kmh=v_from, speed_to_kmh=v_to, gps_latency_s=latency, gps_latency_source=lat_src,
        wheels={w: summarize_wheel(prow, w, rule, lost.get(w), anchors) for w in WHEELS},
    )
    return _high_rate(m, FastSpan.of(fast), brake, vehicle or VehicleConfig(), mu_max, test or TestConfig(), marks) \
        if len(fast) >= 3 else m


def _high_rate(m: ManeuverSummary, span: FastSpan, brake: Sequence[tuple[float, float]],
               vehicle: VehicleConfig, mu_max: float, test: TestConfig, marks: Sequence[float] = ()) -> ManeuverSummary:
    """The maneuver with each wheel's mu-slip fit over its high-rate rows and, braking, its brake-test figures;
    accelerating, its launch."""
    t, v, a, slips = span.time_s, span.speed_mps, span.accel_mps2, span.slips
    wheels = dict(m.wheels)
    points: dict[str, tuple[np.ndarray, np.ndarray]] = {}
    loads: dict[str, np.ndarray] = {}
    if m.phase != "cruise":
        curves = tire_curves(v, a, slips, vehicle, 1.0 if m.phase == "accelerate" else -1.0, mu_max, t)
        points, loads = curves.points, curves.loads
        for w in WHEELS:
            wheels[w] = dataclasses.replace(wheels[w], mu_slip=curves.fits[w])
    figures = None
    launch = top = None
    if m.phase == "brake":
        t_from = float(t[0]) - BRAKE_SIGNAL_BEFORE_S
        bt = [x for x, _ in brake if t_from <= x <= t[-1]]
        bv = [y for x, y in brake if t_from <= x <= t[-1]]
        figures = brake_figures(t, v, a, brake_time_s=bt or None, brake_value=bv or None, slip_time_s=t, slips=slips,
                                mark_time_s=list(marks) or None)
        window = mfdd_window_mps(procedure_for(test, "brake", figures.brake_speed_kmh)) if figures else None
        if window is not None:  # the procedure's MFDD window
            figures = brake_figures(t, v, a, brake_time_s=bt or None, brake_value=bv or None, slip_time_s=t,
                                    slips=slips, mfdd_window_mps=window, mark_time_s=list(marks) or None)
        if figures is not None:
            iv = brake_intervals(t, v, a, figures, bt or None, mfdd_window_mps=window)
            sd, md = iv["stopping_distance_m"], iv["mfdd_mps2"]
            figures = dataclasses.replace(figures, stopping_distance_m_lo=sd[0] if sd else None,
                                          stopping_distance_m_hi=sd[1] if sd else None,
                                          mfdd_mps2_lo=md[0] if md else None, mfdd_mps2_hi=md[1] if md else None)
    elif m.phase == "accelerate":
        k_top = int(np.argmax(v))
        top = float(t[k_top])
        still = np.flatnonzero(v[:k_top + 1] <= STANDSTILL_MPS)
        launch = float(t[still[-1]]) if still.size else None
    v_from, v_to = m.speed_from_kmh, m.speed_to_kmh
    if launch is not None:  # from standstill: the speed there, not the first window's mean
        v_from = min(v_from, float(np.interp(launch, t, v)) * 3.6)
    if figures is not None and figures.stop_s is not None:
        v_to = min(v_to, float(np.interp(figures.stop_s, t, v)) * 3.6)
    return dataclasses.replace(m, wheels=wheels, mu_points=points, mu_loads=loads, brake=figures, launch_s=launch,
                               top_speed_s=top, speed_at=(t, v), speed_from_kmh=v_from, speed_to_kmh=v_to)
