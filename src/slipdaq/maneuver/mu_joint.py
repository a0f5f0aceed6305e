"""The tire's mu–slip curve from every wheel at once. Pure: arrays in, dataclasses out.

Only the vehicle's total longitudinal force Fx(t) = M·a(t) is observed. At the limit a tire carries mu(s)·Fz
whatever the hydraulics ask, so instead of splitting Fx by the brake balance, a Burckhardt curve (mu_slip.py) is
fitted to the total force over the wheels' own high-rate slips (the joint fit):

    Fx(t) = Σ_w sign(s_w)·mu_g(|s_w(t)|)·Fz_w(t),    mu_g(x) = c1_g·(1 − exp(−c2_g·x)) − c3_g·x,

g the wheel's group: one curve for all the wheels that carry force ("shared"), or one per axle ("per axle"). For a
given c2 (per group) the model is linear in (c1, c3), so c2 is searched on a grid (then a finer one around the best)
and (c1, c3) solved by least squares, as in mu_slip.py.

Identifiability: the curves of two axles separate only when their wheels' slips differ over time (ABS cycles each
wheel on its own phase; one axle at the limit, the other in its linear region). The per-axle fit is taken when it
explains the force significantly better than the shared one (an F test on the effective number of independent
samples, EFFECTIVE_SAMPLE_S apart), else the shared curve. A wheel whose slip never leaves the noise (a free-rolling
wheel under drive) carries no force and is left out. Each group's peak counts as observed by mu_slip's rule over its
own wheels' slips; with none observed the caller keeps the hydraulic split (`figures`), which is right where a wheel
stays far from its limit.

Uncertainty: a moving-block bootstrap (blocks of mu_slip.BLOCK_S, BOOTSTRAP_RESAMPLES resamples, a fixed seed so live and
report agree) refits the chosen model; each group's mu peak and slip at the peak get the interval median ± 1.96
robust standard deviations (1.4826·MAD) of the resamples' values: a 95 % interval under normality that a few
degenerate resamples (a curve without a real peak) do not stretch.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

from slipdaq.maneuver.mu_slip import (
    BOOTSTRAP_FOUND_SHARE,
    BOOTSTRAP_RESAMPLES,
    BOOTSTRAP_SEED,
    MIN_EXPLAINED,
    MIN_PEAK_REGION_POINTS,
    MIN_PEAK_SIDE_POINTS,
    MIN_POINTS,
    PEAK_MARGIN,
    PEAK_REGION,
    PEAK_WINDOW,
    PEAK_WINDOW_ITERATIONS,
    block_samples,
    block_starts,
    explained,
    robust_interval,
)

FloatArray = npt.NDArray[np.float64]

AXLES: dict[str, tuple[str, ...]] = {"front": ("FL", "FR"), "rear": ("RL", "RR")}
ACTIVE_SLIP = 0.02
"""A wheel carries force in the fit when its |slip| exceeds this in at least MIN_POINTS samples."""
C2_COARSE = np.geomspace(2.0, 200.0, 36)
"""Coarse grid of c2 (1/slip) per group; refined between the best value's neighbours (C2_FINE_STEPS)."""
C2_FINE_STEPS = 24
EFFECTIVE_SAMPLE_S = 0.1
"""High-rate samples this far apart count as independent in the F test (the slip's noise is correlated over it)."""
F_CRITICAL = 4.0
"""The per-axle fit is taken when its F statistic (3 more parameters) exceeds this (about p = 0.01)."""
LAG_MAX_S = 0.05
"""force_lag_s searches the force's delay behind the slips within ±this."""
LAG_SHARPNESS = 1.1
LAG_SHARPNESS_S = 0.02
"""... and takes the best delay only where the fit LAG_SHARPNESS_S either side of it leaves LAG_SHARPNESS times its
residual (a force that varies slowly, a launch, does not pin a delay down)."""


@dataclass(frozen=True)
class GroupCurve:
    """One group's fitted curve and its peak (None unless observed), with the peak's 95 % interval."""

    wheels: tuple[str, ...]
    model: str
    """'burckhardt' (params c1, c2, c3) or 'magic formula' (params B, C, D)."""
    params: tuple[float, float, float]
    peak_observed: bool
    mu_peak: float | None
    slip_at_mu_peak: float | None
    mu_peak_lo: float | None = None
    mu_peak_hi: float | None = None
    slip_at_mu_peak_lo: float | None = None
    slip_at_mu_peak_hi: float | None = None

    def mu(self, x: npt.ArrayLike) -> FloatArray:
        """mu at |s| = x."""
        xa = np.asarray(x, dtype=float)
        a, b, c = self.params
        if self.model == "magic formula":
            return np.asarray(c * np.sin(b * np.arctan(a * xa)), dtype=float)
        return np.asarray(a * -np.expm1(-b * xa) - c * xa, dtype=float)


@dataclass(frozen=True)
class JointFit:
    method: str
    """'joint shared' or 'joint per axle'."""
    curves: dict[str, GroupCurve]
    """Per wheel that carries force: its group's curve."""
    rms_residual: float
    """RMS of the force residual over the mean total normal load (a mu)."""
    n_points: int
    f_statistic: float | None
    """The per-axle fit against the shared one (None: only one group carries force)."""


def _peak(c1: float, c2: float, c3: float) -> tuple[float, float] | None:
    if not (c1 > 0 and c2 > 0 and c3 > 0 and c1 * c2 > c3):
        return None
    s = math.log(c1 * c2 / c3) / c2
    return float(c1 * -math.expm1(-c2 * s) - c3 * s), s


def _observed(x: FloatArray, s_star: float) -> bool:
    """mu_slip's rule: points below, around and beyond the peak (x: the group's |slip| samples, pooled)."""
    n = x.size
    beyond = int(np.count_nonzero(x > PEAK_MARGIN * s_star))
    below = int(np.count_nonzero((x > 0) & (x < s_star)))
    near = int(np.count_nonzero((x >= PEAK_REGION[0] * s_star) & (x <= PEAK_REGION[1] * s_star)))
    return beyond >= max(MIN_PEAK_SIDE_POINTS, 0.05 * n) and below >= MIN_PEAK_SIDE_POINTS \
        and near >= MIN_PEAK_REGION_POINTS


class _Problem:
    """The fit's data: y (n,) the total force on the maneuver's sign, per group its wheels' |s| and Fz (m, n)."""

    def __init__(self, y: FloatArray, groups: list[tuple[FloatArray, FloatArray, FloatArray]]) -> None:
        self.y = y
        self.groups = groups
        """Per group: (x (m, n) mirrored slips, fz (m, n), sgn (m, n) the sign of each mirrored slip)."""

    def columns(self, g: int, c2s: FloatArray) -> tuple[FloatArray, FloatArray]:
        """The c1 basis per c2 (k, n) and the c3 basis (n,) of group g."""
        x, fz, sgn = self.groups[g]
        e = np.einsum("mn,kmn->kn", fz * sgn, -np.expm1(-c2s[:, None, None] * np.abs(x)[None]))
        return e, -np.sum(fz * sgn * np.abs(x), axis=0)


def _solve(cols: list[tuple[FloatArray, FloatArray]], y: FloatArray, w: FloatArray
           ) -> tuple[FloatArray, FloatArray]:
    """Weighted least squares for every combination of the groups' c2 values (one or two groups): (params (K...,
    2G): c1, c3 per group; sse (K...)); a combination with a c1 <= 0 gets sse = inf."""
    basis = [np.stack([e, np.broadcast_to(b, e.shape)], axis=1) for e, b in cols]  # (k_g, 2, n)
    weighted = [bg * w for bg in basis]
    grams = [np.einsum("kpn,kqn->kpq", wb, bg) for wb, bg in zip(weighted, basis)]
    rhs = [wb @ y for wb in weighted]  # (k_g, 2)
    if len(basis) == 1:
        a, r = grams[0], rhs[0]
    else:
        k1, k2 = basis[0].shape[0], basis[1].shape[0]
        cross = np.einsum("apn,bqn->abpq", weighted[0], basis[1])  # (k1, k2, 2, 2)
        a = np.zeros((k1, k2, 4, 4))
        a[..., :2, :2] = grams[0][:, None]
        a[..., 2:, 2:] = grams[1][None, :]
        a[..., :2, 2:] = cross
        a[..., 2:, :2] = np.swapaxes(cross, -1, -2)
        r = np.concatenate([np.broadcast_to(rhs[0][:, None], (k1, k2, 2)),
                            np.broadcast_to(rhs[1][None, :], (k1, k2, 2))], axis=-1)
    n_par = r.shape[-1]
    scale = np.sqrt(np.maximum(np.einsum("...ii->...i", a), 1e-300))  # Jacobi scaling: c1 and c3 bases differ
    a_s = a / (scale[..., :, None] * scale[..., None, :])
    with np.errstate(all="ignore"):
        params = np.linalg.solve(a_s + 1e-12 * np.eye(n_par), (r / scale)[..., None])[..., 0] / scale
    sse = float(np.sum(w * y * y)) - np.einsum("...p,...p->...", params, r)
    bad = np.any(params[..., 0::2] <= 0, axis=-1) | ~np.isfinite(sse)
    return params, np.where(bad, np.inf, np.maximum(sse, 0.0))


def _fit(p: _Problem, w: FloatArray) -> tuple[FloatArray, FloatArray, float] | None:
    """Coarse grid, then a fine one around the best: (c2 per group, (c1, c3) per group, sse)."""
    g_n = len(p.groups)
    cols = [p.columns(g, C2_COARSE) for g in range(g_n)]
    params, sse = _solve(cols, p.y, w)
    if not np.isfinite(sse).any():
        return None
    best = np.unravel_index(int(np.argmin(sse)), sse.shape)
    fines = [np.geomspace(C2_COARSE[max(int(k) - 1, 0)], C2_COARSE[min(int(k) + 1, C2_COARSE.size - 1)], C2_FINE_STEPS)
             for k in best]
    params_f, sse_f = _solve([p.columns(g, fines[g]) for g in range(g_n)], p.y, w)
    if np.isfinite(sse_f).any() and float(np.min(sse_f)) <= float(sse[best]):
        bf = np.unravel_index(int(np.argmin(sse_f)), sse_f.shape)
        return np.array([fines[g][k] for g, k in enumerate(bf)]), params_f[bf].reshape(g_n, 2), float(sse_f[bf])
    return np.array([C2_COARSE[k] for k in best]), params[best].reshape(g_n, 2), float(sse[best])


MF_B = np.geomspace(2.0, 80.0, 60)
"""Magic Formula stiffness factor B grid (1/slip)."""
MF_C = np.linspace(1.05, 2.2, 32)
"""Magic Formula shape factor C grid (a peak needs C > 1)."""


@dataclass(frozen=True)
class MagicFormula:
    """The Magic Formula's longitudinal form without curvature (Pacejka, Tire and Vehicle Dynamics, ch. 4):
    mu(x) = D·sin(C·atan(B·x)); peak D at x* = tan(pi/(2C))/B."""

    b: float
    c: float
    d: float

    def mu(self, x: npt.ArrayLike) -> FloatArray:
        return np.asarray(self.d * np.sin(self.c * np.arctan(self.b * np.asarray(x, dtype=float))), dtype=float)

    @property
    def peak(self) -> tuple[float, float]:
        return self.d, math.tan(math.pi / (2.0 * self.c)) / self.b


def _mf_basis(p: _Problem) -> tuple[FloatArray, FloatArray]:
    """Σ_w sign·sin(C·atan(B·|s_w|))·Fz_w per (C, B) of the grid, as (C·B, n), and its squares (reused by every
    resample of the bootstrap)."""
    x, fz, sgn = p.groups[0]
    out = np.zeros((MF_C.size, MF_B.size, x.shape[1]))
    for xw, fzw, sw in zip(np.abs(x), fz, sgn):  # one wheel at a time: no (c, b, m, n) array
        out += (fzw * sw) * np.sin(MF_C[:, None, None] * np.arctan(MF_B[None, :, None] * xw[None, None]))
    e = out.reshape(MF_C.size * MF_B.size, x.shape[1])
    return e, e * e


def _fit_mf(basis: tuple[FloatArray, FloatArray], y: FloatArray, w: FloatArray) -> tuple[MagicFormula, float] | None:
    """D by weighted least squares for each (C, B) of the grid (basis: _mf_basis); the best curve and its sse."""
    e, e2 = basis
    return _best_mf(e2 @ w, e @ (w * y), y, w)


MF_ROWS_BLOCK = 64
"""The resamples' products with the Magic Formula's grid, this many grid rows at a time (_mf_products)."""


def _mf_products(basis: tuple[FloatArray, FloatArray], y: FloatArray, ws: list[FloatArray]
                 ) -> list[tuple[FloatArray, FloatArray]]:
    """(e2 @ w, e @ (w * y)) of _fit_mf for each weights w in ws, taken MF_ROWS_BLOCK rows of the grid at a time for
    all of them, so that a block is read from memory once, not once per resample (the grid is megabytes): each row's
    product is the same dot product of that row, the same bits (tests/maneuver/test_mu_joint_products.py)."""
    e, e2 = basis
    wys = [w * y for w in ws]
    ee, ey = np.empty((len(ws), e.shape[0])), np.empty((len(ws), e.shape[0]))
    for r in range(0, e.shape[0], MF_ROWS_BLOCK):
        block, block2 = e[r:r + MF_ROWS_BLOCK], e2[r:r + MF_ROWS_BLOCK]
        for i, (w, wy) in enumerate(zip(ws, wys)):
            ee[i, r:r + MF_ROWS_BLOCK] = block2 @ w
            ey[i, r:r + MF_ROWS_BLOCK] = block @ wy
    return list(zip(ee, ey))


def _best_mf(ee: FloatArray, ey: FloatArray, y: FloatArray, w: FloatArray) -> tuple[MagicFormula, float] | None:
    """_fit_mf from its products ee = e2 @ w, ey = e @ (w * y)."""
    with np.errstate(all="ignore"):
        d = np.where(ee > 0, ey / ee, 0.0)
    sse = np.where(d > 0, float(np.sum(w * y * y)) - d * ey, np.inf)
    if not np.isfinite(sse).any():
        return None
    k = int(np.argmin(sse))
    i, j = divmod(k, MF_B.size)
    return MagicFormula(float(MF_B[j]), float(MF_C[i]), float(d[k])), float(max(sse[k], 0.0))


MF_FINE_STEPS = 9


def _refine_mf(p: _Problem, y: FloatArray, w: FloatArray, coarse: tuple[MagicFormula, float]
               ) -> tuple[MagicFormula, float]:
    """The Magic Formula fit on a finer (B, C) grid between the coarse best's neighbours."""
    best = coarse[0]
    i, j = int(np.argmin(np.abs(MF_C - best.c))), int(np.argmin(np.abs(MF_B - best.b)))
    bs = np.geomspace(MF_B[max(j - 1, 0)], MF_B[min(j + 1, MF_B.size - 1)], MF_FINE_STEPS)
    cs = np.linspace(MF_C[max(i - 1, 0)], MF_C[min(i + 1, MF_C.size - 1)], MF_FINE_STEPS)
    x, fz, sgn = p.groups[0]
    grid = np.zeros((cs.size, bs.size, x.shape[1]))
    for xw, fzw, sw in zip(np.abs(x), fz, sgn):
        grid += (fzw * sw) * np.sin(cs[:, None, None] * np.arctan(bs[None, :, None] * xw[None, None]))
    e = grid.reshape(cs.size * bs.size, -1)
    ee, ey = (e * e) @ w, e @ (w * y)
    with np.errstate(all="ignore"):
        d = np.where(ee > 0, ey / ee, 0.0)
    sse = np.where(d > 0, float(np.sum(w * y * y)) - d * ey, np.inf)
    k = int(np.argmin(sse))
    if not sse[k] < coarse[1]:
        return coarse
    ci, bj = divmod(k, bs.size)
    return MagicFormula(float(bs[bj]), float(cs[ci]), float(d[k])), float(max(sse[k], 0.0))


def _active(slips: Mapping[str, npt.ArrayLike]) -> list[str]:
    """The wheels that carry force in the fit: |slip| above ACTIVE_SLIP in MIN_POINTS samples or more."""
    return [w for w in slips if np.count_nonzero(np.abs(np.asarray(slips[w], dtype=float)) > ACTIVE_SLIP) >= MIN_POINTS]


def force_lag_s(time_s: npt.ArrayLike, slips: Mapping[str, npt.ArrayLike], fz_n: Mapping[str, npt.ArrayLike],
                force_n: npt.ArrayLike, sign: float) -> float:
    """How far the force lags the slips (s): the delay that lets one curve shared by the wheels that carry force
    explain it best. The acceleration reaches the force through causal filters (the IMU's, vehicle_speed.py's), the
    slips come from centred lines (fast_slip.py): in an ABS cycle a delay of one 10 ms sample moves the fitted peak by
    1-2 points of slip. Searched over whole samples within ±LAG_MAX_S (the sample pairs shifted by k), refined by the
    parabola through the best three (where both neighbours of the best have a fit); 0 with too few samples or no
    wheel carrying force, with the best at the search's edge, or with a flat minimum (LAG_SHARPNESS): nothing found."""
    t = np.asarray(time_s, dtype=float)
    y = sign * np.asarray(force_n, dtype=float)
    active = _active(slips)
    if not active or t.size < 3:
        return 0.0
    dt = float(np.median(np.diff(t)))
    k_max = int(round(LAG_MAX_S / dt)) if dt > 0 else 0
    n = t.size - 2 * k_max
    if k_max < 1 or n < MIN_POINTS:
        return 0.0
    x = np.array([sign * np.asarray(slips[w], dtype=float)[k_max:k_max + n] for w in active])
    fz = np.array([np.asarray(fz_n[w], dtype=float)[k_max:k_max + n] for w in active])
    sse = np.full(2 * k_max + 1, np.inf)
    for j in range(sse.size):  # the force k = j - k_max samples later than the slips
        got = _fit(_Problem(y[j:j + n], [(x, fz, np.sign(x))]), np.ones(n))
        if got is not None:
            sse[j] = got[2]
    j = int(np.argmin(sse))
    k2 = max(1, int(round(LAG_SHARPNESS_S / dt)))
    if not np.isfinite(sse[j]) or not k2 <= j < sse.size - k2 or min(sse[j - k2], sse[j + k2]) < LAG_SHARPNESS * sse[j]:
        return 0.0
    curvature = sse[j - 1] - 2.0 * sse[j] + sse[j + 1]
    frac = 0.5 * (sse[j - 1] - sse[j + 1]) / curvature if 0 < curvature < np.inf else 0.0  # a neighbour unfit: inf
    return (j - k_max + float(np.clip(frac, -0.5, 0.5))) * dt


def fit_joint(
    time_s: npt.ArrayLike, slips: Mapping[str, npt.ArrayLike], fz_n: Mapping[str, npt.ArrayLike],
    force_n: npt.ArrayLike, sign: float, axles: Mapping[str, Sequence[str]] = AXLES,
) -> JointFit | None:
    """The joint fit (module docstring) of one maneuver's high-rate samples: each wheel's slip and normal load, the
    total force (all finite, the maneuver's samples only); sign −1 braking, +1 driving. None without a wheel that
    carries force, with fewer than MIN_POINTS samples, or when the curve explains less than MIN_EXPLAINED of the force's
    variance (a steady maneuver: the force hardly varies, its slips are noise)."""
    t = np.asarray(time_s, dtype=float)
    y = sign * np.asarray(force_n, dtype=float)
    active = _active(slips)
    if not active or t.size < MIN_POINTS:
        return None
    groups_w = [g for g in (tuple(w for w in ws if w in active) for ws in axles.values()) if g]
    x = {w: sign * np.asarray(slips[w], dtype=float) for w in active}

    def problem(gs: list[tuple[str, ...]]) -> _Problem:
        return _Problem(y, [(np.array([x[w] for w in g]), np.array([np.asarray(fz_n[w], dtype=float) for w in g]),
                             np.sign(np.array([x[w] for w in g]))) for g in gs])

    def observed_peak(gs: list[tuple[str, ...]], g: int, pk: tuple[float, float] | None) -> bool:
        return pk is not None and _observed(np.abs(np.concatenate([x[wh] for wh in gs[g]])), pk[1])

    def windowed(gs: list[tuple[str, ...]]) -> tuple[_Problem, FloatArray, tuple[FloatArray, FloatArray, float]] | None:
        """The Burckhardt fit, repeated on the samples within PEAK_WINDOW·s* of each observed peak until they
        settle (the sliding branch up to lock bends the curve)."""
        prob = problem(gs)
        w = np.ones_like(y)
        fit = _fit(prob, w)
        for _ in range(PEAK_WINDOW_ITERATIONS):
            if fit is None:
                return None
            keep = np.ones(y.size, dtype=bool)
            for g, ws in enumerate(gs):
                pk = _burckhardt_peak(fit, g)
                if observed_peak(gs, g, pk):
                    for wh in ws:
                        keep &= x[wh] <= PEAK_WINDOW * pk[1]  # type: ignore[index]  # observed: pk is set
            w_new = keep.astype(float)
            if np.array_equal(w_new, w) or keep.sum() < MIN_POINTS:
                break
            w = w_new
            fit = _fit(prob, w)
        return (prob, w, fit) if fit is not None else None

    shared_gs = [tuple(active)]
    got = windowed(shared_gs)
    if got is None:
        return None
    prob, weights, fit = got
    gs, f_stat = shared_gs, None
    if len(groups_w) > 1:
        got_p = windowed(groups_w)
        if got_p is not None:
            p_p, w_p, fit_p = got_p
            n_eff = max(8.0, float(np.sum(w_p)) * float(np.median(np.diff(t))) / EFFECTIVE_SAMPLE_S)
            sse_s = _sse_at(prob, w_p, fit)
            f_stat = ((sse_s - fit_p[2]) / 3.0) / max(fit_p[2] / max(n_eff - 6.0, 1.0), 1e-300)
            if f_stat > F_CRITICAL and all(observed_peak(groups_w, g, _burckhardt_peak(fit_p, g))
                                           for g in range(len(groups_w))):
                prob, weights, fit, gs = p_p, w_p, fit_p, groups_w  # each axle's curve identified by its own peak
    models: list[tuple[str, tuple[float, float, float]]] = [
        ("burckhardt", (float(fit[1][g][0]), float(fit[0][g]), float(fit[1][g][1]))) for g in range(len(gs))]
    sse = fit[2]
    mf_basis = None
    if len(gs) == 1:  # the Magic Formula where it fits the shared curve better
        mf_basis = _mf_basis(prob)
        mf = _fit_mf(mf_basis, y, weights)
        mf = _refine_mf(prob, y, weights, mf) if mf is not None else None
        if mf is not None and mf[1] < sse:
            models, sse = [("magic formula", (mf[0].b, mf[0].c, mf[0].d))], mf[1]
        else:
            mf_basis = None
    w_used = weights > 0
    if explained(sse, y[w_used]) < MIN_EXPLAINED:  # the force hardly varies: no curve to read a peak off
        return None
    intervals = _bootstrap(prob, t, len(gs), weights, mf_basis)
    fz_total = float(np.mean(np.sum([np.asarray(fz_n[w], dtype=float) for w in slips], axis=0)))
    curves: dict[str, GroupCurve] = {}
    for g, ws in enumerate(gs):
        model, params = models[g]
        pk = _model_peak(model, params)
        observed = observed_peak(gs, g, pk)
        lo_hi = intervals[g] if observed else (None, None, None, None)
        curve = GroupCurve(ws, model, params, observed, pk[0] if observed and pk else None,
                           pk[1] if observed and pk else None, *lo_hi)
        for w in ws:
            curves[w] = curve
    n_used = float(np.sum(weights > 0))
    return JointFit("joint per axle" if len(gs) > 1 else "joint shared", curves,
                    math.sqrt(sse / max(n_used, 1.0)) / max(fz_total, 1e-9), int(n_used), f_stat)


def _burckhardt_peak(fit: tuple[FloatArray, FloatArray, float], g: int) -> tuple[float, float] | None:
    return _peak(float(fit[1][g][0]), float(fit[0][g]), float(fit[1][g][1]))


def _model_peak(model: str, params: tuple[float, float, float]) -> tuple[float, float] | None:
    if model == "magic formula":
        b, c, d = params
        return MagicFormula(b, c, d).peak if c > 1.0 and b > 0 and d > 0 else None
    return _peak(*params)


def _sse_at(p: _Problem, w: FloatArray, fit: tuple[FloatArray, FloatArray, float]) -> float:
    """The weighted sse of a fitted curve (its own c2, c1 and c3 per group) on other weights."""
    pred = np.zeros_like(p.y)
    for g in range(len(p.groups)):
        e, b = p.columns(g, np.array([fit[0][g]]))
        pred += fit[1][g][0] * e[0] + fit[1][g][1] * b
    return float(np.sum(w * (p.y - pred) ** 2))


def _bootstrap(p: _Problem, t: FloatArray, n_groups: int, base_w: FloatArray,
               mf_basis: tuple[FloatArray, FloatArray] | None
               ) -> list[tuple[float | None, float | None, float | None, float | None]]:
    """Per group: (mu peak lo, hi, slip at peak lo, hi), moving-block bootstrap of the chosen model (robust_interval)
    (mf_basis given: the Magic Formula; None when fewer than 80 % of the resamples find a peak)."""
    n = t.size
    block = block_samples(t)
    rng = np.random.default_rng(BOOTSTRAP_SEED)
    peaks: list[list[tuple[float, float]]] = [[] for _ in range(n_groups)]
    ws = []
    for _ in range(BOOTSTRAP_RESAMPLES):
        w = np.zeros(n)
        for s in block_starts(rng, n, block):
            w[s:s + block] += 1.0
        w *= base_w
        ws.append(w)
    if mf_basis is not None:
        for w, (ee, ey) in zip(ws, _mf_products(mf_basis, p.y, ws)):
            mf = _best_mf(ee, ey, p.y, w)
            if mf is not None and mf[0].c > 1.0:
                peaks[0].append(mf[0].peak)
        ws = []
    for w in ws:
        fit = _fit(p, w)
        if fit is None:
            continue
        for g in range(n_groups):
            pk = _burckhardt_peak(fit, g)
            if pk is not None:
                peaks[g].append(pk)
    out: list[tuple[float | None, float | None, float | None, float | None]] = []
    for g in range(n_groups):
        if len(peaks[g]) < BOOTSTRAP_FOUND_SHARE * BOOTSTRAP_RESAMPLES:
            out.append((None, None, None, None))
            continue
        mu, s = np.array([a for a, _ in peaks[g]]), np.array([b for _, b in peaks[g]])
        out.append((*robust_interval(mu), *robust_interval(s)))
    return out
