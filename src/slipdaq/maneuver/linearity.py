"""The tire's linear region in one wheel's force–slip points of a maneuver. Pure: sequences in, dataclasses out.

Linear region and the end of linearity (per wheel and maneuver), the exact rule
    1. Points: rows with slip s and tire force Fx (`force_W_n`) both defined, |s| >= S_MIN and Fx·s > 0
       (force and slip of the same sign; a wheel carrying no force has no points).
       S_MIN, S_MAX are the log's `estimator.cx_slip_min`, `cx_slip_max` (defaults 0.005, 0.10).
    2. Line: slip on force, s = s0 + Fx/Cx_line, least squares over the maneuver's windows whose force has the
       maneuver's sign (any slip) and the cruise windows known when it closed, the latest 1000 before it
       (detector.ANCHOR_WINDOWS; they anchor Fx = 0; without: step 2's fallback), both with |s| <= S_MAX. The
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

"""

from __future__ import annotations

import math
import operator
import statistics
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from slipdaq.compiled import kernel
from slipdaq.config import EstimatorConfig

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


SQUARE = 2.0
"""The kernels' power of a residual, an argument so that numba calls libm's pow as Python's ** does (with the
constant 2 it multiplies, which rounds differently for about 1 value in 1,200)."""


def _line_sums(s: np.ndarray, f: np.ndarray, w: np.ndarray, square: float, out: np.ndarray) -> None:
    """out = (Σw, the weighted means of f and s, Sff, Sfs, Sss: the weighted sums of squares and products about
    them) of the points (s, f) with weights w (at least one), each sum added left to right as Python's sum()."""
    sw = wf = ws = 0.0
    for i in range(s.size):
        sw += w[i]
        wf += w[i] * f[i]
        ws += w[i] * s[i]
    f_mean = wf / sw
    s_mean = ws / sw
    sff = sfs = sss = 0.0
    for i in range(s.size):
        sff += w[i] * math.pow(f[i] - f_mean, square)
        sfs += w[i] * (f[i] - f_mean) * (s[i] - s_mean)
        sss += w[i] * math.pow(s[i] - s_mean, square)
    out[0], out[1], out[2], out[3], out[4], out[5] = sw, f_mean, s_mean, sff, sfs, sss


line_sums = kernel(_line_sums, "void(float64[:], float64[:], float64[:], float64, float64[:])")


def _line_rss(s: np.ndarray, f: np.ndarray, w: np.ndarray, a: float, b: float, square: float) -> float:
    """Σ w·(s − a − b·f)², left to right."""
    rss = 0.0
    for i in range(s.size):
        rss += w[i] * math.pow(s[i] - a - b * f[i], square)
    return rss


line_rss = kernel(_line_rss, "float64(float64[:], float64[:], float64[:], float64, float64, float64)")


def _origin_sums(s: np.ndarray, f: np.ndarray, square: float, out: np.ndarray) -> None:
    """out = (Σs², Cx = Σs·f / Σs², Σ(f − Cx·s)²), left to right; Cx and the residual only where Σs² > 0."""
    sss = ssf = 0.0
    for i in range(s.size):
        sss += s[i] * s[i]
        ssf += s[i] * f[i]
    out[0] = sss
    if sss <= 0:
        return
    cx = ssf / sss
    resid = 0.0
    for i in range(s.size):
        resid += math.pow(f[i] - cx * s[i], square)
    out[1], out[2] = cx, resid


origin_sums = kernel(_origin_sums, "void(float64[:], float64[:], float64, float64[:])")


def _speed_weights(v: np.ndarray, reference_mps: float, square: float, out: np.ndarray) -> None:
    """out = (max(v, 0.5) / max(reference_mps, 0.5))² for each speed, as Python's max() and ** take them."""
    ref = 0.5 if 0.5 > reference_mps else reference_mps
    for i in range(v.size):
        x = 0.5 if 0.5 > v[i] else v[i]
        out[i] = math.pow(x / ref, square)


speed_weights_kernel = kernel(_speed_weights, "void(float64[:], float64, float64, float64[:])")


def _variance(x: np.ndarray) -> float:
    """statistics.variance of the values (at least two), the same float: the exact sum of squared deviations over
    n − 1, rounded once (its formula, in integers: the values scaled by one power of two to integers)."""
    _, exp = np.frexp(x)
    low = int(exp.min()) - 53  # x = m·2^e with |m| < 1 of 53 bits: x·2^-low is an integer
    if not np.isfinite(x).all() or int(exp.max()) - low > 1023:
        return float(statistics.variance(x.tolist()))
    ints = [int(v) for v in np.ldexp(x, -low).tolist()]
    n = len(ints)
    num = n * sum(map(operator.mul, ints, ints)) - sum(ints) ** 2
    den = n * (n - 1)
    return num / (den << -2 * low) if low < 0 else (num << 2 * low) / den


def _array(values: Sequence[float | None] | np.ndarray) -> np.ndarray:
    return np.ascontiguousarray(values, dtype=np.float64)


def fit_through_origin(points: Sequence[tuple[float, float]]) -> LineFit | None:
    """Least squares Fx = Cx·s through the origin; None for fewer than 2 points."""
    pairs = np.array(points, dtype=np.float64).reshape(-1, 2)
    return _through_origin(_array(pairs[:, 0]), _array(pairs[:, 1]))


def _through_origin(s: np.ndarray, f: np.ndarray) -> LineFit | None:
    if s.size < 2:
        return None
    out = np.zeros(3)
    origin_sums()(s, f, SQUARE, out)
    sss, cx, resid = out.tolist()
    if sss <= 0:
        return None
    stderr = math.sqrt(resid / (s.size - 1) / sss)
    return LineFit(cx, stderr, s.size)


MIN_SLOPE_T = 3.0
"""The slip-on-force slope must be this many standard errors above 0."""


def fit_slip_on_force(slip: Sequence[float] | np.ndarray, force: Sequence[float] | np.ndarray,
                      noise: tuple[float, float] | None = None,
                      weights: Sequence[float] | np.ndarray | None = None) -> LineFit | None:
    """s = s0 + Fx/Cx, slip the regressand; None for fewer than 3 points or no positive slope.

    weights: per point (default 1): the slip's noise variance is var_s/w (a GPS speed noise in m/s makes a slip noise
    in proportion to 1/V, so w ~ V^2). noise: (var_s, var_F), the variances of the slip's (at weight 1) and the
    force's own noise: a Deming (errors-in-variables) fit with their ratio lambda = var_s/var_F, which noise in Fx
    does not flatten (least squares of s on Fx shrinks the slope by var(Fx true)/var(Fx), and so raises Cx):
        b = (Sss - lambda Sff + sqrt((Sss - lambda Sff)^2 + 4 lambda Sfs^2)) / (2 Sfs)
    (Sff, Sss, Sfs: weighted sums of squares and products about the weighted means). Without noise: weighted least
    squares of s on Fx."""
    s, f = _array(slip), _array(force)
    n = s.size
    if n < 3:
        return None
    w = np.ones(n) if weights is None else _array(weights)
    sums = np.empty(6)
    line_sums()(s, f, w, SQUARE, sums)
    _, f_mean, s_mean, sff, sfs, sss = sums.tolist()
    if sff <= 0:
        return None
    b = sfs / sff
    method = "slip on force"
    if noise is not None and noise[0] > 0 and noise[1] > 0 and sfs > 0:
        lam = noise[0] / noise[1]
        d = sss - lam * sff
        b = (d + math.sqrt(d * d + 4.0 * lam * sfs * sfs)) / (2.0 * sfs)
        method = "errors-in-variables"
    a = s_mean - b * f_mean
    resid = line_rss()(s, f, w, a, b, SQUARE)
    se_b = math.sqrt(resid / (n - 2) / sff)
    if b <= MIN_SLOPE_T * se_b:  # no force spread beyond the noise (one cluster): no slope to take
        return None
    return LineFit(1.0 / b, se_b / (b * b), n, a, method)


MIN_NOISE_ANCHORS = 10
"""The cruise windows give the slip's and the force's noise (their spread about their means) from this many on."""


def anchor_noise(slip: Sequence[float] | np.ndarray, force: Sequence[float] | np.ndarray,
                 weights: Sequence[float] | np.ndarray | None = None) -> tuple[float, float] | None:
    """(var_s at weight 1, var_F) of the cruise windows: there the true force hardly changes, so their spread is the
    noise of each (an upper bound: a drift of the true value adds to it); None with fewer than MIN_NOISE_ANCHORS."""
    s, f = _array(slip), _array(force)
    n = s.size
    if n < MIN_NOISE_ANCHORS:
        return None
    sums = np.empty(6)
    line_sums()(s, f, np.ones(n) if weights is None else _array(weights), SQUARE, sums)
    return float(sums[5]) / (n - 1), _variance(f)


def speed_weights(speeds: Sequence[float] | np.ndarray, reference_mps: float) -> np.ndarray:
    """(V/V_ref)^2: the inverse of a window's slip noise variance (GPS speed noise / V), relative to V_ref."""
    v = _array(speeds)
    out = np.empty(v.size)
    speed_weights_kernel()(v, float(reference_mps), SQUARE, out)
    return out


def _defined(pairs: Sequence[tuple[float | None, float | None]], speeds: Sequence[float | None]
             ) -> tuple[np.ndarray, np.ndarray, tuple[float | None, ...]]:
    """(s, f, speed) of the pairs with both defined, the speeds as given."""
    rows = [(s, f, v) for (s, f), v in zip(pairs, speeds) if s is not None and f is not None]
    if not rows:
        return np.empty(0), np.empty(0), ()
    s, f, v = zip(*rows)
    return _array(s), _array(f), v


def analyse_linearity(
    slips: Sequence[float | None], forces: Sequence[float | None], rule: LinearityRule = LinearityRule(),
    anchors: Sequence[tuple[float | None, float | None]] = (), speeds: Sequence[float | None] | None = None,
    anchor_speeds: Sequence[float | None] | None = None,
) -> Linearity:
    """The linear region of one wheel's force–slip points (rule in the module docstring); anchors: (slip, force) of
    the log's cruise windows; speeds, anchor_speeds: the windows' speeds (the line's weights, speed_weights)."""
    spd = list(speeds) if speeds is not None else [None] * len(slips)
    aspd = list(anchor_speeds) if anchor_speeds is not None else [None] * len(anchors)
    pairs = list(zip(slips, forces))
    # (slip, force, speed) of the windows and the anchors; the speed 1.0 for all when some is missing (unweighted)
    b_s, b_f, b_spd = _defined(pairs, spd)
    a_s, a_f, a_spd = _defined(anchors, aspd)
    weighted = None not in b_spd and None not in a_spd
    b_v = _array(b_spd) if weighted else np.ones(b_s.size)
    a_v = _array(a_spd) if weighted else np.ones(a_s.size)
    sign = 1.0 if sum(b_f.tolist()) >= 0 else -1.0
    both = np.array(pairs, dtype=np.float64).reshape(-1, 2)  # None: NaN, which no comparison keeps
    s_all, f_all = both[:, 0], both[:, 1]
    with np.errstate(invalid="ignore"):
        keep = (np.abs(s_all) >= rule.slip_min) & (s_all * f_all > 0)
    order = np.flatnonzero(keep)
    order = order[np.argsort(np.abs(s_all[order]), kind="stable")]
    p_s, p_f = s_all[order], f_all[order]
    p_abs = np.abs(p_s)
    if not p_s.size:
        return Linearity(0, None)
    # bins by |s|: contiguous runs of the points sorted by |s|; kept: (index, start, stop) of the full ones
    keys = np.floor(p_abs / rule.bin_width)
    starts = [0, *(np.flatnonzero(np.diff(keys)) + 1).tolist(), p_s.size]
    kept = [(int(keys[a]), a, b) for a, b in zip(starts, starts[1:]) if b - a >= rule.min_bin_points]
    bin_f = [statistics.median(np.abs(p_f[a:b]).tolist()) for _, a, b in kept]
    bin_s = [statistics.median(p_abs[a:b].tolist()) for _, a, b in kept]

    fit_max = rule.slip_max
    line: LineFit | None = None
    end: tuple[int, int, int] | None = None
    for _ in range(rule.max_refits):
        n_fit = int(np.searchsorted(p_abs, fit_max, side="right"))
        if n_fit < rule.min_fit_points:
            break
        line = _line_of(b_s, b_f, b_v, a_s, a_f, a_v, sign, fit_max) if a_s.size else None
        line = line or _through_origin(p_s[:n_fit], p_f[:n_fit])
        if line is None:
            break
        below = [fb < (1.0 - rule.tolerance) * abs(line.force_n(sign * sb)) for fb, sb in zip(bin_f, bin_s)]
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
        if np.count_nonzero(p_abs < edge) < rule.min_fit_points:
            break
        fit_max = math.nextafter(edge, 0.0)
    if line is None:
        return Linearity(p_s.size, None)
    end_slip = end_force = None
    linear = p_s.size
    if end is not None:
        linear = int(np.count_nonzero(p_abs < end[0] * rule.bin_width))
        _, a, b = end
        sign = 1.0 if sum(p_s[a:b].tolist()) > 0 else -1.0
        end_slip = sign * statistics.median(p_abs[a:b].tolist())
        end_force = sign * statistics.median(np.abs(p_f[a:b]).tolist())
    # the point of largest |Fx| among the first `linear` (sorted by |s|: those below the end's edge); the first such
    peak = int(np.argmax(np.abs(p_f[:linear]))) if linear else None
    return Linearity(
        p_s.size, line, end_slip, end_force,
        float(p_f[peak]) if peak is not None else None, float(p_s[peak]) if peak is not None else None,
    )


def _line_of(b_s: np.ndarray, b_f: np.ndarray, b_v: np.ndarray, a_s: np.ndarray, a_f: np.ndarray, a_v: np.ndarray,
             sign: float, fit_max: float) -> LineFit | None:
    """Rule step 2's slip-on-force line: the maneuver's windows with its force's sign and the cruise windows, both
    with |s| <= fit_max, weighted by speed about the cruise windows' median speed (1.0 without them)."""
    with np.errstate(invalid="ignore"):
        ka = np.abs(a_s) <= fit_max
        kb = (b_f * sign > 0) & (np.abs(b_s) <= fit_max)
    ks, kf, kv = a_s[ka], a_f[ka], a_v[ka]
    v_ref = statistics.median(kv.tolist()) if kv.size else 1.0
    return fit_slip_on_force(np.concatenate((b_s[kb], ks)), np.concatenate((b_f[kb], kf)),
                             anchor_noise(ks, kf, speed_weights(kv, v_ref)),
                             speed_weights(np.concatenate((b_v[kb], kv)), v_ref))


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


