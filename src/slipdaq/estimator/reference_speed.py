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

from slipdaq.compiled import kernel
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
    times = np.ascontiguousarray(times_s, dtype=np.float64)
    samples = np.ascontiguousarray(sample_times_s, dtype=np.float64)
    lo = np.searchsorted(samples, times - h)
    mid = np.searchsorted(samples, times)
    hi = np.searchsorted(samples, times + h, side="right")
    slopes = np.full(len(times), np.nan)
    parabola_slopes()(samples, np.ascontiguousarray(revolutions, dtype=np.float64), times, lo, mid, hi, h, slopes)
    return radius_m * TWO_PI * slopes


def _parabola_slopes(x: np.ndarray, y: np.ndarray, at: np.ndarray, lo: np.ndarray, mid: np.ndarray, hi: np.ndarray,
                     h: float, out: np.ndarray) -> None:
    """out[k]: the slope at at[k] of the least-squares parabola through the samples lo[k]:hi[k] (those within h of it),
    where mid[k] - lo[k] >= 5 and hi[k] - mid[k] >= 5 (out[k] left as it is elsewhere). The fit is taken in
    u = (x - at[k]) / h, of y - y[mid[k]] (no digits lost to the revolutions counted before the window): the normal
    equations G c = r, G[i][j] = sum u^(i+j), r[i] = sum u^i (y - y[mid]), solved by Cramer's rule; slope = c[1] / h.
    It is the same parabola as numpy's polyfit(x - at[k], y, 2) (Vandermonde, lstsq), rounded differently (u in
    [-1, 1]: G is well conditioned): over 300 s of 1 kHz samples the slopes differ by about 1e-12 rev/s, polyfit's
    rounding of the revolutions counted before the window."""
    for k in range(len(at)):
        a, m, b = lo[k], mid[k], hi[k]
        if m - a < 5 or b - m < 5:
            continue
        y0 = y[m]
        s0 = s1 = s2 = s3 = s4 = r0 = r1 = r2 = 0.0
        for i in range(a, b):
            u = (x[i] - at[k]) / h
            d = y[i] - y0
            u2 = u * u
            s0 += 1.0
            s1 += u
            s2 += u2
            s3 += u2 * u
            s4 += u2 * u2
            r0 += d
            r1 += u * d
            r2 += u2 * d
        # Cramer's rule for c[1]: det(G with column 1 replaced by r) / det(G), G symmetric
        c00 = s2 * s4 - s3 * s3
        c01 = s1 * s4 - s2 * s3
        c02 = s1 * s3 - s2 * s2
        det = s0 * c00 - s1 * c01 + s2 * c02
        num = s0 * (r1 * s4 - s3 * r2) - r0 * c01 + s2 * (s1 * r2 - s2 * r1)
        out[k] = num / det / h


parabola_slopes = kernel(_parabola_slopes, "void(float64[:], float64[:], float64[:], int64[:], int64[:], int64[:], "
                                           "float64, float64[:])")
"""parabola_slopes()(x, y, at, lo, mid, hi, h, out): see _parabola_slopes (wheel_speed_mps)."""


def reference_speed_mps(fix_times_s: np.ndarray, gps_speed_mps: np.ndarray, wheel_speed: np.ndarray | None,
                        accuracy_mps: np.ndarray | None = None, max_gap_s: float = 1.0) -> np.ndarray:
    """The fixes' speeds, smoothed over the run: around the free-rolling wheels' speed (wheel_speed: their mean r0 *
    omega at the fix times, NaN where unknown) where it is known, the GPS speed alone elsewhere."""
    known = np.isfinite(wheel_speed) if wheel_speed is not None else np.zeros(len(fix_times_s), dtype=bool)
    out = np.empty(len(fix_times_s))
    if not known.all():  # the GPS smoothed alone: the fixes without the wheels' speed keep it (all, below 3 with it)
        out[:] = smooth_speed(fix_times_s, gps_speed_mps, accuracy_mps, max_gap_s=max_gap_s).speed_mps
    if wheel_speed is None or known.sum() < 3:
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
