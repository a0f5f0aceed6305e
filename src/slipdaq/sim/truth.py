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
    """Truth as arrays on the log's clock: time_s, speed_mps and slip_<W> for each wheel."""
    out = {
        "time_s": np.array([t.time_s + start_utc_s for t in truth]),
        "speed_mps": np.array([t.speed_mps for t in truth]),
    }
    for w in WHEELS:
        out[f"slip_{w}"] = np.array([t.wheels[w].slip for t in truth])
    return out


def slip_error(
    rows: Iterable[dict[str, Any]], truth: dict[str, np.ndarray], min_speed_mps: float = 5.0,
    wheels: Sequence[str] = WHEELS,
) -> SlipError:
    """Compare each estimate's slip with the truth averaged over the same window (speed above min_speed_mps)."""
    errors: list[float] = []
    t = truth["time_s"]
    for row in rows:
        if row["speed_mps"] is None or row["speed_mps"] < min_speed_mps:
            continue
        half = 0.5 * row.get("window_s", 0.5)
        grid = np.linspace(row["time_s"] - half, row["time_s"] + half, 21)
        for w in wheels:
            s = row.get(f"slip_{w}")
            if s is None:
                continue
            errors.append(s - float(np.mean(np.interp(grid, t, truth[f"slip_{w}"]))))
    e = np.abs(np.array(errors)) * 100.0
    if e.size == 0:
        return SlipError(0, *[float("nan")] * 4)
    return SlipError(
        int(e.size), float(np.sqrt(np.mean(e**2))), float(e.max()), float(np.median(e)), float(np.percentile(e, 95))
    )
