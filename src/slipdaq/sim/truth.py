"""Estimates against the simulator's truth: the error figures used by the demo, the tests and the benchmarks, and
the true brake-test figures (onset, stopping distance, MFDD) and tire peak they are compared with."""

from __future__ import annotations

from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass
from typing import Any, NamedTuple

import numpy as np

from slipdaq import WHEELS
from slipdaq.sim.vehicle import ROADS, TruthSample

MFDD_START_SHARE, MFDD_END_SHARE = 0.8, 0.1
"""ECE R13-H: the MFDD is the mean deceleration between 0.8*v0 and 0.1*v0."""


@dataclass(frozen=True)
class SlipError:
    samples: int
    rms_points: float
    """RMS of estimated minus true slip, in percentage points."""
    max_abs_points: float
    median_abs_points: float
    p95_abs_points: float


def truth_series(truth: Sequence[TruthSample], start_utc_s: float) -> dict[str, np.ndarray]:
    """Truth as arrays on the log's clock: time_s, speed_mps, accel_mps2, distance_m, brake_pressed (bool), and
    slip_/force_/r0_/fz_/mu_ of each wheel."""
    out = {
        "time_s": np.array([t.time_s + start_utc_s for t in truth]),
        "speed_mps": np.array([t.speed_mps for t in truth]),
        "accel_mps2": np.array([t.accel_mps2 for t in truth]),
        "distance_m": np.array([t.distance_m for t in truth]),
        "brake_pressed": np.array([t.brake_pressed for t in truth], dtype=bool),
    }
    for w in WHEELS:
        out[f"slip_{w}"] = np.array([t.wheels[w].slip for t in truth])
        out[f"force_{w}"] = np.array([t.wheels[w].force_n for t in truth])
        out[f"r0_{w}"] = np.array([t.wheels[w].r0_m for t in truth])
        out[f"fz_{w}"] = np.array([t.wheels[w].fz_n for t in truth])
        out[f"mu_{w}"] = np.array([t.wheels[w].mu for t in truth])
    return out


Truth = Sequence[TruthSample] | Mapping[str, np.ndarray]
"""Truth samples in time order, or their truth_series arrays (then times are on the series' clock)."""


def _arrays(truth: Truth) -> Mapping[str, np.ndarray]:
    return truth if isinstance(truth, Mapping) else truth_series(truth, 0.0)


def _onset_index(series: Mapping[str, np.ndarray]) -> int | None:
    """The first sample with the brake applied (after one without, or the first sample)."""
    pressed = np.flatnonzero(series["brake_pressed"])
    return int(pressed[0]) if pressed.size else None


def brake_onset_time_s(truth: Truth) -> float | None:
    """Time of the first truth sample with the driver's brake applied; None without braking."""
    series = _arrays(truth)
    i = _onset_index(series)
    return None if i is None else float(series["time_s"][i])


def speed_at_onset_mps(truth: Truth) -> float | None:
    """v0: the speed at brake_onset_time_s."""
    series = _arrays(truth)
    i = _onset_index(series)
    return None if i is None else float(series["speed_mps"][i])


def stopping_distance_m(truth: Truth) -> float | None:
    """Distance travelled from the brake onset to the first standstill (V = 0) after it; None when it never stops."""
    series = _arrays(truth)
    i = _onset_index(series)
    if i is None:
        return None
    stopped = np.flatnonzero(series["speed_mps"][i:] <= 0.0)
    return None if not stopped.size else float(series["distance_m"][i + stopped[0]] - series["distance_m"][i])


def _distance_at_speed_m(series: Mapping[str, np.ndarray], start: int, speed_mps: float) -> float | None:
    """Distance where the speed first falls to speed_mps at or after sample `start` (linear in time between
    samples; the distance at that time linear between samples too)."""
    v, x = series["speed_mps"], series["distance_m"]
    below = np.flatnonzero(v[start:] <= speed_mps)
    if not below.size:
        return None
    j = start + int(below[0])
    if j == start:
        return float(x[j])
    share = (v[j - 1] - speed_mps) / (v[j - 1] - v[j])
    return float(x[j - 1] + share * (x[j] - x[j - 1]))


def mfdd_mps2(truth: Truth) -> float | None:
    """Mean fully developed deceleration (ECE R13-H): MFDD = (vb^2 - ve^2) / (2*(se - sb)), vb = 0.8*v0,
    ve = 0.1*v0, sb and se the distances travelled (from the onset) when the speed falls to vb and ve."""
    series = _arrays(truth)
    i = _onset_index(series)
    if i is None:
        return None
    v0 = float(series["speed_mps"][i])
    vb, ve = MFDD_START_SHARE * v0, MFDD_END_SHARE * v0
    sb, se = _distance_at_speed_m(series, i, vb), _distance_at_speed_m(series, i, ve)
    if sb is None or se is None or se <= sb:
        return None
    return (vb * vb - ve * ve) / (2.0 * (se - sb))


class TirePeak(NamedTuple):
    mu_peak: float
    """Largest Fx/Fz of the tire curve: D/Fz = mu."""
    slip_at_mu_peak: float
    """|slip| where it is reached: tan(pi/(2C))/B."""


def tire_peak(road: str) -> TirePeak:
    """The true peak of the road's tire curve (the simulator's TireModel)."""
    tire = ROADS[road]
    return TirePeak(tire.mu, tire.peak_slip)


def _window_mean(truth: dict[str, np.ndarray], key: str, t_c: float, half_s: float) -> float:
    grid = np.linspace(t_c - half_s, t_c + half_s, 21)
    return float(np.mean(np.interp(grid, truth["time_s"], truth[key])))


def slip_errors(
    rows: Iterable[dict[str, Any]], truth: dict[str, np.ndarray], min_speed_mps: float = 5.0,
    wheels: Sequence[str] = WHEELS, only_calibrated: bool = False,
) -> np.ndarray:
    """Estimated minus true slip (window-averaged truth), per wheel window, speed above min_speed_mps."""
    errors: list[float] = []
    for row in rows:
        if row["speed_mps"] is None or row["speed_mps"] < min_speed_mps or row.get("source", "gps") != "gps":
            continue
        half = 0.5 * row.get("window_s", 0.5)
        for w in wheels:
            s = row.get(f"slip_{w}")
            if s is None or (only_calibrated and row.get(f"r0_source_{w}") not in ("calibrated", "calibrating")):
                continue
            errors.append(s - _window_mean(truth, f"slip_{w}", row["time_s"], half))
    return np.array(errors)


def summarize(errors: np.ndarray) -> SlipError:
    e = np.abs(errors) * 100.0
    if e.size == 0:
        return SlipError(0, *[float("nan")] * 4)
    return SlipError(
        int(e.size), float(np.sqrt(np.mean(e**2))), float(e.max()), float(np.median(e)), float(np.percentile(e, 95))
    )


def slip_error(
    rows: Iterable[dict[str, Any]], truth: dict[str, np.ndarray], min_speed_mps: float = 5.0,
    wheels: Sequence[str] = WHEELS, only_calibrated: bool = False,
) -> SlipError:
    """Compare each estimate's slip with the truth averaged over the same window (speed above min_speed_mps)."""
    return summarize(slip_errors(rows, truth, min_speed_mps, wheels, only_calibrated))


def linear_stiffness_truth(
    rows: Iterable[dict[str, Any]], truth: dict[str, np.ndarray], wheel: str, min_speed_mps: float = 5.0,
    max_slip: float = 0.10,
) -> float | None:
    """The stiffness a perfect measurement would give with slipdaq's fit: 1 / the least-squares slope of the true
    slip against the true tire force (with intercept) over the windows the fit uses. On a tire whose curve bends
    within the linear region this is below the initial slope dF/ds(0)."""
    s_true: list[float] = []
    f_true: list[float] = []
    for row in rows:
        if row["speed_mps"] is None or row["speed_mps"] < min_speed_mps or row.get("source", "gps") != "gps":
            continue
        if row.get(f"slip_{wheel}") is None or abs(row[f"slip_{wheel}"]) > max_slip or row.get("force_n") is None:
            continue
        half = 0.5 * row.get("window_s", 0.5)
        s_true.append(_window_mean(truth, f"slip_{wheel}", row["time_s"], half))
        f_true.append(_window_mean(truth, f"force_{wheel}", row["time_s"], half))
    if len(s_true) < 10 or np.ptp(f_true) < 100.0:
        return None
    slope, _ = np.polyfit(np.array(f_true), np.array(s_true), 1)  # slip on force, as the estimator fits it
    return float(1.0 / slope) if slope > 0 else None
