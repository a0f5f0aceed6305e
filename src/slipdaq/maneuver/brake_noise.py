"""The 95 % intervals of a brake maneuver's stopping distance and MFDD from their inputs' noise. Pure.

Inputs and their noise: the speed (the fused high-rate speed: its noise sigma_v is the RMS of its difference from a
centred moving average over SMOOTH_S, taken as correlated over CORRELATION_S, as a GPS speed's error is between
fixes) and the onset (from the deceleration's rise: DECEL_ONSET_SIGMA_S; from a time mark: none). DRAWS draws of
both (a fixed seed: live and report agree) recompute the figures (brake_test.brake_figures with the onset given);
the interval is their 2.5 and 97.5 percentiles. From a sampled brake signal the press lies anywhere within the
onset ± onset_half_s (between the last released and the first pressed sample): the interval of the draws at the
onset is widened by how far each figure moves with the onset at either end of that range.
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np
import numpy.typing as npt

from slipdaq.maneuver.brake_test import BrakeFigures, brake_figures

SMOOTH_S = 0.3
CORRELATION_S = 0.1
DECEL_ONSET_SIGMA_S = 0.05
"""The onset from the deceleration's rise: its standard uncertainty (the rise's line extrapolated over a ramp)."""
DRAWS = 40
SEED = 20261125


def _moving_average(x: np.ndarray, n: int) -> np.ndarray:
    if n <= 1 or x.size < n:
        return x.copy()
    k = np.ones(n) / n
    pad = n // 2
    return np.convolve(np.pad(x, (pad, n - 1 - pad), mode="edge"), k, mode="valid")


def speed_noise_mps(time_s: npt.ArrayLike, speed_mps: npt.ArrayLike) -> float:
    """sigma_v: RMS of the speed about its centred moving average over SMOOTH_S, where the car moves (> 1 m/s)."""
    t, v = np.asarray(time_s, dtype=float), np.asarray(speed_mps, dtype=float)
    if t.size < 3:
        return 0.0
    dt = float(np.median(np.diff(t)))
    n = max(1, int(round(SMOOTH_S / max(dt, 1e-6))))
    resid = (v - _moving_average(v, n))[v > 1.0]
    return float(np.sqrt(np.mean(resid * resid))) if resid.size else 0.0


def brake_intervals(
    time_s: npt.ArrayLike, speed_mps: npt.ArrayLike, accel_mps2: npt.ArrayLike, figures: BrakeFigures,
    brake_time_s: npt.ArrayLike | None = None, mfdd_window_mps: tuple[float, float] | None = None,
) -> dict[str, tuple[float, float] | None]:
    """{stopping_distance_m, mfdd_mps2}: (lo, hi) each, None where fewer than 80 % of the draws give the figure;
    mfdd_window_mps: as brake_figures'. brake_time_s: the brake signal's sample times (old callers: its interval
    when onset_half_s is not set)."""
    t, v = np.asarray(time_s, dtype=float), np.asarray(speed_mps, dtype=float)
    sigma_v = speed_noise_mps(t, v)
    half = figures.onset_half_s
    if figures.onset_source == "brake signal" and half == 0.0 and brake_time_s is not None \
            and np.asarray(brake_time_s).size > 1:
        half = 0.5 * float(np.median(np.diff(np.asarray(brake_time_s, dtype=float))))
    sigma_onset = DECEL_ONSET_SIGMA_S if figures.onset_source == "deceleration" else 0.0
    dt = float(np.median(np.diff(t))) if t.size > 1 else 0.01
    n_corr = max(1, int(round(CORRELATION_S / max(dt, 1e-6))))
    rng = np.random.default_rng(SEED)
    got: dict[str, list[float]] = {"stopping_distance_m": [], "mfdd_mps2": []}
    for _ in range(DRAWS):
        noise = _moving_average(rng.standard_normal(t.size), n_corr)
        sd = float(np.std(noise))
        dv = noise * (sigma_v / sd) if sd > 0 else np.zeros_like(v)
        f = brake_figures(t, np.maximum(v + dv, 0.0), accel_mps2,
                          onset_s=figures.onset_s + float(rng.normal(0.0, sigma_onset)), mfdd_window_mps=mfdd_window_mps)
        if f is None:
            continue
        for k in got:
            x = getattr(f, k)
            if x is not None:
                got[k].append(float(x))
    out = {k: (float(np.percentile(x, 2.5)), float(np.percentile(x, 97.5))) if len(x) >= 0.8 * DRAWS else None
           for k, x in got.items()}
    return _widened(out, figures, half, lambda onset: brake_figures(t, v, accel_mps2, onset_s=onset,
                                                                           mfdd_window_mps=mfdd_window_mps)) \
        if half > 0.0 else out


def _widened(intervals: dict[str, tuple[float, float] | None], figures: BrakeFigures, half_s: float,
             at_onset: Callable[[float], BrakeFigures | None]) -> dict[str, tuple[float, float] | None]:
    """Each interval widened by how far its figure moves when the onset is at either end of onset ± half_s."""
    ends = [at_onset(figures.onset_s - half_s), at_onset(figures.onset_s + half_s)]
    out: dict[str, tuple[float, float] | None] = {}
    for k, iv in intervals.items():
        x = getattr(figures, k)
        moved = [getattr(f, k) for f in ends if f is not None]
        if iv is None or x is None or len(moved) < 2 or any(m is None for m in moved):
            out[k] = iv
            continue
        out[k] = (iv[0] - max(0.0, x - min(moved)), iv[1] + max(0.0, max(moved) - x))
    return out
