"""The `/maneuver` record: one per accelerate, brake or coast maneuver as it ends, with its validity against the test day's
targets ([test]). Declared once (MANEUVER_COLUMNS): its JSON, JSON Schema and CSV columns are derived from it.

Validity (`judge`), each failed check a short reason in `invalid_reasons`:
    - speed (only with [test] target_speeds_kmh): a brake maneuver whose brake speed (else its top speed) lies more
      than speed_tolerance_kmh from every target; an acceleration whose top speed stays more than the tolerance below
      the lowest target. target_speed_kmh: the target met (braking: the nearest; accelerating: the highest reached).
    - a GPS gap (estimates on the wheels' clock) or `disturbed` windows (a gap in the wheel or GPS samples) inside it;
    - too short to judge: less than MIN_JUDGE_S long or less than MIN_JUDGE_SPEED_KMH of speed change;
    - braking: no brake onset found, or no stop (the speed never fell to standstill in the span).
time_to_speed_s (accelerating): from the launch (the last instant at standstill; a rolling start: the first window's
start) to the first instant at the target (no target, or a target met only within the tolerance: the top speed), on
the high-rate fused speed (the windows' speed without high-rate rows), linearly interpolated.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np

from slipdaq.config import TestConfig
from slipdaq.maneuver.coast import CoastRun
from slipdaq.maneuver.figures import ManeuverSummary, WheelSummary
from slipdaq.maneuver.test_set import procedure_for, run_speed_kmh
from slipdaq.records.columns import Column, ColumnGroup, record_row

MANEUVER_KINDS = ("accelerate", "brake", "coast")
MIN_JUDGE_S = 1.0
MIN_JUDGE_SPEED_KMH = 5.0


@dataclass(frozen=True, slots=True)
class ManeuverWheel:
    mean_slip: float | None
    max_abs_slip: float | None
    cx_line_n: float | None
    mu_peak: float | None
    slip_at_mu_peak: float | None
    cx_line_n_lo: float | None = None
    cx_line_n_hi: float | None = None
    mu_peak_lo: float | None = None
    mu_peak_hi: float | None = None
    slip_at_mu_peak_lo: float | None = None
    slip_at_mu_peak_hi: float | None = None
    mu_slip_method: str | None = None
    mu_flag: str | None = None


@dataclass(frozen=True, slots=True)
class Maneuver:
    """One maneuver's results, decided when it ended."""

    index: int
    kind: str
    t_start_s: float
    t_end_s: float
    speed_from_kmh: float
    speed_to_kmh: float
    target_speed_kmh: float | None
    valid: bool
    invalid_reasons: tuple[str, ...]
    brake_speed_kmh: float | None
    stopping_distance_m: float | None
    stopping_distance_corrected_m: float | None
    mfdd_mps2: float | None
    abs_cycles: int | None
    abs_frequency_hz: float | None
    time_to_speed_s: float | None
    wheels: dict[str, ManeuverWheel] = field(default_factory=dict)
    stopping_distance_m_lo: float | None = None
    stopping_distance_m_hi: float | None = None
    mfdd_mps2_lo: float | None = None
    mfdd_mps2_hi: float | None = None
    procedure: str | None = None
    road_load_f0_n: float | None = None
    road_load_f0_n_lo: float | None = None
    road_load_f0_n_hi: float | None = None
    road_load_f1_n_per_mps: float | None = None
    road_load_f1_n_per_mps_lo: float | None = None
    road_load_f1_n_per_mps_hi: float | None = None
    road_load_f2_n_per_mps2: float | None = None
    road_load_f2_n_per_mps2_lo: float | None = None
    road_load_f2_n_per_mps2_hi: float | None = None
    coast_runs_paired: int | None = None

    def as_row(self) -> dict[str, object]:
        """Flat mapping in the /maneuver JSON's and the maneuvers CSV's column names (MANEUVER_COLUMNS)."""
        row: dict[str, object] = dict(record_row(self, MANEUVER_COLUMNS))
        row["invalid_reasons"] = list(self.invalid_reasons)
        return row


MANEUVER_COLUMNS: tuple[ColumnGroup, ...] = (
    ColumnGroup((
        Column("index", "index", "integer", description="the maneuver's number in the log: 1, 2, ..."),
        Column("kind", "kind", "enum", MANEUVER_KINDS, "accelerate, brake or coast"),
        Column("t_start_s", "t_start_s", "number", description="its first window, seconds from the log's first "
                                                                 "estimate"),
        Column("t_end_s", "t_end_s", "number", description="its last window, seconds from the log's first estimate"),
        Column("speed_from_kmh", "speed_from_kmh", "number", description="speed at its start (0 from standstill)"),
        Column("speed_to_kmh", "speed_to_kmh", "number", description="speed at its end (0 at a stop)"),
        Column("target_speed_kmh", "target_speed_kmh", "number?",
               description="the [test] target it met; undefined: none met, or no targets"),
        Column("valid", "valid", "bool", description="true when every check passed (invalid_reasons empty)"),
        Column("invalid_reasons", "invalid_reasons", "texts", description="why it is not valid, one short text each"),
        Column("brake_speed_kmh", "brake_speed_kmh", "number?", description="braking: the speed at the brake onset"),
        Column("stopping_distance_m", "stopping_distance_m", "number?",
               description="braking: distance from the onset to standstill"),
        Column("stopping_distance_corrected_m", "stopping_distance_corrected_m", "number?",
               description="braking: the stopping distance corrected to the nominal speed (ISO 21994)"),
        Column("mfdd_mps2", "mfdd_mps2", "number?", description="braking: mean fully developed deceleration "
                                                                 "(ECE R13-H)"),
        Column("abs_cycles", "abs_cycles", "integer?", description="braking: ABS cycles of the wheel that cycled most"),
        Column("abs_frequency_hz", "abs_frequency_hz", "number?", description="braking: their rate"),
        Column("time_to_speed_s", "time_to_speed_s", "number?",
               description="accelerating: from standstill (or its start) to the target (or its top speed)"),
    ), per_wheel=False, csv="contract"),
    ColumnGroup((
        Column("mean_slip_{w}", "mean_slip", "number?", description="mean slip of the {w} wheel's windows"),
        Column("max_abs_slip_{w}", "max_abs_slip", "number?", description="largest |slip| of the {w} wheel's windows"),
        Column("cx_line_n_{w}", "cx_line_n", "number?",
               description="the {w} tire's force-slip line slope (N per unit slip) over its linear region"),
        Column("mu_peak_{w}", "mu_peak", "number?", description="peak friction coefficient of the {w} tire's "
                                                                "mu-slip curve; undefined: the points never passed it"),
        Column("slip_at_mu_peak_{w}", "slip_at_mu_peak", "number?", description="slip at the {w} tire's mu peak"),
    ), per_wheel=True, csv="contract"),
    ColumnGroup((
        Column("stopping_distance_m_lo", "stopping_distance_m_lo", "number?",
               description="braking: the stopping distance's 95 % interval from its inputs' noise, low end"),
        Column("stopping_distance_m_hi", "stopping_distance_m_hi", "number?", description="... high end"),
        Column("mfdd_mps2_lo", "mfdd_mps2_lo", "number?", description="braking: the MFDD's 95 % interval, low end"),
        Column("mfdd_mps2_hi", "mfdd_mps2_hi", "number?", description="... high end"),
    ), per_wheel=False, csv="contract"),
    ColumnGroup((
        Column("cx_line_n_lo_{w}", "cx_line_n_lo", "number?", description="95 % interval of cx_line_n_{w}, low end"),
        Column("cx_line_n_hi_{w}", "cx_line_n_hi", "number?", description="... high end"),
        Column("mu_peak_lo_{w}", "mu_peak_lo", "number?", description="95 % interval of mu_peak_{w}, low end"),
        Column("mu_peak_hi_{w}", "mu_peak_hi", "number?", description="... high end"),
        Column("slip_at_mu_peak_lo_{w}", "slip_at_mu_peak_lo", "number?",
               description="95 % interval of slip_at_mu_peak_{w}, low end"),
        Column("slip_at_mu_peak_hi_{w}", "slip_at_mu_peak_hi", "number?", description="... high end"),
        Column("mu_slip_method_{w}", "mu_slip_method", "text?", description="how the {w} tire's force was had: "
               "hydraulic split, joint shared, joint per axle (the curve fitted to the total force over every wheel)"),
        Column("mu_flag_{w}", "mu_flag", "text?", description="why the {w} tire has no mu peak although it has a curve: "
               "peak not passed, mu above MU_MAX, split exceeds the load, not determined; undefined: none"),
    ), per_wheel=True, csv="contract"),
    ColumnGroup((
        Column("procedure", "procedure", "text?", description="the [[test.procedure]] it belongs to (its kind, the "
               "nearest target speed); undefined: none of its kind"),
        Column("road_load_f0_n", "road_load_f0_n", "number?",
               description="coast: the road loads' F0 in F(v) = F0 + F1*v + F2*v^2 (the paired runs' mean)"),
        Column("road_load_f0_n_lo", "road_load_f0_n_lo", "number?", description="95 % interval of F0, low end"),
        Column("road_load_f0_n_hi", "road_load_f0_n_hi", "number?", description="... high end"),
        Column("road_load_f1_n_per_mps", "road_load_f1_n_per_mps", "number?", description="coast: F1"),
        Column("road_load_f1_n_per_mps_lo", "road_load_f1_n_per_mps_lo", "number?",
               description="95 % interval of F1, low end"),
        Column("road_load_f1_n_per_mps_hi", "road_load_f1_n_per_mps_hi", "number?", description="... high end"),
        Column("road_load_f2_n_per_mps2", "road_load_f2_n_per_mps2", "number?", description="coast: F2"),
        Column("road_load_f2_n_per_mps2_lo", "road_load_f2_n_per_mps2_lo", "number?",
               description="95 % interval of F2, low end"),
        Column("road_load_f2_n_per_mps2_hi", "road_load_f2_n_per_mps2_hi", "number?", description="... high end"),
        Column("coast_runs_paired", "coast_runs_paired", "integer?",
               description="coast: the runs the road loads average, in pairs of opposite GPS courses (wind and grade "
                           "cancel); 0: this run's own fit"),
    ), per_wheel=False, csv="contract"),
)
"""The /maneuver record's fields, in the order of its JSON and of `export --maneuvers-csv`."""


def _fmt(v: float) -> str:
    return f"{v:.0f}" if v == round(v) else f"{v:.1f}"


def _time_to_speed(m: ManeuverSummary, target_kmh: float | None) -> float | None:
    t, v = m.speed_at
    if len(t) < 2:
        t = np.array([r["time_s"] for r in m.rows], dtype=np.float64)
        v = np.array([r["speed_mps"] for r in m.rows], dtype=np.float64)
    if len(t) < 2:
        return None
    top = int(np.argmax(v))
    start = m.launch_s if m.launch_s is not None else m.rows[0]["time_s"] - 0.5 * float(m.rows[0].get("window_s") or 0.5)
    level = float(v[top]) if target_kmh is None else min(float(v[top]), target_kmh / 3.6)
    k = int(np.flatnonzero(v[: top + 1] >= level)[0])
    t_at = float(t[k]) if k == 0 or v[k] == v[k - 1] else \
        float(t[k - 1] + (level - v[k - 1]) / (v[k] - v[k - 1]) * (t[k] - t[k - 1]))
    return t_at - start if t_at >= start else None


def judge(m: ManeuverSummary, test: TestConfig) -> tuple[float | None, list[str], float | None]:
    """(target met, reasons it is invalid, time to speed) of an accelerate or brake maneuver (module docstring)."""
    reasons: list[str] = []
    targets = sorted(test.target_speeds_kmh)
    tol = test.speed_tolerance_kmh
    target: float | None = None
    b = m.brake
    if m.phase == "brake":
        speed = b.brake_speed_kmh if b is not None else m.speed_from_kmh
        if targets:
            near = min(targets, key=lambda x: abs(x - speed))
            if abs(near - speed) <= tol:
                target = near
            else:
                reasons.append(f"brake speed {speed:.1f} km/h not within {_fmt(tol)} km/h of a target "
                               f"({', '.join(_fmt(x) for x in targets)} km/h)")
        if b is None:
            reasons.append("no brake onset found")
        elif b.stop_s is None:
            reasons.append(f"no stop (speed still {m.speed_to_kmh:.1f} km/h)")
    else:
        reached = [x for x in targets if m.speed_to_kmh >= x - tol]
        if reached:
            target = reached[-1]
        elif targets:
            reasons.append(f"reached {m.speed_to_kmh:.1f} km/h, below the lowest target {_fmt(targets[0])} km/h")
    lost = sum(1 for r in m.rows if r.get("source") == "wheels")
    disturbed = sum(1 for r in m.rows if r.get("quality") == "disturbed" and r.get("source") != "wheels")
    if lost:
        reasons.append(f"GPS lost in {lost} windows")
    if disturbed:
        reasons.append(f"{disturbed} disturbed windows (a gap in the wheel or GPS samples)")
    duration = m.t_end_s - m.t_start_s
    change = abs(m.speed_to_kmh - m.speed_from_kmh)
    if duration < MIN_JUDGE_S or change < MIN_JUDGE_SPEED_KMH:
        reasons.append(f"too short to judge ({duration:.1f} s, {change:.0f} km/h)")
    tts = _time_to_speed(m, target) if m.phase == "accelerate" else None
    return target, reasons, tts


def determined(value: float | None, lo: float | None, hi: float | None) -> float | None:
    """The value, or None when its 95 % interval is wider than the value itself (not determined)."""
    if value is None or lo is None or hi is None:
        return value
    return None if hi - lo > abs(value) else value


Z95 = 1.959963984540054
"""The normal distribution's 97.5 % quantile: a ~95 % interval is value +- Z95 standard errors."""


def _wheel(ws: WheelSummary) -> ManeuverWheel:
    line, mu = ws.linearity.line, ws.mu_slip
    lo = hi = None
    if line is not None:
        lo, hi = line.cx_n - Z95 * line.stderr_n, line.cx_n + Z95 * line.stderr_n
    return ManeuverWheel(
        mean_slip=ws.mean_slip, max_abs_slip=ws.max_abs_slip,
        cx_line_n=determined(line.cx_n if line else None, lo, hi), cx_line_n_lo=lo, cx_line_n_hi=hi,
        mu_peak=mu.mu_peak if mu else None, slip_at_mu_peak=mu.slip_at_mu_peak if mu else None,
        mu_peak_lo=mu.mu_peak_lo if mu else None, mu_peak_hi=mu.mu_peak_hi if mu else None,
        slip_at_mu_peak_lo=mu.slip_at_mu_peak_lo if mu else None,
        slip_at_mu_peak_hi=mu.slip_at_mu_peak_hi if mu else None,
        mu_slip_method=mu.method if mu else None, mu_flag=mu.flag if mu else None,
    )


def coast_record(run: CoastRun, index: int, t0_s: float, wheels: Sequence[str],
                 test: TestConfig | None = None) -> Maneuver:
    """The /maneuver record of a coast (maneuver/coast.py): its span and the road loads; invalid while no run in the
    opposite direction pairs with it; its procedure: the coast procedure nearest its start speed (test_set)."""
    proc = procedure_for(test, "coast", run.speed_from_kmh) if test is not None else None
    none = ManeuverWheel(None, None, None, None, None)
    f0, f1, f2 = run.loads
    lo, hi = run.loads_lo, run.loads_hi
    return Maneuver(
        index=index, kind="coast", t_start_s=run.t_start_s - t0_s, t_end_s=run.t_end_s - t0_s,
        speed_from_kmh=run.speed_from_kmh, speed_to_kmh=run.speed_to_kmh, target_speed_kmh=None,
        valid=not run.reasons, invalid_reasons=run.reasons, brake_speed_kmh=None, stopping_distance_m=None,
        stopping_distance_corrected_m=None, mfdd_mps2=None, abs_cycles=None, abs_frequency_hz=None,
        time_to_speed_s=None, wheels=dict.fromkeys(wheels, none),
        road_load_f0_n=f0, road_load_f0_n_lo=lo[0], road_load_f0_n_hi=hi[0],
        road_load_f1_n_per_mps=f1, road_load_f1_n_per_mps_lo=lo[1], road_load_f1_n_per_mps_hi=hi[1],
        road_load_f2_n_per_mps2=f2, road_load_f2_n_per_mps2_lo=lo[2], road_load_f2_n_per_mps2_hi=hi[2],
        coast_runs_paired=run.runs_paired, procedure=proc.name if proc is not None else None,
    )


def maneuver_record(m: ManeuverSummary, index: int, test: TestConfig, wheels: Sequence[str]) -> Maneuver:
    """The /maneuver record of an accelerate or brake maneuver (a figure whose interval is wider than itself: not
    determined, None). With a procedure of its kind (test_set.procedure_for): the stopping distance corrected to the
    procedure's target speed, d·(v_target/v0)² (ISO 21994), and the time to its target speed."""
    target, reasons, tts = judge(m, test)
    b = m.brake
    proc = procedure_for(test, m.phase, run_speed_kmh(m.phase, b.brake_speed_kmh if b else None, m.speed_from_kmh,
                                                      m.speed_to_kmh))
    corrected = b.stopping_distance_corrected_m if b else None
    if proc is not None and b is not None and b.stopping_distance_m is not None:
        corrected = b.stopping_distance_m * (proc.target_speed_kmh / b.brake_speed_kmh) ** 2
    if proc is not None and m.phase == "accelerate":
        tts = _time_to_speed(m, proc.target_speed_kmh)
    return Maneuver(
        index=index, kind=m.phase, t_start_s=m.t_start_s, t_end_s=m.t_end_s,
        speed_from_kmh=m.speed_from_kmh, speed_to_kmh=m.speed_to_kmh, target_speed_kmh=target,
        valid=not reasons, invalid_reasons=tuple(reasons),
        brake_speed_kmh=b.brake_speed_kmh if b else None,
        stopping_distance_m=determined(b.stopping_distance_m, b.stopping_distance_m_lo, b.stopping_distance_m_hi)
        if b else None,
        stopping_distance_corrected_m=corrected,
        mfdd_mps2=determined(b.mfdd_mps2, b.mfdd_mps2_lo, b.mfdd_mps2_hi) if b else None,
        abs_cycles=b.abs_cycles if b else None, abs_frequency_hz=b.abs_frequency_hz if b else None,
        time_to_speed_s=tts, wheels={w: _wheel(m.wheels[w]) for w in wheels},
        stopping_distance_m_lo=b.stopping_distance_m_lo if b else None,
        stopping_distance_m_hi=b.stopping_distance_m_hi if b else None,
        mfdd_mps2_lo=b.mfdd_mps2_lo if b else None, mfdd_mps2_hi=b.mfdd_mps2_hi if b else None,
        procedure=proc.name if proc is not None else None,
    )
