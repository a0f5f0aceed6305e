"""Brake-test figures of one brake maneuver from its time series. Pure: arrays in, dataclasses out.

Inputs: time_s, the vehicle speed (m/s, ~100 Hz) and longitudinal acceleration (m/s², braking < 0) over the
maneuver's span; optionally the brake signal's samples (times, values; nonzero = pressed) and the wheels' high-rate
slip (fractions, braking < 0).

Figures
    onset t0: `brake_onset_s`; v0 = v(t0) (linear interpolation on the fused high-rate speed). From a time mark (the
        receiver's UBX-TIM-TM2 of the brake-light switch, on the host's clock): that instant; from a sampled brake
        signal: the midpoint between the last released and the first pressed sample, the press lying anywhere
        within ± half their interval (`onset_half_s`, carried into the stopping distance's interval).
    Stopping distance (ISO 21994): d = ∫ v dt from t0 to standstill, trapezoids (the ends interpolated linearly).
        Standstill: the first time after t0 that v falls to STANDSTILL_MPS (interpolated crossing); the distance
        still rolled below it, v²/(2·a), is under 1 mm at any real deceleration and left out.
    Corrected distance (ISO 21994): d·(v_nom/v0)² with v_nom = v0 rounded to the nearest 10 km/h (halves up).
    MFDD (ECE R13-H, annex 3): (vb² − ve²) / (2·(se − sb)) with vb = 0.8·v0, ve = 0.1·v0 and se − sb the
        distance travelled between the (linearly interpolated) times the speed falls to vb and to ve; or over a
        given window (vb, ve) (a procedure's, e.g. UN R117's 80 to 20 km/h), when v0 is above vb.
    ABS cycles: `abs_cycling` per wheel, between t0 and the time v falls to ABS_MIN_SPEED_MPS; the wheel with
        the most cycles is reported (ABS acts per wheel; one wheel cycling is ABS at work).
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

FloatArray = npt.NDArray[np.float64]

STANDSTILL_MPS = 0.1
"""The car has stopped once its speed falls to this."""
DECEL_THRESHOLD_MPS2 = 1.0
"""Deceleration onset: the deceleration must first exceed this ..."""
RISE_LOW, RISE_HIGH = 0.10, 0.50
"""... and the line through its rise between these fractions of the peak deceleration (above the pre-brake level)
is extrapolated back to that level."""
PEAK_SEARCH_S = 1.0
"""The peak deceleration is looked for within this long after the threshold crossing."""
BASE_WINDOW_S = 0.5
"""The pre-brake level: the median deceleration over this long before the rise (0 when the span has none)."""
ABS_BAND = 0.03
"""Hysteresis half-width about the median |slip| (slip fraction) that an ABS cycle must cross both ways."""
MIN_ABS_CYCLES = 2
"""Fewer cycles than this is no cycling (a single excursion: a wheel locking, a bump)."""
ABS_MIN_SPEED_MPS = 1.5
"""ABS cycles are counted while the car is faster than this (ABS switches off at walking pace; slip is ill-defined
near standstill)."""


def _arrays(*cols: npt.ArrayLike) -> list[FloatArray]:
    out = [np.asarray(c, dtype=float).ravel() for c in cols]
    if any(c.shape != out[0].shape for c in out):
        raise ValueError("time series of one maneuver must have the same length")
    ok = np.logical_and.reduce([np.isfinite(c) for c in out])
    return [c[ok] for c in out]


def _onset_from_brake(t_from: float, t_to: float, brake_time_s: npt.ArrayLike,
                      brake_value: npt.ArrayLike) -> tuple[float, float] | None:
    """(midpoint, half interval) of the first brake sample pressed (nonzero) within [t_from, t_to] and the released
    one right before it: the press happened between the two samples."""
    bt, bv = _arrays(brake_time_s, brake_value)
    order = np.argsort(bt, kind="stable")
    bt, pressed = bt[order], bv[order] != 0
    rising = np.flatnonzero(pressed[1:] & ~pressed[:-1]) + 1
    rising = rising[(bt[rising] >= t_from) & (bt[rising] <= t_to)]
    if not rising.size:
        return None
    before, after = float(bt[rising[0] - 1]), float(bt[rising[0]])
    return 0.5 * (before + after), 0.5 * (after - before)


def _onset_from_marks(t_from: float, t_to: float, mark_time_s: npt.ArrayLike) -> float | None:
    """The first time mark of the brake's press within [t_from, t_to]."""
    (mt,) = _arrays(mark_time_s)
    mt = np.sort(mt[(mt >= t_from) & (mt <= t_to)])
    return float(mt[0]) if mt.size else None


def _onset_from_decel(t: FloatArray, a: FloatArray, threshold_mps2: float) -> float | None:
    """The deceleration's rise extrapolated back to the pre-brake level (module constants RISE_*, BASE_WINDOW_S)."""
    d = -a
    above = np.flatnonzero(d > threshold_mps2)
    if above.size == 0:
        return None
    i_thr = int(above[0])
    t_thr = float(t[i_thr])
    if i_thr > 0:  # the threshold crossing itself, interpolated: the fallback when no line can be fitted
        t_thr = float(np.interp(threshold_mps2, [d[i_thr - 1], d[i_thr]], [t[i_thr - 1], t[i_thr]]))
    peak = float(np.max(d[(t >= t[i_thr]) & (t <= t[i_thr] + PEAK_SEARCH_S)]))
    j = i_thr
    while j > 0 and d[j - 1] > RISE_LOW * peak:
        j -= 1
    pre = d[(t < t[j]) & (t >= t[j] - BASE_WINDOW_S)]
    base = float(np.median(pre)) if pre.size else 0.0
    lo, hi = base + RISE_LOW * (peak - base), base + RISE_HIGH * (peak - base)
    k0 = i_thr
    while k0 > 0 and d[k0 - 1] > lo:
        k0 -= 1
    reached = np.flatnonzero(d[k0:] >= hi)
    k1 = k0 + int(reached[0]) if reached.size else i_thr
    if k1 - k0 < 1:
        return t_thr
    slope, intercept = np.polyfit(t[k0:k1 + 1], d[k0:k1 + 1], 1)
    if not slope > 0:
        return t_thr
    return min(float((base - intercept) / slope), t_thr)


def brake_onset_s(
    time_s: npt.ArrayLike, accel_mps2: npt.ArrayLike,
    brake_time_s: npt.ArrayLike | None = None, brake_value: npt.ArrayLike | None = None,
    threshold_mps2: float = DECEL_THRESHOLD_MPS2, mark_time_s: npt.ArrayLike | None = None,
) -> float | None:
    """Brake onset (s, the clock of time_s) in the maneuver's span [time_s[0], time_s[-1]].

    From a time mark of the press when one lies in the span (mark_time_s: the first). Else from the brake signal
    when given: the midpoint between the first sample pressed (nonzero) in the span and the released one right
    before it (which may lie before the span), no rounding to the time_s grid. Without the signal,
    or without such a transition in the span (pressed throughout, never pressed): from the deceleration d = −a,
    the first sample with d > threshold_mps2; the line fitted to d over its rise between RISE_LOW and RISE_HIGH of
    the peak (the largest d within PEAK_SEARCH_S) above the pre-brake level (median d over BASE_WINDOW_S before
    the rise) intersects that level at the onset (the rise's first part is a ramp, the brake's pressure build-up).
    With fewer than 2 points on the rise: the interpolated threshold crossing. None: no deceleration above it."""
    return _onset(time_s, accel_mps2, brake_time_s, brake_value, threshold_mps2, mark_time_s)[0]


def _onset(
    time_s: npt.ArrayLike, accel_mps2: npt.ArrayLike,
    brake_time_s: npt.ArrayLike | None, brake_value: npt.ArrayLike | None, threshold_mps2: float,
    mark_time_s: npt.ArrayLike | None = None,
) -> tuple[float | None, str, float]:
    """(onset, its source, half the interval it lies in: 0 unless from sampled brake signal)."""
    t, a = _arrays(time_s, accel_mps2)
    if t.size < 2:
        return None, "none", 0.0
    if mark_time_s is not None:
        mark = _onset_from_marks(float(t[0]), float(t[-1]), mark_time_s)
        if mark is not None:
            return mark, "time mark", 0.0
    if brake_time_s is not None and brake_value is not None:
        sampled = _onset_from_brake(float(t[0]), float(t[-1]), brake_time_s, brake_value)
        if sampled is not None:
            return sampled[0], "brake signal", sampled[1]
    onset = _onset_from_decel(t, a, threshold_mps2)
    return (onset, "deceleration", 0.0) if onset is not None else (None, "none", 0.0)


def _falls_to(t: FloatArray, v: FloatArray, t_from: float, level: float) -> float | None:
    """First time after t_from at which v (linearly interpolated) falls to level; None if it never does."""
    after = np.flatnonzero((t > t_from) & (v <= level))
    if after.size == 0:
        return None
    k = int(after[0])
    if k > 0 and t[k - 1] > t_from:
        t_prev, v_prev = float(t[k - 1]), float(v[k - 1])
    else:
        t_prev, v_prev = t_from, float(np.interp(t_from, t, v))
    if v_prev <= level:
        return t_prev
    return t_prev + (v_prev - level) / (v_prev - float(v[k])) * (float(t[k]) - t_prev)


def _distance_m(t: FloatArray, v: FloatArray, t_a: float, t_b: float) -> float:
    """∫ v dt from t_a to t_b by trapezoids over the samples between, the ends interpolated."""
    inner = (t > t_a) & (t < t_b)
    tt = np.concatenate([[t_a], t[inner], [t_b]])
    vv = np.interp(tt, t, v)
    return float(np.sum(0.5 * (vv[1:] + vv[:-1]) * np.diff(tt)))


@dataclass(frozen=True)
class AbsCycling:
    cycles: int
    """Excursions of |slip| above median + band each followed by one below median − band (0: no cycling)."""
    frequency_hz: float | None
    """(starts − 1) / (last start − first start) over the excursions' start times: None without cycling."""
    first_start_s: float | None = None
    last_start_s: float | None = None


def abs_cycling(
    time_s: npt.ArrayLike, slip: npt.ArrayLike, band: float = ABS_BAND,
    t_from: float | None = None, t_to: float | None = None,
) -> AbsCycling:
    """ABS cycles of one wheel's high-rate slip within [t_from, t_to] (default: all of it).

    x = |slip|, m its median there; a cycle starts when x rises above m + band (the crossing time interpolated)
    and is complete when x then falls below m − band (hysteresis: noise within ±band counts nothing). The
    frequency is the mean rate of cycle starts (cycles / the time from the first to the last start, counting the
    starts). Fewer than MIN_ABS_CYCLES cycles (a locked wheel: x constant at 1; a light brake: x within the band)
    give 0 cycles and no frequency."""
    t, s = _arrays(time_s, slip)
    keep = np.ones(t.shape, dtype=bool)
    if t_from is not None:
        keep &= t >= t_from
    if t_to is not None:
        keep &= t <= t_to
    t, x = t[keep], np.abs(s[keep])
    if x.size < 3:
        return AbsCycling(0, None)
    m = float(np.median(x))
    hi, lo = m + band, m - band
    state = np.where(x > hi, 1, np.where(x < lo, -1, 0))
    nz = np.flatnonzero(state)
    if nz.size == 0:
        return AbsCycling(0, None)
    vals = state[nz]
    entries = np.concatenate([[0], np.flatnonzero(np.diff(vals) != 0) + 1])  # positions in nz where a state begins
    cycles = int(np.count_nonzero(vals[entries[1:]] == -1))  # every change into "low" follows a "high"
    if cycles < MIN_ABS_CYCLES:
        return AbsCycling(0, None)
    starts = []
    for i in nz[entries[vals[entries] == 1]]:
        if i > 0 and x[i] != x[i - 1]:
            starts.append(float(t[i - 1] + (hi - x[i - 1]) / (x[i] - x[i - 1]) * (t[i] - t[i - 1])))
        else:
            starts.append(float(t[i]))
    span = starts[-1] - starts[0]
    freq = (len(starts) - 1) / span if len(starts) >= 2 and span > 0 else None
    return AbsCycling(cycles, freq, starts[0], starts[-1])


@dataclass(frozen=True)
class BrakeFigures:
    onset_s: float
    onset_source: str
    """'time mark', 'brake signal' or 'deceleration' (brake_onset_s); 'given'."""
    brake_speed_kmh: float
    """v0: the speed at onset."""
    stop_s: float | None
    """Time the speed fell to STANDSTILL_MPS; None: the car did not stop within the span."""
    stopping_distance_m: float | None
    nominal_speed_kmh: float | None
    """v0 rounded to the nearest 10 km/h (halves up); None below 5 km/h."""
    stopping_distance_corrected_m: float | None
    """d·(v_nom/v0)²."""
    mfdd_mps2: float | None
    """ECE R13-H; None when the speed does not fall to 0.1·v0 within the span."""
    abs_cycles: int
    abs_frequency_hz: float | None
    abs_wheel: str | None
    """The wheel the ABS figures are from (the one with the most cycles); None without slip or cycling."""
    stopping_distance_m_lo: float | None = None
    """95 % intervals from the inputs' noise (brake_noise.brake_intervals; None: not computed or not given)."""
    stopping_distance_m_hi: float | None = None
    mfdd_mps2_lo: float | None = None
    mfdd_mps2_hi: float | None = None
    onset_half_s: float = 0.0
    """The press lies within onset_s ± this (a sampled brake signal: half the interval between the last released
    and the first pressed sample; 0 otherwise)."""


def brake_figures(
    time_s: npt.ArrayLike, speed_mps: npt.ArrayLike, accel_mps2: npt.ArrayLike, *,
    brake_time_s: npt.ArrayLike | None = None, brake_value: npt.ArrayLike | None = None,
    slip_time_s: npt.ArrayLike | None = None, slips: Mapping[str, npt.ArrayLike] | None = None,
    standstill_mps: float = STANDSTILL_MPS, threshold_mps2: float = DECEL_THRESHOLD_MPS2, abs_band: float = ABS_BAND,
    onset_s: float | None = None, mfdd_window_mps: tuple[float, float] | None = None,
    mark_time_s: npt.ArrayLike | None = None,
) -> BrakeFigures | None:
    """The figures of one brake maneuver (module docstring) over the span of time_s. slips: wheel -> slip series
    on slip_time_s (default time_s); onset_s: the onset, given (source 'given'); mfdd_window_mps: the MFDD's (vb, ve)
    (default 0.8·v0, 0.1·v0); mark_time_s: time marks of the brake's press. None when no onset is found or the car
    is not moving at it."""
    t, v = _arrays(time_s, speed_mps)
    onset, source, half = (onset_s, "given", 0.0) if onset_s is not None else \
        _onset(time_s, accel_mps2, brake_time_s, brake_value, threshold_mps2, mark_time_s)
    if onset is None or t.size < 2:
        return None
    v0 = float(np.interp(onset, t, v))
    if not v0 > standstill_mps:
        return None
    v0_kmh = v0 * 3.6
    stop = _falls_to(t, v, onset, standstill_mps)
    dist = _distance_m(t, v, onset, stop) if stop is not None else None
    nominal = 10.0 * math.floor(v0_kmh / 10.0 + 0.5)
    nominal_kmh = nominal if nominal > 0 else None
    corrected = dist * (nominal / v0_kmh) ** 2 if dist is not None and nominal_kmh is not None else None

    mfdd = None
    vb, ve = mfdd_window_mps or (0.8 * v0, 0.1 * v0)
    tb = _falls_to(t, v, onset, vb) if vb < v0 else None
    te = _falls_to(t, v, tb, ve) if tb is not None else None
    if tb is not None and te is not None and te > tb:
        mfdd = (vb * vb - ve * ve) / (2.0 * _distance_m(t, v, tb, te))

    cycles, freq, wheel = 0, None, None
    if slips:
        t_end = _falls_to(t, v, onset, ABS_MIN_SPEED_MPS)
        st = time_s if slip_time_s is None else slip_time_s
        for w, series in slips.items():
            res = abs_cycling(st, series, abs_band, onset, t_end)
            if res.cycles > cycles:
                cycles, freq, wheel = res.cycles, res.frequency_hz, w
    return BrakeFigures(
        onset_s=onset, onset_source=source, brake_speed_kmh=v0_kmh, stop_s=stop, stopping_distance_m=dist,
        nominal_speed_kmh=nominal_kmh, stopping_distance_corrected_m=corrected, mfdd_mps2=mfdd,
        abs_cycles=cycles, abs_frequency_hz=freq, abs_wheel=wheel, onset_half_s=half,
    )
