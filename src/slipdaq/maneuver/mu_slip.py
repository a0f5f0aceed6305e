"""The tire's mu–slip curve over the whole slip range. Pure: arrays in, dataclasses out.

Normal load per wheel (static axle load plus longitudinal load transfer, a < 0 braking loads the front):
    Fz_front_axle = M·g·share − M·a·h/L,   Fz_rear_axle = M·g·(1 − share) + M·a·h/L,   each wheel half its axle.
Friction coefficient: mu = Fx_tire / Fz_tire.

Burckhardt model (Burckhardt 1993; Kiencke & Nielsen, Automotive Control Systems, ch. 7):
    mu(s) = sign(s)·(c1·(1 − exp(−c2·|s|)) − c3·|s|),   c1, c2, c3 >= 0,
    initial slope mu'(0) = c1·c2 − c3,   peak at s* = ln(c1·c2/c3)/c2 (when c3 > 0 and c1·c2 > c3).
Fitted by linear least squares in (c1, c3) for every c2 of a log-spaced grid, then a finer grid around the best;
with a peak in the data, refitted on the points up to PEAK_WINDOW·s* (fit_mu_slip).
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

from slipdaq import WHEELS
from slipdaq.estimator.force import G_MPS2

MIN_POINTS = 20
"""A fit needs at least this many finite (slip, mu) points."""
MIN_SLIP_SPAN = 0.01
"""... spread over at least this much slip (max |s| − min |s|, fraction)."""
OPPOSITE_SLIP_MAX = 0.01
"""Points whose slip has the other sign than the maneuver's by more than this are dropped (noise about s = 0 is kept)."""
PEAK_MARGIN = 1.15
"""The peak counts as observed only with points beyond PEAK_MARGIN·s* ..."""
MIN_PEAK_REGION_POINTS = 10
"""... and with this many points within PEAK_REGION of s* (a wheel that locks passes its peak in a few hundredths of
a second: two or three high-rate points there do not place it; an ABS cycles around it)."""
PEAK_REGION = (0.75, 1.25)
MIN_PEAK_SIDE_POINTS = 5
"""... at least this many (and at least 5 % of the points) beyond it, and at least this many below s*."""
PEAK_WINDOW = 1.6
"""With a peak observed, the fit is repeated on the points with |s| <= PEAK_WINDOW·s* (the range ABS cycles
over, 0.5–1.6·s*): the sliding branch up to lock (|s| -> 1) bends a 3-parameter curve and shifts its peak ..."""
PEAK_WINDOW_ITERATIONS = 5
"""... at most this many times."""
C2_GRID = np.geomspace(1.0, 200.0, 200)
"""Coarse grid of c2 (1/slip); the fit refines between the best value's neighbours."""
LINEARITY_TOLERANCE = 0.10
"""End of linearity: where the fitted mu falls this fraction below its initial linear slope."""

FloatArray = npt.NDArray[np.float64]


def normal_loads_n(
    wheel: str, accel_mps2: npt.ArrayLike, mass_kg: float, front_axle_load_share: float,
    cg_height_m: float, wheelbase_m: float,
) -> FloatArray:
    """Fz of one wheel ("FL", "FR", "RL", "RR") per acceleration sample: half its axle's
    M·g·share ∓ M·a·h/L (front −, rear +; a < 0 braking loads the front)."""
    if wheel not in WHEELS:
        raise ValueError(f"unknown wheel {wheel!r} (one of {', '.join(WHEELS)})")
    if wheelbase_m <= 0:
        raise ValueError("wheelbase_m must be > 0")
    a = np.asarray(accel_mps2, dtype=float)
    transfer = mass_kg * a * cg_height_m / wheelbase_m
    if wheel[0] == "F":
        axle = mass_kg * G_MPS2 * front_axle_load_share - transfer
    else:
        axle = mass_kg * G_MPS2 * (1.0 - front_axle_load_share) + transfer
    return np.asarray(0.5 * axle, dtype=float)


def mu_from_force(force_n: npt.ArrayLike, fz_n: npt.ArrayLike) -> FloatArray:
    """mu = Fx/Fz elementwise; NaN where Fz <= 0 or either is not finite."""
    f = np.asarray(force_n, dtype=float)
    z = np.asarray(fz_n, dtype=float)
    f, z = np.broadcast_arrays(f, z)
    ok = np.isfinite(f) & np.isfinite(z) & (z > 0)
    out = np.full(f.shape, np.nan)
    np.divide(f, z, out=out, where=ok)
    return out


def _burckhardt(x: FloatArray, c1: float, c2: float, c3: float) -> FloatArray:
    """The one-sided curve c1·(1 − exp(−c2·x)) − c3·x (x = |s|)."""
    return np.asarray(c1 * -np.expm1(-c2 * x) - c3 * x, dtype=float)


@dataclass(frozen=True)
class MuSlipFit:
    """A fitted Burckhardt curve (module docstring). Slips are fractions; `slip_sign` is −1 for braking data.

    mu_peak / slip_at_mu_peak (a positive magnitude) are None unless `peak_observed`: points from the linear
    region alone do not identify a peak (any c3 fits them about equally well, so s* is an extrapolation)."""

    c1: float
    c2: float
    c3: float
    mu_peak: float | None
    slip_at_mu_peak: float | None
    rms_residual: float
    n_points: int
    peak_observed: bool
    slip_sign: float
    """+1 driving, −1 braking: the sign of the fitted points' slip."""
    max_abs_slip: float
    """The largest |s| among the fitted points (the curve is an extrapolation beyond it)."""
    points_beyond_window: int = 0
    """Points beyond PEAK_WINDOW·s* left out of the final fit (0: every point fitted)."""
    model: str = "burckhardt"
    """'burckhardt', or 'magic formula' (mu_joint: then c1, c2, c3 hold its B, C, D)."""
    method: str = "hydraulic split"
    """Where each point's force came from: 'hydraulic split' (M·a split as the estimator splits it), 'joint shared' or
    'joint per axle' (the curve fitted to the total force over every wheel's slip, mu_joint)."""
    flag: str | None = None
    """Why mu_peak is not given although there is a curve (mu_flag): 'peak not passed', 'mu above MU_MAX', 'split
    exceeds the load', 'not determined' (its 95 % interval wider than the value)."""
    mu_peak_lo: float | None = None
    mu_peak_hi: float | None = None
    slip_at_mu_peak_lo: float | None = None
    slip_at_mu_peak_hi: float | None = None

    def mu(self, slip: npt.ArrayLike) -> FloatArray:
        """The fitted mu at each slip, sign(s)·(c1·(1 − exp(−c2·|s|)) − c3·|s|) (Magic Formula: sign(s)·D·sin(C·
        atan(B·|s|)))."""
        s = np.asarray(slip, dtype=float)
        if self.model == "magic formula":
            return np.sign(s) * self.c3 * np.sin(self.c2 * np.arctan(self.c1 * np.abs(s)))
        return np.sign(s) * _burckhardt(np.abs(s), self.c1, self.c2, self.c3)

    @property
    def initial_slope(self) -> float:
        """dmu/ds at s = 0: c1·c2 − c3 (Magic Formula: B·C·D)."""
        if self.model == "magic formula":
            return self.c1 * self.c2 * self.c3
        return self.c1 * self.c2 - self.c3


def c1_basis(c2s: FloatArray, x: FloatArray) -> FloatArray:
    """(k, n): 1 − exp(−c2·x) for each c2 of the grid and each point."""
    return -np.expm1(-np.outer(c2s, x))


class Bases:
    """c1_basis of a maneuver's points (x = sign·slip, for each sign) on the grids the fits take, each computed once
    over all the points; a subset of them (a bootstrap resample, the points inside the peak window) gathers its
    columns, the same values bit for bit as its own c1_basis. At most MAX_GRIDS grids are kept; others are computed
    for the subset alone."""

    MAX_GRIDS = 8

    def __init__(self, slip: FloatArray) -> None:
        self.slip = slip
        self._grids: dict[tuple[float, bytes], FloatArray] = {}

    def columns(self, sign: float, c2s: FloatArray, pos: npt.NDArray[np.intp]) -> FloatArray:
        """c1_basis(c2s, sign·slip[pos])."""
        key = (sign, c2s.tobytes())
        e = self._grids.get(key)
        if e is None:
            if len(self._grids) >= self.MAX_GRIDS:
                return c1_basis(c2s, sign * self.slip[pos])
            with np.errstate(all="ignore"):  # non-finite slips: their columns are never gathered
                e = self._grids[key] = c1_basis(c2s, sign * self.slip)
        return np.take(e, pos, axis=1)  # C order, as c1_basis's own: the sums below take its order


def _solve_grid(x: FloatArray, y: FloatArray, c2s: FloatArray, e: FloatArray | None = None
                ) -> tuple[FloatArray, FloatArray, FloatArray]:
    """For each c2: least squares y ≈ c1·(1 − exp(−c2·x)) − c3·x with c1, c3 >= 0 (a 2-variable NNLS: the
    unconstrained solution if feasible, else the better of the boundary solutions); e: c1_basis(c2s, x) where it is
    known. Returns (c1, c3, sse)."""
    if e is None:
        e = c1_basis(c2s, x)  # (k, n): the c1 basis
    b = -x  # the c3 basis
    ee = np.einsum("kn,kn->k", e, e)
    eb = e @ b
    bb = float(b @ b)
    ey = e @ y
    by = float(b @ y)
    yy = float(y @ y)
    det = ee * bb - eb * eb
    with np.errstate(divide="ignore", invalid="ignore"):
        c1_u = np.where(det > 0, (ey * bb - eb * by) / det, -1.0)
        c3_u = np.where(det > 0, (ee * by - eb * ey) / det, -1.0)
        c1_only = np.maximum(0.0, np.where(ee > 0, ey / ee, 0.0))
    c3_only = max(0.0, by / bb) if bb > 0 else 0.0

    def sse(c1: FloatArray, c3: FloatArray) -> FloatArray:
        return np.asarray(yy - 2 * c1 * ey - 2 * c3 * by + c1 * c1 * ee + 2 * c1 * c3 * eb + c3 * c3 * bb, dtype=float)

    cands = [
        (np.maximum(c1_u, 0.0), np.maximum(c3_u, 0.0), (c1_u >= 0) & (c3_u >= 0)),
        (c1_only, np.zeros_like(c1_only), np.ones_like(ee, dtype=bool)),
        (np.zeros_like(ee), np.full_like(ee, c3_only), np.ones_like(ee, dtype=bool)),
    ]
    best_c1, best_c3 = cands[1][0], cands[1][1]
    best_sse = sse(best_c1, best_c3)
    for c1, c3, ok in (cands[0], cands[2]):
        s = np.where(ok, sse(c1, c3), np.inf)
        better = s < best_sse
        best_c1 = np.where(better, c1, best_c1)
        best_c3 = np.where(better, c3, best_c3)
        best_sse = np.where(better, s, best_sse)
    return best_c1, best_c3, np.maximum(best_sse, 0.0)


def fit_mu_slip(slip: npt.ArrayLike, mu: npt.ArrayLike, peak_window: float | None = PEAK_WINDOW) -> MuSlipFit | None:
    """Burckhardt fit to one maneuver's (slip, mu) points, all braking or all driving.

    The maneuver's sign is that of the median slip; points are mirrored onto it (x = sign·s, y = sign·mu, so the
    noise about s = 0 stays unbiased) and points of the other sign beyond OPPOSITE_SLIP_MAX are dropped. c2 is
    searched on C2_GRID, then on 200 values between the best one's neighbours; (c1, c3) by least squares, >= 0.
    The peak s* = ln(c1·c2/c3)/c2 counts as observed only with points on both sides of it (MIN_PEAK_SIDE_POINTS
    below s*, and beyond PEAK_MARGIN·s*), MIN_PEAK_REGION_POINTS around it, and a curve that explains the points
    (MIN_EXPLAINED); else mu_peak and slip_at_mu_peak
    are None: the linear region alone does not identify a peak (its points fit a family of curves with peaks
    anywhere beyond them).
    With a peak observed and points beyond peak_window·s*, the fit is repeated on the points up to it until s*
    settles (PEAK_WINDOW_ITERATIONS); the curve is then an extrapolation beyond max_abs_slip. peak_window=None:
    one fit over every point (the whole-range curve, its peak biased towards the sliding branch).
    None for fewer than MIN_POINTS points, an |s| spread below MIN_SLIP_SPAN, or no rising curve (c1 = 0)."""
    s = np.asarray(slip, dtype=float).ravel()
    m = np.asarray(mu, dtype=float).ravel()
    if s.shape != m.shape:
        raise ValueError("slip and mu must have the same length")
    return _fit_mu_slip(s, m, peak_window)


def _fit_mu_slip(s: FloatArray, m: FloatArray, peak_window: float | None, bases: Bases | None = None,
                 pos: npt.NDArray[np.intp] | None = None) -> MuSlipFit | None:
    """fit_mu_slip of 1-d arrays; bases: of points of which s are those at pos."""
    ok = np.isfinite(s) & np.isfinite(m)
    s, m = s[ok], m[ok]
    if s.size < MIN_POINTS:
        return None
    sign = -1.0 if np.median(s) < 0 else 1.0
    x, y = sign * s, sign * m
    keep = x >= -OPPOSITE_SLIP_MAX
    x, y = x[keep], y[keep]
    at = pos[ok][keep] if bases is not None and pos is not None else None

    fit = _fit_points(x, y, sign, bases, at)
    if peak_window is None or peak_window <= PEAK_MARGIN:
        return fit
    for _ in range(PEAK_WINDOW_ITERATIONS):
        if fit is None or fit.slip_at_mu_peak is None:
            break
        inside = x <= peak_window * fit.slip_at_mu_peak
        if inside.all():
            break
        refit = _fit_points(x[inside], y[inside], sign, bases, at[inside] if at is not None else None)
        if refit is None or refit.slip_at_mu_peak is None:
            break
        settled = abs(refit.slip_at_mu_peak - fit.slip_at_mu_peak) < 1e-4
        fit = dataclasses.replace(refit, points_beyond_window=int(np.count_nonzero(~inside)))
        if settled:
            break
    return fit


MIN_EXPLAINED = 0.3
"""A peak counts as observed only where the curve explains at least this share of the points' variance about their
mean (R²): slip noise spreads a force that hardly changes (a gentle, steady maneuver) across slips, and a curve through
such a cloud has a peak anywhere."""


def robust_interval(x: FloatArray) -> tuple[float, float]:
    """median ± 1.96·1.4826·MAD: a 95 % interval that a few degenerate resamples (a curve with no real peak) do not
    stretch as they stretch the percentiles."""
    m = float(np.median(x))
    half = 1.959963984540054 * 1.4826 * float(np.median(np.abs(x - m)))
    return m - half, m + half


BOOTSTRAP_RESAMPLES = 40
BOOTSTRAP_SEED = 20261125
BOOTSTRAP_FOUND_SHARE = 0.8
"""An interval is given only where this share of the resamples find a peak."""
BLOCK_S = 0.2
"""The bootstrap's blocks: the slip's noise is correlated over about this."""


def block_samples(time_s: npt.ArrayLike | None) -> int:
    """BLOCK_S in samples of the time series time_s (10 ms apart where it is not given)."""
    t = None if time_s is None else np.asarray(time_s, dtype=float)
    dt = float(np.median(np.diff(t))) if t is not None and t.size > 1 else 0.01
    return max(1, int(round(BLOCK_S / max(dt, 1e-6))))


def block_starts(rng: np.random.Generator, n: int, block: int) -> npt.NDArray[np.int64]:
    """One moving-block resample of n samples: the first samples of its ceil(n / block) blocks."""
    return rng.integers(0, max(1, n - block + 1), size=int(math.ceil(n / block)))


def peak_interval(slip: npt.ArrayLike, mu: npt.ArrayLike, block: int
                  ) -> tuple[float | None, float | None, float | None, float | None]:
    """(mu peak lo, hi, slip at peak lo, hi) of fit_mu_slip over time-ordered points: a moving-block bootstrap
    (blocks of `block` consecutive points, BOOTSTRAP_RESAMPLES resamples, a fixed seed so live and report agree),
    robust_interval of the resamples' peaks; all None unless BOOTSTRAP_FOUND_SHARE of them find one."""
    s, m = np.asarray(slip, dtype=float), np.asarray(mu, dtype=float)
    n = s.size
    block = max(1, min(block, n))
    rng = np.random.default_rng(BOOTSTRAP_SEED)
    peaks = []
    s, m = s.ravel(), m.ravel()
    if s.shape != m.shape:
        raise ValueError("slip and mu must have the same length")
    bases = Bases(s)
    for _ in range(BOOTSTRAP_RESAMPLES):
        starts = block_starts(rng, n, block)
        idx = (starts[:, None] + np.arange(block)[None, :]).ravel()[:n]
        fit = _fit_mu_slip(s[idx], m[idx], PEAK_WINDOW, bases, idx)
        if fit is not None and fit.mu_peak is not None and fit.slip_at_mu_peak is not None:
            peaks.append((fit.mu_peak, fit.slip_at_mu_peak))
    if len(peaks) < BOOTSTRAP_FOUND_SHARE * BOOTSTRAP_RESAMPLES:
        return None, None, None, None
    arr = np.array(peaks)
    return (*robust_interval(arr[:, 0]), *robust_interval(arr[:, 1]))


def explained(sse: float, y: FloatArray) -> float:
    """R² = 1 − sse / Σ(y − ȳ)²; 0 when y does not vary."""
    sst = float(np.sum((y - np.mean(y)) ** 2)) if y.size else 0.0
    return 1.0 - sse / sst if sst > 0 else 0.0


def _fit_points(x: FloatArray, y: FloatArray, sign: float, bases: Bases | None = None,
                pos: npt.NDArray[np.intp] | None = None) -> MuSlipFit | None:
    """The grid fit on mirrored points (x >= −OPPOSITE_SLIP_MAX); None as fit_mu_slip says; bases: of points of
    which x are sign times those at pos."""
    n = int(x.size)
    if n < MIN_POINTS or float(np.max(np.abs(x)) - np.min(np.abs(x))) < MIN_SLIP_SPAN:
        return None

    def basis(c2s: FloatArray) -> FloatArray | None:
        return bases.columns(sign, c2s, pos) if bases is not None and pos is not None else None

    c1s, c3s, sses = _solve_grid(x, y, C2_GRID, basis(C2_GRID))
    i = int(np.argmin(sses))
    lo, hi = C2_GRID[max(i - 1, 0)], C2_GRID[min(i + 1, C2_GRID.size - 1)]
    fine = np.geomspace(lo, hi, 200)
    f1, f3, fs = _solve_grid(x, y, fine, basis(fine))
    j = int(np.argmin(fs))
    if fs[j] <= sses[i]:
        c1, c2, c3, sse = float(f1[j]), float(fine[j]), float(f3[j]), float(fs[j])
    else:
        c1, c2, c3, sse = float(c1s[i]), float(C2_GRID[i]), float(c3s[i]), float(sses[i])
    if c1 <= 0:
        return None

    mu_peak: float | None = None
    s_peak: float | None = None
    observed = False
    if c3 > 0 and c1 * c2 > c3:
        s_star = math.log(c1 * c2 / c3) / c2
        beyond = int(np.count_nonzero(x > PEAK_MARGIN * s_star))
        below = int(np.count_nonzero((x > 0) & (x < s_star)))
        near = int(np.count_nonzero((x >= PEAK_REGION[0] * s_star) & (x <= PEAK_REGION[1] * s_star)))
        observed = beyond >= max(MIN_PEAK_SIDE_POINTS, 0.05 * n) and below >= MIN_PEAK_SIDE_POINTS \
            and near >= MIN_PEAK_REGION_POINTS and explained(sse, y) >= MIN_EXPLAINED
        if observed:
            s_peak = s_star
            mu_peak = float(_burckhardt(np.array([s_star]), c1, c2, c3)[0])
    return MuSlipFit(
        c1=c1, c2=c2, c3=c3, mu_peak=mu_peak, slip_at_mu_peak=s_peak,
        rms_residual=math.sqrt(sse / n), n_points=n, peak_observed=observed,
        slip_sign=sign, max_abs_slip=float(np.max(np.abs(x))),
    )


def end_of_linearity_slip(fit: MuSlipFit, tolerance: float = LINEARITY_TOLERANCE) -> float | None:
    """|s| (a positive fraction) where the fitted mu first falls more than `tolerance` below the initial linear
    slope: mu(s) = (1 − tolerance)·mu'(0)·s with mu'(0) = c1·c2 − c3 (mu(s)/s decreases monotonically, the curve
    being concave, so bisection finds the one root). None without a positive initial slope, or when that slip lies
    beyond the fitted points (max_abs_slip): the curve there is an extrapolation. Burckhardt's exponential bends
    from s = 0 on (the 10 % point of c1·(1 − exp(−c2·s)) alone is s ≈ 0.21/c2), so on a tire that stays straight
    longer (a Magic Formula curve) this comes earlier than the tire's own end of linearity."""
    k = fit.initial_slope
    if k <= 0 or not 0 < tolerance < 1:
        return None

    def excess(x: float) -> float:  # > 0 while still within the tolerance
        return float(_burckhardt(np.array([x]), fit.c1, fit.c2, fit.c3)[0]) - (1.0 - tolerance) * k * x

    hi = fit.max_abs_slip
    if hi <= 0 or excess(hi) > 0:
        return None
    lo = 0.0
    for _ in range(100):
        mid = 0.5 * (lo + hi)
        if excess(mid) > 0:
            lo = mid
        else:
            hi = mid
        if hi - lo < 1e-9:
            break
    return 0.5 * (lo + hi)
