"""Estimates against the simulator's truth: the error figures used by the demo, the tests and the benchmarks."""

from __future__ import annotations

from collections.abc import Iterable, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from slipdaq import WHEELS
from slipdaq.sim.vehicle import TruthSample


@dataclass(frozen=True)
class SlipError:
    samples: int
    rms_points: float
    """RMS of estimated minus true slip, in percentage points."""
    max_abs_points: float
    median_abs_points: float
    p95_abs_points: float


def truth_series(truth: Sequence[TruthSample], start_utc_s: float) -> dict[str, np.ndarray]:
    """Truth as arrays on the log's clock: time_s, speed_mps, and slip_/force_/r0_ of each wheel."""
    out = {
        "time_s": np.array([t.time_s + start_utc_s for t in truth]),
        "speed_mps": np.array([t.speed_mps for t in truth]),
        "accel_mps2": np.array([t.accel_mps2 for t in truth]),
    }
    for w in WHEELS:
        out[f"slip_{w}"] = np.array([t.wheels[w].slip for t in truth])
        out[f"force_{w}"] = np.array([t.wheels[w].force_n for t in truth])
        out[f"r0_{w}"] = np.array([t.wheels[w].r0_m for t in truth])
    return out


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
