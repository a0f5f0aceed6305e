"""Offline (two-pass) smoothing of GPS speed: a Rauch-Tung-Striebel (RTS) smoother on x = [v, a], white-noise jerk.

Model over each interval dt = t[k+1] - t[k] (the exact discretisation of a' = w, w white with spectral density q):
  x[k+1] = F x[k] + w[k],  F = [[1, dt], [0, 1]],  cov(w[k]) = Q = q * [[dt^3/3, dt^2/2], [dt^2/2, dt]]
  z[k]   = v[k] + e[k],    e[k] ~ N(0, sigma[k]^2)
Kalman filter forward (predict, update with z[k]: speed_model.py); RTS backward:
  C[k] = P[k|k] F' P[k+1|k]^-1,   x[k|n] = x[k|k] + C[k] (x[k+1|n] - x[k+1|k]).
Prior: x[0] ~ N([z0, (z1 - z0)/dt0], diag(PRIOR_SIGMA_SPEED_MPS^2, PRIOR_SIGMA_ACCEL_MPS2^2)), wide.
sigma: the receiver's stated accuracy where finite and > 0, else estimate_noise_mps (robust, from the data).
q: maximum of the innovations' log-likelihood (the innovations after each segment's first two fixes) over a log grid,
refined by golden section. Gaps longer than max_gap_s split the run into segments smoothed independently (one sigma
estimate and one q for the whole run).
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from slipdaq.compiled import kernel
from slipdaq.estimator.speed_model import predict, update_speed

MIN_NOISE_MPS = 0.005
"""Floor of the measurement sigma (estimated or stated): keeps the filter off a zero measurement variance."""
PRIOR_SIGMA_SPEED_MPS = 100.0
"""1-sigma width of the prior on a segment's first speed (centred on its first fix)."""
PRIOR_SIGMA_ACCEL_MPS2 = 100.0
"""1-sigma width of the prior on a segment's first acceleration (centred on the first finite difference)."""
JERK_PSD_GRID_M2PS5 = np.logspace(-3.0, 3.0, 25)
"""The grid of jerk spectral densities q (m^2/s^5) searched for the maximum likelihood; q stays within its ends."""
REFINE_TOL_DECADES = 0.01
"""The golden-section refinement around the best grid point stops when log10(q) is bracketed this closely."""
MAD_TO_SIGMA = 1.482602218505602
"""1 / Phi^-1(3/4): median(|e|) * MAD_TO_SIGMA = sigma for Gaussian e."""

_LOG_2PI = math.log(2.0 * math.pi)
_GOLDEN = (math.sqrt(5.0) - 1.0) / 2.0


@dataclass(frozen=True, eq=False)
class SmoothedSpeed:
    """The smoothed run, at the input times. eq=False: the fields are arrays (compare them with numpy)."""

    speed_mps: np.ndarray
    """Smoothed speed (float64, one per fix). Not clipped at 0: near a standstill it may dip a few mm/s below."""
    accel_mps2: np.ndarray
    """Smoothed acceleration (float64, one per fix)."""
    noise_mps: np.ndarray
    """The measurement sigma used for each fix (float64, one per fix): the stated accuracy where finite and > 0
    (floored at MIN_NOISE_MPS), else the run's estimate (estimate_noise_mps)."""
    jerk_psd: float
    """The jerk spectral density q (m^2/s^5) chosen by maximum likelihood; NaN when no segment has 3 fixes."""


def _check_inputs(time_s: np.ndarray, speed_mps: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    t = np.asarray(time_s, dtype=np.float64)
    z = np.asarray(speed_mps, dtype=np.float64)
    if t.ndim != 1 or z.ndim != 1 or t.shape != z.shape:
        raise ValueError(f"time_s and speed_mps must be 1-D arrays of the same length (got shapes {t.shape} and {z.shape})")
    if not np.all(np.isfinite(t)):
        raise ValueError("time_s must be finite")
    if not np.all(np.isfinite(z)):
        raise ValueError("speed_mps must be finite")
    if t.size > 1:
        bad = np.flatnonzero(np.diff(t) <= 0.0)
        if bad.size:
            i = int(bad[0]) + 1
            raise ValueError(f"time_s must be strictly increasing: time_s[{i}] = {t[i]!r} <= time_s[{i - 1}] = {t[i - 1]!r}")
    return t, z


def _noise_array(noise_mps: float | np.ndarray, n: int) -> np.ndarray:
    r = np.broadcast_to(np.asarray(noise_mps, dtype=np.float64), (n,))
    if not np.all(np.isfinite(r)) or np.any(r <= 0.0):
        raise ValueError("noise_mps must be finite and > 0")
    return r


def segment_bounds(time_s: np.ndarray, max_gap_s: float) -> list[tuple[int, int]]:
    """[start, stop) of each run of fixes whose consecutive intervals are all <= max_gap_s."""
    n = len(time_s)
    if n == 0:
        return []
    cuts = (np.flatnonzero(np.diff(time_s) > max_gap_s) + 1).tolist()
    starts = [0, *cuts]
    stops = [*cuts, n]
    return list(zip(starts, stops))


def estimate_noise_mps(time_s: np.ndarray, speed_mps: np.ndarray, max_gap_s: float = 1.0) -> float:
    """Robust sigma of the speed noise, from each interior fix's residual against the line through its neighbours:
      r[k] = z[k] - (w_prev z[k-1] + w_next z[k+1]),  w_prev = (t[k+1] - t[k]) / (t[k+1] - t[k-1]),  w_next = 1 - w_prev
      var(r[k]) = sigma^2 (1 + w_prev^2 + w_next^2)  for white noise, and r[k] = 0 for a constant acceleration;
      sigma = MAD_TO_SIGMA * median(|r[k]| / sqrt(1 + w_prev^2 + w_next^2)),  floored at MIN_NOISE_MPS.
    With even spacing r[k] = -d2[k]/2 (d2 the second difference), i.e. sigma = 1.4826 * median(|d2|) / sqrt(6).
    Only fixes whose both neighbours are within max_gap_s count; MIN_NOISE_MPS when there are none."""
    t, z = _check_inputs(time_s, speed_mps)
    if t.size < 3:
        return MIN_NOISE_MPS
    dt_prev = t[1:-1] - t[:-2]
    dt_next = t[2:] - t[1:-1]
    ok = (dt_prev <= max_gap_s) & (dt_next <= max_gap_s)
    if not np.any(ok):
        return MIN_NOISE_MPS
    w_prev = dt_next / (dt_prev + dt_next)
    w_next = 1.0 - w_prev
    r = z[1:-1] - (w_prev * z[:-2] + w_next * z[2:])
    scaled = np.abs(r[ok]) / np.sqrt(1.0 + w_prev[ok] ** 2 + w_next[ok] ** 2)
    return max(MIN_NOISE_MPS, MAD_TO_SIGMA * float(np.median(scaled)))


def _filter(t: np.ndarray, z: np.ndarray, var: np.ndarray, q: float, states: np.ndarray, keep: bool) -> float:
    """Kalman filter over one segment (len >= 2); returns the log-likelihood of the innovations k >= 2 (the first two
    are those of the prior's centre, ~0 with a huge variance, and carry no information about q). keep: each fix's
    predicted state into states[k, :5] and its filtered state into states[k, 5:] (v, a, c00, c01, c11)."""
    x = (z[0], (z[1] - z[0]) / (t[1] - t[0]), PRIOR_SIGMA_SPEED_MPS * PRIOR_SIGMA_SPEED_MPS, 0.0,
         PRIOR_SIGMA_ACCEL_MPS2 * PRIOR_SIGMA_ACCEL_MPS2)
    loglik = 0.0
    for k in range(len(t)):
        if k:
            x = predict(x, t[k] - t[k - 1], q)
        if keep:
            for j in range(5):
                states[k, j] = x[j]
        x, y, s = update_speed(x, z[k], var[k])
        if k >= 2:
            loglik -= 0.5 * (_LOG_2PI + math.log(s) + y * y / s)
        if keep:
            for j in range(5):
                states[k, 5 + j] = x[j]
    return loglik


filter_kernel = kernel(_filter, "float64(float64[:], float64[:], float64[:], float64, float64[:, :], boolean)",
                       uses=(predict, update_speed))
"""filter_kernel()(t, z, var, q, states, keep): see _filter."""
_NO_STATES = np.empty((0, 10))


def _forward(t: np.ndarray, z: np.ndarray, var: np.ndarray, q: float) -> float:
    """The innovations' log-likelihood of one segment (len >= 2) at q (_filter)."""
    return float(filter_kernel()(t, z, var, q, _NO_STATES, False))


def _backward(t: np.ndarray, states: np.ndarray, sv: np.ndarray, sa: np.ndarray) -> None:
    """RTS pass over _filter's states (predicted states[k, :5], filtered states[k, 5:]): the smoothed speed and
    acceleration into sv and sa."""
    n = len(t)
    for k in range(n):
        sv[k] = states[k, 5]
        sa[k] = states[k, 6]
    for k in range(n - 2, -1, -1):
        dt = t[k + 1] - t[k]
        fv, fa, f00, f01, f11 = states[k, 5], states[k, 6], states[k, 7], states[k, 8], states[k, 9]
        pv, pa, m00, m01, m11 = states[k + 1, 0], states[k + 1, 1], states[k + 1, 2], states[k + 1, 3], states[k + 1, 4]
        # G = P[k|k] F'
        g00 = f00 + dt * f01
        g01 = f01
        g10 = f01 + dt * f11
        g11 = f11
        det = m00 * m11 - m01 * m01
        i00 = m11 / det
        i01 = -m01 / det
        i11 = m00 / det
        dv = sv[k + 1] - pv
        da = sa[k + 1] - pa
        sv[k] = fv + (g00 * i00 + g01 * i01) * dv + (g00 * i01 + g01 * i11) * da
        sa[k] = fa + (g10 * i00 + g11 * i01) * dv + (g10 * i01 + g11 * i11) * da


backward_kernel = kernel(_backward, "void(float64[:], float64[:, :], float64[:], float64[:])")
"""backward_kernel()(t, states, sv, sa): see _backward."""


def _short(t: np.ndarray, z: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """A segment of 0, 1 or 2 fixes: the speed as given; acceleration 0 (1 fix) or the finite difference (2 fixes)."""
    accel = np.zeros(len(t))
    if len(t) == 2:
        accel[:] = (z[1] - z[0]) / (t[1] - t[0])
    return z.copy(), accel


def rts(time_s: np.ndarray, speed_mps: np.ndarray, noise_mps: float | np.ndarray,
        jerk_psd: float) -> tuple[np.ndarray, np.ndarray]:
    """One segment (no gap splitting) smoothed with the given sigma (scalar or per fix) and q: (speed_mps, accel_mps2).
    Fewer than 3 fixes: the speed as given and acceleration 0 (1 fix) or the finite difference (2 fixes)."""
    t, z = _check_inputs(time_s, speed_mps)
    r = _noise_array(noise_mps, len(t))
    if len(t) < 3:
        return _short(t, z)
    if not (math.isfinite(jerk_psd) and jerk_psd > 0.0):
        raise ValueError("jerk_psd must be finite and > 0")
    states = np.empty((len(t), 10))
    filter_kernel()(t, z, r * r, float(jerk_psd), states, True)
    sv, sa = np.empty(len(t)), np.empty(len(t))
    backward_kernel()(t, states, sv, sa)
    return sv, sa


def log_likelihood(time_s: np.ndarray, speed_mps: np.ndarray, noise_mps: float | np.ndarray, jerk_psd: float) -> float:
    """One segment's innovations log-likelihood at q = jerk_psd: log p(z[2:] | z[0], z[1]) (0 with fewer than 3 fixes)."""
    t, z = _check_inputs(time_s, speed_mps)
    r = _noise_array(noise_mps, len(t))
    if len(t) < 3:
        return 0.0
    return _forward(t, z, r * r, float(jerk_psd))


def smooth_segments(time_s: np.ndarray, speed_mps: np.ndarray, noise_mps: float | np.ndarray, jerk_psd: float,
                    max_gap_s: float = 1.0) -> tuple[np.ndarray, np.ndarray]:
    """rts on each segment (gaps > max_gap_s split), with the given sigma and q: (speed_mps, accel_mps2)."""
    t, z = _check_inputs(time_s, speed_mps)
    r = _noise_array(noise_mps, len(t))
    speed = np.empty(len(t))
    accel = np.empty(len(t))
    for i, j in segment_bounds(t, max_gap_s):
        speed[i:j], accel[i:j] = rts(t[i:j], z[i:j], r[i:j], jerk_psd)
    return speed, accel


def _golden_max(f: Callable[[float], float], lo: float, hi: float, tol: float) -> tuple[float, float]:
    """(x, f(x)) at the maximum of a unimodal f on [lo, hi], bracketed to tol."""
    x1 = hi - _GOLDEN * (hi - lo)
    x2 = lo + _GOLDEN * (hi - lo)
    f1 = f(x1)
    f2 = f(x2)
    while hi - lo > tol:
        if f1 >= f2:
            hi, x2, f2 = x2, x1, f1
            x1 = hi - _GOLDEN * (hi - lo)
            f1 = f(x1)
        else:
            lo, x1, f1 = x1, x2, f2
            x2 = lo + _GOLDEN * (hi - lo)
            f2 = f(x2)
    return (x1, f1) if f1 >= f2 else (x2, f2)


def smooth_speed(time_s: np.ndarray, speed_mps: np.ndarray, accuracy_mps: np.ndarray | None = None,
                 max_gap_s: float = 1.0) -> SmoothedSpeed:
    """Smooth a whole run's GPS speed (offline: uses future fixes). See the module docstring for the model.

    time_s: fix times, strictly increasing (s); speed_mps: GPS ground speed; accuracy_mps: per-fix 1-sigma speed
    accuracy (NaN where not stated) or None; max_gap_s: intervals longer than this split the run (never bridged)."""
    t, z = _check_inputs(time_s, speed_mps)
    if not (math.isfinite(max_gap_s) and max_gap_s > 0.0):
        raise ValueError(f"max_gap_s must be finite and > 0 (got {max_gap_s!r})")
    n = len(t)
    stated = np.full(n, np.nan)
    if accuracy_mps is not None:
        acc = np.asarray(accuracy_mps, dtype=np.float64)
        if acc.shape != t.shape:
            raise ValueError(f"accuracy_mps must have the shape of time_s (got {acc.shape}, expected {t.shape})")
        stated = np.where(np.isfinite(acc) & (acc > 0.0), acc, np.nan)
    have = np.isfinite(stated)
    noise = np.maximum(stated, MIN_NOISE_MPS)
    if not np.all(have):
        noise[~have] = estimate_noise_mps(t, z, max_gap_s)

    segments = [(i, j) for i, j in segment_bounds(t, max_gap_s) if j - i >= 3]
    if not segments:
        speed, accel = smooth_segments(t, z, noise, 1.0, max_gap_s)
        return SmoothedSpeed(speed, accel, noise, math.nan)

    var = noise**2
    data = [(t[i:j], z[i:j], var[i:j]) for i, j in segments]

    def loglik(log10_q: float) -> float:
        q = 10.0**log10_q
        return sum(_forward(ts, zs, vs, q) for ts, zs, vs in data)

    grid = np.log10(JERK_PSD_GRID_M2PS5)
    values = [loglik(float(x)) for x in grid]
    best = int(np.argmax(values))
    lo = float(grid[max(best - 1, 0)])
    hi = float(grid[min(best + 1, len(grid) - 1)])
    x, fx = _golden_max(loglik, lo, hi, REFINE_TOL_DECADES)
    jerk_psd = 10.0**x if fx > values[best] else float(JERK_PSD_GRID_M2PS5[best])

    speed, accel = smooth_segments(t, z, noise, jerk_psd, max_gap_s)
    return SmoothedSpeed(speed, accel, noise, jerk_psd)
