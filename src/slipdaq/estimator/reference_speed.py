"""A non-causal reference speed for a second pass: GPS speed with its noise smoothed away using the free-rolling
wheels' shape.

The GPS speed alone, smoothed (smoother.py), keeps much of its noise where the speed changes fast: the smoother must
follow every step of the acceleration. The non-driven wheels' speed r0 * omega has almost no noise and follows every
step, but is off by their own slip (about 0 while they roll freely, a few % when braked). So the difference
  d(t) = v_gps(t) - r0 * omega_ref(t)
is smooth (their slip times the speed) plus the GPS noise, and is smoothed with the same RTS smoother (its jerk
density, chosen by maximum likelihood, is then far lower); the reference speed at each fix is
  v(t_k) = r0 * omega_ref(t_k) + d_smoothed(t_k).
Its low frequencies are the GPS's (the slip of the reference wheels stays measured); its high frequencies the wheels'.
Where the reference wheels have no samples around a fix, or with every wheel driven, the GPS speed is smoothed alone.
"""

from __future__ import annotations

import numpy as np

from slipdaq.estimator.smoother import smooth_speed
from slipdaq.estimator.wheel_revolutions import TWO_PI

SPEED_HALF_WINDOW_S = 0.2
"""A wheel's speed at t: the slope at t of a parabola fitted to its revolutions from t - 0.2 s to t + 0.2 s (about 40
samples at 100 Hz: the count's quantisation, 1/ppr of a revolution, and the timestamps' jitter average out; the
parabola follows a steady acceleration)."""


def wheel_speed_mps(times_s: np.ndarray, sample_times_s: np.ndarray, revolutions: np.ndarray,
                    radius_m: float) -> np.ndarray:
    """r0 * omega at times_s from one wheel's samples (NaN without 5 samples on each side within the window)."""
    h = SPEED_HALF_WINDOW_S
    out = np.full(len(times_s), np.nan)
    lo = np.searchsorted(sample_times_s, times_s - h)
    mid = np.searchsorted(sample_times_s, times_s)
    hi = np.searchsorted(sample_times_s, times_s + h, side="right")
    for k, (a, m, b) in enumerate(zip(lo.tolist(), mid.tolist(), hi.tolist())):
        if m - a < 5 or b - m < 5:
            continue
        out[k] = radius_m * TWO_PI * _parabola_slope(sample_times_s[a:b] - times_s[k], revolutions[a:b])
    return out


def _parabola_slope(x: np.ndarray, y: np.ndarray) -> float:
    """The linear coefficient of the least-squares parabola through (x, y): numpy.polynomial.polynomial.polyfit(x, y,
    2)[1], computed as polyfit computes it (the same Vandermonde rows, column scaling, lstsq and rcond, so the same
    bits) without its checks and its general degree."""
    x = x + 0.0
    v = np.empty((3, len(x)))
    v[0] = x * 0 + 1
    v[1] = x
    v[2] = v[1] * x
    scl = np.sqrt(np.square(v).sum(1))
    scl[scl == 0] = 1
    c = np.linalg.lstsq(v.T / scl, y + 0.0, len(x) * np.finfo(x.dtype).eps)[0]
    return float(c[1] / scl[1])


def reference_speed_mps(fix_times_s: np.ndarray, gps_speed_mps: np.ndarray, wheel_speed: np.ndarray | None,
                        accuracy_mps: np.ndarray | None = None, max_gap_s: float = 1.0) -> np.ndarray:
    """The fixes' speeds, smoothed over the run: around the free-rolling wheels' speed (wheel_speed: their mean r0 *
    omega at the fix times, NaN where unknown) where it is known, the GPS speed alone elsewhere."""
    out = smooth_speed(fix_times_s, gps_speed_mps, accuracy_mps, max_gap_s=max_gap_s).speed_mps.copy()
    if wheel_speed is None:
        return out
    known = np.isfinite(wheel_speed)
    if known.sum() < 3:
        return out
    t, w = fix_times_s[known], wheel_speed[known]
    diff = gps_speed_mps[known] - w
    acc = accuracy_mps[known] if accuracy_mps is not None else None
    smooth = np.empty_like(diff)
    for a, b in _phases(t, w):  # each phase with its own jerk density: d is flat while the wheels roll freely
        smooth[a:b] = smooth_speed(t[a:b], diff[a:b], None if acc is None else acc[a:b],
                                   max_gap_s=max_gap_s).speed_mps if b - a >= 3 else diff[a:b]
    out[known] = w + smooth
    return out


BRAKING_MPS2 = -0.3
"""The reference wheels decelerate faster than this: they are braked (and slip)."""
PHASE_MARGIN_S = 0.5


def _phases(t: np.ndarray, wheel_speed: np.ndarray) -> list[tuple[int, int]]:
    """Index ranges of the fixes in turn while the reference wheels roll freely and while they are braked (their
    deceleration beyond BRAKING_MPS2, widened by PHASE_MARGIN_S on each side)."""
    if len(t) < 3:
        return [(0, len(t))]
    braked_t = t[np.gradient(wheel_speed, t) < BRAKING_MPS2]
    # a braked fix within PHASE_MARGIN_S on either side (one search per fix, not one pass per braked fix)
    near = np.searchsorted(braked_t, t + PHASE_MARGIN_S, "right") > np.searchsorted(braked_t, t - PHASE_MARGIN_S, "left")
    edges = np.flatnonzero(np.diff(near.astype(np.int8))) + 1
    bounds = [0, *edges.tolist(), len(t)]
    return list(zip(bounds[:-1], bounds[1:]))
