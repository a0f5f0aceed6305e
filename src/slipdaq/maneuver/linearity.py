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
import statistics
from collections.abc import Sequence
from dataclasses import dataclass

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


