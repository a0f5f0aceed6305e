"""The report's numbers: estimate rows of a log in, dataclasses out. Pure (no I/O, no plotting).

Maneuvers
    Each estimate row has a phase: its own `phase` field when the log has one, else `fallback.derive_phases`
    (speed < 0.5 m/s standstill, |a| < 0.3 m/s² cruise, else accelerate or brake). A run of fewer than 3
    consecutive rows of one phase between two runs of one other phase (noise on a) takes that phase. A maneuver is
    one event: a run of rows of one phase; two runs of accelerate (or brake) with nothing but cruise between them,
    for less than MERGE_GAP_S (a gear change, an ABS cycle), are one event. Standstill, and events of fewer than 5
    rows or without any defined slip, make none. Its title gives the speed range in km/h rounded to 5 (e.g.
    "accelerate 0–60 km/h"), numbered "#1", "#2", ... in time order when a log has several of one phase; its `key`
    (the phase, or "accelerate-2", ...) names its plots.

Linear region and the end of linearity (per wheel and maneuver), the exact rule
    1. Points: rows with slip s and tire force Fx (`force_W_n`) both defined, |s| >= S_MIN and Fx·s > 0
       (force and slip of the same sign; a wheel carrying no force has no points).
       S_MIN, S_MAX are the log's `estimator.cx_slip_min`, `cx_slip_max` (defaults 0.005, 0.10).
    2. Line: slip on force, s = s0 + Fx/Cx_line, least squares over the maneuver's windows whose force has the
       maneuver's sign (any slip) and the log's cruise windows (which anchor Fx = 0; a log without: step 2's
       fallback), both with |s| <= S_MAX. The
       slip is the noisy one (GPS), so it is the regressand: its noise adds spread, not bias; Fx = M·a spreads
       widely between cruise and the maneuver and its own noise is small against that spread (docs/method.md,
       fitted stiffness). With 10 cruise windows or more, their spread is each variable's noise and the fit is
       errors-in-variables (Deming, fit_slip_on_force): noise in Fx no longer flattens the slope. s0 takes a radius
       error out. Without force spread (fewer than 3 points, or a slope not
       3 standard errors above 0: one cluster of points):
       Fx = Cx_line·s through the origin over the sign-consistent points (the secant; `cx_line_method` says which).
       With neither, no line and no linearity result.
    3. Bins: the points are binned by |s| in steps of 1 % slip ([0, 1 %), [1 %, 2 %), ...); bins of fewer than
       5 points are skipped. A bin is below the line when its median |Fx| < (1 − 0.10)·Cx_line·(its median |s|).
    4. Linearity ends at the first bin (by increasing |s|) that is below the line and after which every kept bin
       is below the line too, counting at least 2 kept bins below the line from it on (one lone bin is not enough:
       noise in s puts a few points of a force plateau in the next bin up); the end point is that bin's
       (median s, median Fx), signed like the maneuver.
       If the bin starts at or below S_MAX, the line is refitted on the points with |s| below the bin's lower
       edge and steps 2–4 repeat, at most 5 times (nonlinear points must not bend the line); with fewer than 3
       points below the edge the line stays as it is.
       No such bin: "linear throughout" (no end point is invented).
    5. Peak linear force: the point of largest |Fx| below the end bin's lower edge (all points when linear
       throughout), with the slip there.

Other figures per wheel and maneuver
    mean Re: mean of `re_W_m`; r0: the reference radius `r0_W_m`; peak Cx: the largest median |`cx_W_n`| (the
    estimator's windowed Fx/s) over the same 1 % slip bins of at least 5 values, with that bin's median slip
    (a single window's Fx/s at low slip is too noisy to take its maximum); fitted Cx and its confidence:
    the online `cx_fit_W_n` / `cx_fit_W_conf` of the
    maneuver's row with the highest confidence when the rows have them, else Cx_line with confidence
    max(0, 1 − 2·SE(Cx_line)/|Cx_line|) (1 − the relative half width
    of a ~95 % interval). GPS latency: median `gps_latency_s` of the maneuver's rows when present (source: their most
    common `latency_source`), else the log config's fixed `gps.latency_s` (0 for "auto").
    Lost frames (per wheel) and bad sentences: the last `/diagnostics`.

The tire's mu-slip curve (per wheel and maneuver; mu_slip.py), from the high-rate slip (/slip/fast) over the
maneuver's span (its first window's start - SPAN_BEFORE_S to its last window's end + SPAN_AFTER_S):
    mu = Fx_tire / Fz_tire, Fx_tire = M*a split as the estimator splits it (driven wheels; brake_front_share), a the
    fused acceleration of the high-rate rows from MU_MIN_SPEED_MPS on; Fz with the load transfer M*a*h/L
    (vehicle.wheelbase_m, cg_height_m, front_axle_load_share); a Burckhardt curve fitted over the whole slip range:
    mu_peak and slip_at_mu_peak when the data pass the peak (else none: a peak cannot be read off the linear region).

Brake-test figures (per brake maneuver; brake_test.py): the onset from the brake signal on CAN ([brake], nonzero =
pressed) when the log has one, else from the onset of deceleration; the speed there, the stopping distance to
standstill, corrected to the nominal speed (ISO 21994), the MFDD (ECE R13-H) and the ABS cycles of the high-rate slip.
"""

from __future__ import annotations

import dataclasses
import math
import statistics
from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from slipdaq import WHEELS
from slipdaq.config import Config, ConfigError, EstimatorConfig, VehicleConfig, parse_config
from slipdaq.estimator.force import tire_forces
from slipdaq.report import fallback
from slipdaq.report.brake_test import BrakeFigures, brake_figures
from slipdaq.report.labels import format_labels
from slipdaq.report.mu_slip import MuSlipFit, fit_mu_slip, mu_from_force, normal_loads_n

PHASES: tuple[str, ...] = ("accelerate", "cruise", "brake")
"""Phases that make a maneuver, in report order (standstill has no slip)."""
MIN_RUN_ROWS = 3
"""A run of fewer consecutive rows of one phase between two runs of another phase (noise on a) takes that phase."""
MIN_MANEUVER_ROWS = 5
"""An event with fewer rows (after debouncing) makes no maneuver."""
MERGE_GAP_S = 2.0
"""Two runs of one phase with only cruise between them, for less than this, are one event."""
SPAN_BEFORE_S = 1.5
"""The high-rate rows of a maneuver start this long before its first window (a brake's onset precedes the first
window that the phase classifies as braking)."""
SPAN_AFTER_S = 3.0
"""... and end this long after its last window (a stop ends below the estimates' minimum speed)."""
MU_MIN_SPEED_MPS = 3.0
"""The mu-slip fit takes high-rate rows from this speed on: below it a count's quantisation is a large slip, and
ABS hands over to locked wheels (2 m/s) before the stop."""


def events(phases: Sequence[str | None], times_s: Sequence[float]) -> list[tuple[str | None, list[int]]]:
    """The rows (indices) of each event in time order: runs of one phase, two runs of a phase with only a short
    cruise between them joined (the cruise rows between belong to neither)."""
    runs: list[tuple[str | None, list[int]]] = []
    for i, p in enumerate(phases):
        if runs and runs[-1][0] == p:
            runs[-1][1].append(i)
        else:
            runs.append((p, [i]))
    out: list[tuple[str | None, list[int]]] = []
    for p, rows in runs:
        if p in ("accelerate", "brake") and len(out) >= 2 and out[-2][0] == p and out[-1][0] == "cruise" \
                and times_s[rows[0]] - times_s[out[-2][1][-1]] < MERGE_GAP_S:
            out.pop()
            out[-1][1].extend(rows)
            continue
        out.append((p, list(rows)))
    return out


def debounce(phases: Sequence[str | None], min_run: int = MIN_RUN_ROWS) -> list[str | None]:
    """A run of fewer than min_run rows between two runs of one same phase takes that phase (a spike of noise)."""
    runs: list[list[Any]] = []  # [phase, length]
    for p in phases:
        if runs and runs[-1][0] == p:
            runs[-1][1] += 1
        else:
            runs.append([p, 1])
    for i in range(1, len(runs) - 1):
        if runs[i][1] < min_run and runs[i - 1][0] == runs[i + 1][0] and runs[i - 1][0] is not None:
            runs[i][0] = runs[i - 1][0]
    return [p for p, n in runs for _ in range(n)]


_ESTIMATOR_DEFAULTS = EstimatorConfig()


@dataclass(frozen=True)
class LinearityRule:
    slip_min: float = _ESTIMATOR_DEFAULTS.cx_slip_min
    slip_max: float = _ESTIMATOR_DEFAULTS.cx_slip_max
    tolerance: float = 0.10
    """A bin is below the line when its median force is more than this fraction below it."""
    bin_width: float = 0.01
    min_bin_points: int = 5
    min_fit_points: int = 3
    max_refits: int = 5
    min_end_bins: int = 2
    """The force must stay below the line over at least this many kept bins (a lone bin is slip noise)."""


@dataclass(frozen=True)
class LineFit:
    cx_n: float
    stderr_n: float
    points: int
    slip_offset: float = 0.0
    """s0: the line is Fx = Cx·(s − s0)."""
    method: str = "through origin"
    """'slip on force' or 'through origin' (rule step 2)."""

    def force_n(self, slip: float) -> float:
        return self.cx_n * (slip - self.slip_offset)

    @property
    def confidence(self) -> float:
        """max(0, 1 − 2·SE/|Cx|)."""
        return max(0.0, 1.0 - 2.0 * self.stderr_n / abs(self.cx_n)) if self.cx_n else 0.0


@dataclass(frozen=True)
class Linearity:
    points: int
    """Sign-consistent points with |s| >= slip_min."""
    line: LineFit | None
    end_slip: float | None = None
    """Median slip of the first bin below the line; None: linear throughout (or no line)."""
    end_force_n: float | None = None
    peak_fx_n: float | None = None
    """Fx of largest |Fx| in the linear region (signed)."""
    peak_fx_slip: float | None = None

    @property
    def verdict(self) -> str:
        if self.line is None:
            return "no force–slip points" if self.points == 0 else "too few points"
        if self.end_slip is None:
            return "linear throughout"
        return f"ends at {abs(self.end_slip) * 100:.1f} % slip"


def fit_through_origin(points: Sequence[tuple[float, float]]) -> LineFit | None:
    """Least squares Fx = Cx·s through the origin; None for fewer than 2 points."""
    if len(points) < 2:
        return None
    sss = sum(s * s for s, _ in points)
    if sss <= 0:
        return None
    cx = sum(s * f for s, f in points) / sss
    resid = sum((f - cx * s) ** 2 for s, f in points)
    stderr = math.sqrt(resid / (len(points) - 1) / sss)
    return LineFit(cx, stderr, len(points))


MIN_SLOPE_T = 3.0
"""The slip-on-force slope must be this many standard errors above 0."""


def fit_slip_on_force(points: Sequence[tuple[float, float]], noise: tuple[float, float] | None = None,
                      weights: Sequence[float] | None = None) -> LineFit | None:
    """s = s0 + Fx/Cx, slip the regressand; None for fewer than 3 points or no positive slope.

    weights: per point (default 1): the slip's noise variance is var_s/w (a GPS speed noise in m/s makes a slip noise
    in proportion to 1/V, so w ~ V^2). noise: (var_s, var_F), the variances of the slip's (at weight 1) and the
    force's own noise: a Deming (errors-in-variables) fit with their ratio lambda = var_s/var_F, which noise in Fx
    does not flatten (least squares of s on Fx shrinks the slope by var(Fx true)/var(Fx), and so raises Cx):
        b = (Sss - lambda Sff + sqrt((Sss - lambda Sff)^2 + 4 lambda Sfs^2)) / (2 Sfs)
    (Sff, Sss, Sfs: weighted sums of squares and products about the weighted means). Without noise: weighted least
    squares of s on Fx."""
    n = len(points)
    if n < 3:
        return None
    w = [1.0] * n if weights is None else list(weights)
    sw = sum(w)
    f_mean = sum(wi * f for wi, (_, f) in zip(w, points)) / sw
    s_mean = sum(wi * s for wi, (s, _) in zip(w, points)) / sw
    sff = sum(wi * (f - f_mean) ** 2 for wi, (_, f) in zip(w, points))
    if sff <= 0:
        return None
    sfs = sum(wi * (f - f_mean) * (s - s_mean) for wi, (s, f) in zip(w, points))
    b = sfs / sff
    method = "slip on force"
    if noise is not None and noise[0] > 0 and noise[1] > 0 and sfs > 0:
        lam = noise[0] / noise[1]
        sss = sum(wi * (s - s_mean) ** 2 for wi, (s, _) in zip(w, points))
        d = sss - lam * sff
        b = (d + math.sqrt(d * d + 4.0 * lam * sfs * sfs)) / (2.0 * sfs)
        method = "errors-in-variables"
    a = s_mean - b * f_mean
    resid = sum(wi * (s - a - b * f) ** 2 for wi, (s, f) in zip(w, points))
    se_b = math.sqrt(resid / (n - 2) / sff)
    if b <= MIN_SLOPE_T * se_b:  # no force spread beyond the noise (one cluster): no slope to take
        return None
    return LineFit(1.0 / b, se_b / (b * b), n, a, method)


MIN_NOISE_ANCHORS = 10
"""The cruise windows give the slip's and the force's noise (their spread about their means) from this many on."""


def anchor_noise(anchors: Sequence[tuple[float, float]], weights: Sequence[float] | None = None
                 ) -> tuple[float, float] | None:
    """(var_s at weight 1, var_F) of the cruise windows: there the true force hardly changes, so their spread is the
    noise of each (an upper bound: a drift of the true value adds to it); None with fewer than MIN_NOISE_ANCHORS."""
    n = len(anchors)
    if n < MIN_NOISE_ANCHORS:
        return None
    w = [1.0] * n if weights is None else list(weights)
    s_mean = sum(wi * s for wi, (s, _) in zip(w, anchors)) / sum(w)
    var_s = sum(wi * (s - s_mean) ** 2 for wi, (s, _) in zip(w, anchors)) / (n - 1)
    return var_s, statistics.variance([f for _, f in anchors])


def speed_weights(speeds: Sequence[float], reference_mps: float) -> list[float]:
    """(V/V_ref)^2: the inverse of a window's slip noise variance (GPS speed noise / V), relative to V_ref."""
    return [(max(v, 0.5) / max(reference_mps, 0.5)) ** 2 for v in speeds]


def analyse_linearity(
    slips: Sequence[float | None], forces: Sequence[float | None], rule: LinearityRule = LinearityRule(),
    anchors: Sequence[tuple[float | None, float | None]] = (), speeds: Sequence[float | None] | None = None,
    anchor_speeds: Sequence[float | None] | None = None,
) -> Linearity:
    """The linear region of one wheel's force–slip points (rule in the module docstring); anchors: (slip, force) of
    the log's cruise windows; speeds, anchor_speeds: the windows' speeds (the line's weights, speed_weights)."""
    spd = list(speeds) if speeds is not None else [None] * len(slips)
    aspd = list(anchor_speeds) if anchor_speeds is not None else [None] * len(anchors)
    weighted = all(v is not None for s, f, v in zip(slips, forces, spd) if s is not None and f is not None) and \
        all(v is not None for (s, f), v in zip(anchors, aspd) if s is not None and f is not None)
    # (slip, force, speed); the speed 1.0 for all when some is missing (unweighted)
    both = [(s, f, float(v) if weighted and v is not None else 1.0) for s, f, v in zip(slips, forces, spd)
            if s is not None and f is not None]
    sign = 1.0 if sum(f for _, f, _ in both) >= 0 else -1.0
    anchor = [(s, f, float(v) if weighted and v is not None else 1.0) for (s, f), v in zip(anchors, aspd)
              if s is not None and f is not None]
    pts = sorted(
        ((s, f) for s, f in zip(slips, forces)
         if s is not None and f is not None and abs(s) >= rule.slip_min and s * f > 0),
        key=lambda p: abs(p[0]),
    )
    if not pts:
        return Linearity(0, None)
    bins: dict[int, list[tuple[float, float]]] = {}
    for p in pts:
        bins.setdefault(math.floor(abs(p[0]) / rule.bin_width), []).append(p)
    kept = [(j, b) for j, b in sorted(bins.items()) if len(b) >= rule.min_bin_points]

    fit_max = rule.slip_max
    line: LineFit | None = None
    end: tuple[int, list[tuple[float, float]]] | None = None
    for _ in range(rule.max_refits):
        fit_pts = [p for p in pts if abs(p[0]) <= fit_max]
        if len(fit_pts) < rule.min_fit_points:
            break
        kept_anchors = [p for p in anchor if abs(p[0]) <= fit_max]
        fit_both = [p for p in both if p[1] * sign > 0 and abs(p[0]) <= fit_max] + kept_anchors
        v_ref = statistics.median(p[2] for p in kept_anchors) if kept_anchors else 1.0
        line = (fit_slip_on_force([(s, f) for s, f, _ in fit_both],
                                  anchor_noise([(s, f) for s, f, _ in kept_anchors],
                                               speed_weights([p[2] for p in kept_anchors], v_ref)),
                                  speed_weights([p[2] for p in fit_both], v_ref)) if anchor else None) \
            or fit_through_origin(fit_pts)
        if line is None:
            break
        below = [
            statistics.median(abs(f) for _, f in b)
            < (1.0 - rule.tolerance) * abs(line.force_n(sign * statistics.median(abs(s) for s, _ in b)))
            for _, b in kept
        ]
        end = None
        for i in range(len(kept) - rule.min_end_bins + 1):
            if all(below[i:]):
                end = kept[i]
                break
        if end is None:
            break
        edge = end[0] * rule.bin_width
        if edge > fit_max:  # the end lies beyond the fitted points: the line is clean
            break
        if sum(abs(p[0]) < edge for p in pts) < rule.min_fit_points:
            break
        fit_max = math.nextafter(edge, 0.0)
    if line is None:
        return Linearity(len(pts), None)
    if end is None:
        linear = pts
        end_slip = end_force = None
    else:
        edge = end[0] * rule.bin_width
        linear = [p for p in pts if abs(p[0]) < edge]
        sign = 1.0 if sum(s for s, _ in end[1]) > 0 else -1.0
        end_slip = sign * statistics.median(abs(s) for s, _ in end[1])
        end_force = sign * statistics.median(abs(f) for _, f in end[1])
    peak = max(linear, key=lambda p: abs(p[1]), default=None)
    return Linearity(
        len(pts), line, end_slip, end_force,
        peak[1] if peak else None, peak[0] if peak else None,
    )


def peak_binned(points: Sequence[tuple[float, float]], rule: LinearityRule) -> tuple[float | None, float | None]:
    """(value, slip) of the bin (by |s|, rule.bin_width) of at least rule.min_bin_points points whose median |value|
    is largest: the median value and the median slip of that bin, signed; (None, None) when no bin is full enough."""
    bins: dict[int, list[tuple[float, float]]] = {}
    for s, v in points:
        bins.setdefault(math.floor(abs(s) / rule.bin_width), []).append((s, v))
    best: tuple[float, float] | None = None
    for b in bins.values():
        if len(b) < rule.min_bin_points:
            continue
        v = statistics.median(abs(x) for _, x in b)
        if best is None or v > abs(best[0]):
            sign = 1.0 if sum(x for _, x in b) >= 0 else -1.0
            ssign = 1.0 if sum(s for s, _ in b) >= 0 else -1.0
            best = (sign * v, ssign * statistics.median(abs(s) for s, _ in b))
    return best if best is not None else (None, None)


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
    fast: tuple[dict[str, Any], ...] = field(default=(), repr=False, compare=False)
    """The high-rate slip rows over the maneuver's span."""
    mu_points: dict[str, tuple[np.ndarray, np.ndarray]] = field(default_factory=dict, repr=False, compare=False)
    """Per wheel: (slip, mu) of the high-rate rows the mu-slip fit used."""
    brake: BrakeFigures | None = None


@dataclass(frozen=True)
class LogSummary:
    path: str
    name: str
    labels: dict[str, str]
    group: str
    mode: str
    estimates: int
    t0_s: float | None
    """Time of the first estimate (the log's clock); plot times are relative to it."""
    lost_frames: dict[str, int]
    bad_sentences: int | None
    maneuvers: list[ManeuverSummary]

    @property
    def title(self) -> str:
        lab = format_labels(self.labels)
        return f"{self.name} ({lab})" if lab else self.name


def group_of(labels: dict[str, str], group_by: Sequence[str] | None = None) -> str:
    """The comparison group of a log: its labels on the group_by keys (default: every key but `maneuver`)."""
    keys = list(group_by) if group_by else [k for k in labels if k != "maneuver"]
    parts = [f"{k}={labels.get(k, '–')}" for k in keys if group_by or k in labels]
    return ", ".join(parts) if parts else "(no labels)"


def _mean(values: Sequence[float]) -> float | None:
    return sum(values) / len(values) if values else None


def _round5(v_mps: float) -> int:
    return int(5 * round(v_mps * 3.6 / 5))


def maneuver_title(phase: str, speeds_mps: Sequence[float]) -> tuple[str, float, float]:
    """('accelerate 0–60 km/h', from, to) with from/to in km/h (rounded to 5 in the title)."""
    lo, hi = min(speeds_mps), max(speeds_mps)
    if phase == "accelerate":
        a, b = lo, hi
    elif phase == "brake":
        a, b = hi, lo
    else:
        m = statistics.median(speeds_mps)
        return f"{phase} {_round5(m)} km/h", lo * 3.6, hi * 3.6
    return f"{phase} {_round5(a)}–{_round5(b)} km/h", a * 3.6, b * 3.6


def log_config(metadata: dict[str, str]) -> Config | None:
    """The config a log was recorded with (config.py's models and defaults); None without one or with one this
    version cannot read."""
    text = metadata.get("config_toml")
    if not text:
        return None
    try:
        return parse_config(text)
    except ConfigError:
        return None


def summarize_wheel(
    rows: Sequence[dict[str, Any]], wheel: str, rule: LinearityRule, lost_frames: int | None,
    anchors: Sequence[dict[str, Any]] = (),
) -> WheelSummary:
    """anchors: the log's cruise rows (rule step 2)."""
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


def summarize_log(
    rows: Sequence[dict[str, Any]],
    metadata: dict[str, str],
    diagnostics: dict[str, Any] | None,
    *,
    path: str,
    name: str,
    labels: dict[str, str],
    group_by: Sequence[str] | None = None,
    rule: LinearityRule | None = None,
    fast: Sequence[dict[str, Any]] = (),
    sensors: Sequence[dict[str, Any]] = (),
) -> LogSummary:
    """Every maneuver of one log, per wheel; fast: its /slip/fast rows, sensors: its /can/sensors samples (the
    brake signal), both in time order."""
    cfg = log_config(metadata)
    rule = rule or LinearityRule()
    if cfg is not None:  # the bounds the estimator used for Cx
        rule = dataclasses.replace(rule, slip_min=cfg.estimator.cx_slip_min, slip_max=cfg.estimator.cx_slip_max)
    diag = diagnostics or {}
    lost = {w: int(v) for w, v in (diag.get("lost_frames") or {}).items()}
    have_phase = any(r.get("phase") is not None for r in rows)
    phases = debounce([r.get("phase") for r in rows] if have_phase else fallback.derive_phases(rows))
    t0 = rows[0]["time_s"] if rows else None
    cfg_latency = None if cfg is None else (cfg.latency_fixed_s or 0.0)  # "auto": 0
    maneuvers: list[ManeuverSummary] = []
    found = events(phases, [r["time_s"] for r in rows])
    cruise = tuple(r for r, p in zip(rows, phases) if p == "cruise")
    vehicle = cfg.vehicle if cfg is not None else VehicleConfig()
    fast_t = np.array([r["time_s"] for r in fast], dtype=np.float64)
    brake = [(d["time_s"], d["value"]) for d in sensors if d.get("kind") == "brake"]
    for phase in PHASES:
        kept = [tuple(rows[i] for i in idx) for p, idx in found if p == phase]
        kept = [prow for prow in kept if len(prow) >= MIN_MANEUVER_ROWS
                and any(r.get(f"slip_{w}") is not None for r in prow for w in WHEELS)]
        for k, prow in enumerate(kept, start=1):
            m = _maneuver(phase, prow, k if len(kept) > 1 else 0, rows[0]["time_s"], cfg_latency, rule, lost,
                          cruise if phase != "cruise" else ())
            maneuvers.append(_high_rate(m, fast, fast_t, brake, vehicle) if len(fast_t) else m)
    return LogSummary(
        path=path, name=name, labels=dict(labels), group=group_of(labels, group_by),
        mode=metadata.get("mode", ""), estimates=len(rows), t0_s=t0, lost_frames=lost,
        bad_sentences=diag.get("bad_sentences"), maneuvers=maneuvers,
    )


def _maneuver(phase: str, prow: tuple[dict[str, Any], ...], number: int, t0: float, cfg_latency: float | None,
              rule: LinearityRule, lost: dict[str, int], anchors: Sequence[dict[str, Any]]) -> ManeuverSummary:
    """One event's maneuver; number: its place among the log's events of the phase (0: the only one)."""
    title, v_from, v_to = maneuver_title(phase, [r["speed_mps"] for r in prow])
    lat = [r["gps_latency_s"] for r in prow if r.get("gps_latency_s") is not None]
    if lat:
        srcs = [r["latency_source"] for r in prow if r.get("latency_source")]
        latency: float | None = float(statistics.median(lat))
        lat_src = f"estimates ({statistics.mode(srcs)})" if srcs else "estimates"
    else:
        latency, lat_src = cfg_latency, "config"
    return ManeuverSummary(
        phase=phase, title=f"{title} #{number}" if number else title,
        key=f"{phase}-{number}" if number else phase, rows=prow,
        t_start_s=prow[0]["time_s"] - t0, t_end_s=prow[-1]["time_s"] - t0,
        speed_from_kmh=v_from, speed_to_kmh=v_to, gps_latency_s=latency, gps_latency_source=lat_src,
        wheels={w: summarize_wheel(prow, w, rule, lost.get(w), anchors) for w in WHEELS},
    )


def _high_rate(m: ManeuverSummary, fast: Sequence[dict[str, Any]], fast_t: np.ndarray,
               brake: Sequence[tuple[float, float]], vehicle: VehicleConfig) -> ManeuverSummary:
    """The maneuver with its high-rate rows, each wheel's mu-slip fit and, braking, its brake-test figures."""
    half = 0.5 * float(m.rows[0].get("window_s") or 0.5)
    t_from = m.rows[0]["time_s"] - half - SPAN_BEFORE_S
    t_to = m.rows[-1]["time_s"] + half + (SPAN_AFTER_S if m.phase == "brake" else 0.0)
    i0, i1 = int(fast_t.searchsorted(t_from)), int(fast_t.searchsorted(t_to, side="right"))
    span = tuple(fast[i0:i1])
    if len(span) < 3:
        return m
    t = fast_t[i0:i1]
    v = np.array([r["speed_mps"] for r in span])
    a = np.array([r["accel_mps2"] for r in span])
    slips = {w: np.array([math.nan if r.get(f"slip_{w}") is None else r[f"slip_{w}"] for r in span]) for w in WHEELS}
    wheels = dict(m.wheels)
    points: dict[str, tuple[np.ndarray, np.ndarray]] = {}
    if m.phase != "cruise":
        sign = 1.0 if m.phase == "accelerate" else -1.0
        mass = vehicle.mass_kg
        split = [tire_forces(mass * x, vehicle.driven_axle, vehicle.brake_front_share) for x in a]
        for w in WHEELS:
            fx = np.array([f[w] for f in split])
            fz = normal_loads_n(w, a, mass, vehicle.front_axle_load_share, vehicle.cg_height_m, vehicle.wheelbase_m)
            mu = mu_from_force(fx, fz)
            use = np.isfinite(slips[w]) & np.isfinite(mu) & (a * sign > 0) & (v >= MU_MIN_SPEED_MPS)
            points[w] = (slips[w][use], mu[use])
            fit = fit_mu_slip(slips[w][use], mu[use]) if use.sum() else None
            wheels[w] = dataclasses.replace(wheels[w], mu_slip=fit)
    figures = None
    if m.phase == "brake":
        bt = [x for x, _ in brake if t_from - 5.0 <= x <= t_to]
        bv = [y for x, y in brake if t_from - 5.0 <= x <= t_to]
        figures = brake_figures(t, v, a, brake_time_s=bt or None, brake_value=bv or None, slip_time_s=t, slips=slips)
    return dataclasses.replace(m, wheels=wheels, fast=span, mu_points=points, brake=figures)


# ---- the table (summary.csv / summary.json) ----------------------------------------------------------------

COLUMNS: tuple[str, ...] = (
    "log", "labels", "group", "maneuver", "phase", "wheel", "t_start_s", "t_end_s", "speed_from_kmh",
    "speed_to_kmh", "slip_samples", "mean_slip", "max_abs_slip", "linearity", "linear_end_slip",
    "linear_end_fx_n", "peak_linear_fx_n", "peak_linear_fx_slip", "cx_line_n", "cx_line_points", "cx_line_method",
    "cx_line_slip_offset", "mean_re_m",
    "r0_m", "peak_cx_n", "peak_cx_slip", "cx_fit_n", "cx_fit_conf", "cx_fit_source", "gps_latency_s",
    "gps_latency_source", "lost_frames", "bad_sentences", "mu_peak", "slip_at_mu_peak", "mu_slip_model",
    "brake_speed_kmh", "stopping_distance_m", "stopping_distance_corrected_m", "mfdd_mps2", "abs_cycles",
    "abs_frequency_hz",
)
"""One row per log, maneuver and wheel. Slips are fractions, forces N, radii m, stiffness N per unit slip."""


BRAKE_COLUMNS = ("brake_speed_kmh", "stopping_distance_m", "stopping_distance_corrected_m", "mfdd_mps2", "abs_cycles",
                 "abs_frequency_hz")


def brake_columns(b: BrakeFigures | None) -> dict[str, Any]:
    """The brake-test figures of a maneuver by their column names (None each without)."""
    return {c: getattr(b, c) if b is not None else None for c in BRAKE_COLUMNS}


def table_rows(logs: Sequence[LogSummary]) -> list[dict[str, Any]]:
    out: list[dict[str, Any]] = []
    for log in logs:
        for m in log.maneuvers:
            for w, ws in m.wheels.items():
                lin = ws.linearity
                out.append({
                    "log": log.name, "labels": format_labels(log.labels), "group": log.group,
                    "maneuver": m.title, "phase": m.phase, "wheel": w,
                    "t_start_s": m.t_start_s, "t_end_s": m.t_end_s,
                    "speed_from_kmh": m.speed_from_kmh, "speed_to_kmh": m.speed_to_kmh,
                    "slip_samples": ws.slip_samples, "mean_slip": ws.mean_slip, "max_abs_slip": ws.max_abs_slip,
                    "linearity": lin.verdict, "linear_end_slip": lin.end_slip, "linear_end_fx_n": lin.end_force_n,
                    "peak_linear_fx_n": lin.peak_fx_n, "peak_linear_fx_slip": lin.peak_fx_slip,
                    "cx_line_n": lin.line.cx_n if lin.line else None,
                    "cx_line_points": lin.line.points if lin.line else 0,
                    "cx_line_method": lin.line.method if lin.line else None,
                    "cx_line_slip_offset": lin.line.slip_offset if lin.line else None,
                    "mean_re_m": ws.mean_re_m, "r0_m": ws.r0_m,
                    "peak_cx_n": ws.peak_cx_n, "peak_cx_slip": ws.peak_cx_slip,
                    "cx_fit_n": ws.cx_fit_n, "cx_fit_conf": ws.cx_fit_conf, "cx_fit_source": ws.cx_fit_source,
                    "gps_latency_s": m.gps_latency_s, "gps_latency_source": m.gps_latency_source,
                    "lost_frames": ws.lost_frames, "bad_sentences": log.bad_sentences,
                    "mu_peak": ws.mu_slip.mu_peak if ws.mu_slip else None,
                    "slip_at_mu_peak": ws.mu_slip.slip_at_mu_peak if ws.mu_slip else None,
                    "mu_slip_model": ws.mu_slip.model if ws.mu_slip else None,
                } | brake_columns(m.brake))
    return out


# ---- comparison across logs, grouped by labels -------------------------------------------------------------

@dataclass(frozen=True)
class GroupWheel:
    cx_fit_n: float | None
    """Mean over the group's logs."""
    peak_linear_fx_n: float | None
    """Of largest |Fx| over the group's logs."""
    peak_linear_fx_slip: float | None
    linear_end_slip: float | None
    """Smallest |end| over the logs; None: linear throughout in every log."""
    mean_re_m: float | None


@dataclass(frozen=True)
class GroupSummary:
    group: str
    logs: tuple[str, ...]
    titles: tuple[str, ...]
    wheels: dict[str, GroupWheel]


@dataclass(frozen=True)
class Comparison:
    phase: str
    groups: list[GroupSummary]


def compare(logs: Sequence[LogSummary]) -> list[Comparison]:
    """Per phase, the groups (by label) side by side, each aggregated over its logs."""
    out: list[Comparison] = []
    groups = list(dict.fromkeys(log.group for log in logs))
    for phase in PHASES:
        gs: list[GroupSummary] = []
        for g in groups:
            ms = [(log, m) for log in logs if log.group == g for m in log.maneuvers if m.phase == phase]
            if not ms:
                continue
            wheels: dict[str, GroupWheel] = {}
            for w in WHEELS:
                ws = [m.wheels[w] for _, m in ms]
                peaks = [x.linearity for x in ws if x.linearity.peak_fx_n is not None]
                peak = max(peaks, key=lambda lin: abs(lin.peak_fx_n or 0.0), default=None)
                ends = [x.linearity.end_slip for x in ws if x.linearity.end_slip is not None]
                wheels[w] = GroupWheel(
                    cx_fit_n=_mean([x.cx_fit_n for x in ws if x.cx_fit_n is not None]),
                    peak_linear_fx_n=peak.peak_fx_n if peak else None,
                    peak_linear_fx_slip=peak.peak_fx_slip if peak else None,
                    linear_end_slip=min(ends, key=abs) if ends else None,
                    mean_re_m=_mean([x.mean_re_m for x in ws if x.mean_re_m is not None]),
                )
            gs.append(GroupSummary(g, tuple(log.name for log, _ in ms), tuple(m.title for _, m in ms), wheels))
        if gs:
            out.append(Comparison(phase, gs))
    return out
