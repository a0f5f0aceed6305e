"""The MF 6.1 pure longitudinal coefficients of one tire from its maneuvers' points (slip, Fx, Fz). Pure: arrays in,
a dataclass out.

Least squares on the friction residual (Fx0(k, Fz) − Fx)/Fz over the points (Levenberg-Marquardt, numpy, the
Jacobian in closed form: mf61.Fx0Terms), in steps:
    1. PCX1, PDX1, PKX1 (the curve at FNOMIN), and PEX1 where it explains the points better (an F test, as in 3).
       Where the points never pass the peak, the peak is not measured: PCX1 is held at C_UNSEEN and PEX1 at 0, PDX1
       is bounded below by the largest |Fx/Fz| seen (99th percentile); where the points leave PKX1 undetermined (its
       95 % interval wider than half of it, or fewer than MIN_SIDE_POINTS points beyond ASYM_SLIP: slip noise near
       zero slip flattens a least-squares slope), PKX1 is the force-slip lines' errors-in-variables slope per unit
       load and PDX1 at least what keeps the curve within LINEARITY_TOLERANCE of that slope over the slip covered
       (the data saw it linear there). The file then holds only for the slip its data cover.
    2. PEX4 (the curvature's braking/driving asymmetry) where the points reach beyond ASYM_SLIP on both sides.
    3. PDX2 and PKX2 (friction and stiffness against load) where the peak was passed, the tire's load varied (load
       transfer) over at least MIN_DFZ_SPAN of FNOMIN, adding them explains the points significantly better (an F
       test on the effective samples, F > F_CRITICAL) and each one's 95 % interval is clear of 0; else 0.
The other coefficients stay 0 (the road does not separate them). Standard errors from the Jacobian at the optimum,
sigma² from the residuals, the points counted EFFECTIVE_SAMPLE_S apart (the slip's noise is correlated over it).
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

from slipdaq.maneuver.mu_joint import EFFECTIVE_SAMPLE_S, F_CRITICAL
from slipdaq.maneuver.mu_slip import LINEARITY_TOLERANCE
from slipdaq.maneuver.record import Z95
from slipdaq.tire_model.mf61 import LongitudinalMF61

FloatArray = npt.NDArray[np.float64]

C_UNSEEN = 1.65
"""PCX1 where the peak was not passed (Pacejka's typical longitudinal shape factor)."""
ASYM_SLIP = 0.05
"""PEX4 is fitted only where at least MIN_SIDE_POINTS points lie beyond this |slip| on each side."""
MIN_SIDE_POINTS = 50
MIN_DFZ_SPAN = 0.1
"""The load terms are tried only where the points' dfz spans this much (5th to 95th percentile)."""
MIN_POINTS = 20
PEAK_MARGIN = 1.15
"""The peak counts as passed with at least max(5, 5 %) points beyond PEAK_MARGIN·s* and 5 below it."""
BOUNDS: dict[str, tuple[float, float]] = {
    "pcx1": (1.0, 2.5), "pdx1": (0.05, 3.0), "pex1": (-5.0, 0.99), "pkx1": (1.0, 200.0), "pex4": (-0.99, 0.99),
    "pdx2": (-1.0, 1.0), "pkx2": (-100.0, 100.0),
}


@dataclass(frozen=True)
class MF61Fit:
    """The fitted model, its coefficients' standard errors (.tir names), what was and was not identified."""

    model: LongitudinalMF61
    stderr: dict[str, float]
    n_points: int
    n_effective: float
    rms_mu: float
    """RMS of the friction residual (Fx0 − Fx)/Fz."""
    peak_passed: bool
    slip_min: float
    slip_max: float
    load_terms: bool
    load_note: str
    asymmetry: bool
    dfz_span: float
    stiffness_from: str = "the points"
    """Where PKX1 came from: 'the points', or 'the force-slip line' (linearity.py's errors-in-variables slope)."""


Evaluation = tuple[FloatArray, Callable[[], FloatArray]]
"""The residual at x and what computes its Jacobian there (one row per coefficient; asked for only where a step is
taken)."""


def _dot(a: FloatArray, b: FloatArray) -> float:
    """a·b by numpy's own loop: a BLAS dot or matrix product over 10⁵ points wakes OpenBLAS's threads, which then spin
    on the other core between the fit's calls (twice the fit's CPU time on 2 cores)."""
    return float(np.einsum("n,n->", a, b))


def _normal(jt: FloatArray) -> FloatArray:
    """JᵀJ of the Jacobian's rows jt (_dot)."""
    p = jt.shape[0]
    a = np.empty((p, p))
    for i in range(p):
        for k in range(i + 1):
            a[i, k] = a[k, i] = _dot(jt[i], jt[k])
    return a


def _lm(evaluate: Callable[[FloatArray], Evaluation], x0: FloatArray, lo: FloatArray, hi: FloatArray,
        iterations: int = 80) -> tuple[FloatArray, FloatArray, FloatArray]:
    """Levenberg-Marquardt within box bounds: (x, residual at x, Jacobian's rows at x). A coefficient at a bound
    that the gradient pushes past it is held out of the step (the active set), the others solved for alone; the step
    is then clipped to the box."""
    x = np.clip(x0, lo, hi)
    r, jac = evaluate(x)
    cost = _dot(r, r)
    lam = 1e-3
    jt = jac()
    for _ in range(iterations):
        g = np.array([_dot(row, r) for row in jt])
        a = _normal(jt)
        free = ~(((x <= lo) & (g > 0)) | ((x >= hi) & (g < 0)))
        if not free.any():  # every coefficient at a bound it is pushed past: the box's optimum
            break
        step = np.zeros_like(x)
        af = a[np.ix_(free, free)]
        step[free] = np.linalg.solve(af + lam * np.diag(np.maximum(np.diag(af), 1e-12)), -g[free])
        x_new = np.clip(x + step, lo, hi)
        r_new, jac_new = evaluate(x_new)
        c_new = _dot(r_new, r_new)
        if c_new < cost:
            done = cost - c_new < 1e-12 * max(cost, 1e-30) or np.all(np.abs(x_new - x) <= 1e-10 * (1 + np.abs(x)))
            x, r, cost = x_new, r_new, c_new
            lam = max(lam / 3.0, 1e-9)
            jt = jac_new()
            if done:
                break
        else:
            lam *= 4.0
            if lam > 1e8:
                break
    return x, r, jt


def _fit(base: LongitudinalMF61, names: Sequence[str], k: FloatArray, fx: FloatArray, fz: FloatArray,
         lower: dict[str, float] | None = None) -> tuple[LongitudinalMF61, FloatArray, float]:
    """Fit `names` of base to the points: (model, Jacobian's rows, SSR); the Jacobian in closed form
    (Fx0Terms.jacobian)."""
    lo = np.array([max(BOUNDS[n][0], (lower or {}).get(n, -math.inf)) for n in names])
    hi = np.array([BOUNDS[n][1] for n in names])
    per_fz = 1.0 / fz
    points = base.point_terms(k, fz)  # what the fitted coefficients do not enter, once

    def model(x: FloatArray) -> LongitudinalMF61:
        return dataclasses.replace(base, **{n: float(v) for n, v in zip(names, x)})

    def evaluate(x: FloatArray) -> Evaluation:
        terms = model(x).fx0_terms(points)
        return np.asarray((terms.fx0 - fx) / fz, dtype=float), lambda: terms.jacobian(names) * per_fz

    x, r, jt = _lm(evaluate, np.array([getattr(base, n) for n in names], dtype=float), lo, hi)
    return model(x), jt, _dot(r, r)


def _stderr(jt: FloatArray, ssr: float, n_eff: float, names: Sequence[str]) -> dict[str, float]:
    p, n = jt.shape
    sigma2 = ssr / max(n - p, 1.0) * (n / max(n_eff, 1.0))
    try:
        cov = np.linalg.inv(_normal(jt)) * sigma2
    except np.linalg.LinAlgError:
        return {n.upper(): math.nan for n in names}
    return {n.upper(): float(math.sqrt(max(cov[i, i], 0.0))) for i, n in enumerate(names)}


def _f_stat(ssr: float, ssr_more: float, added: int, n: int, n_eff: float) -> float:
    """F of a fit with `added` more parameters, on the effective samples."""
    return ((ssr - ssr_more) / added) / max(ssr_more / max(n - added, 1.0), 1e-300) * (n_eff / n)


def _passed(x: FloatArray, s_star: float) -> bool:
    beyond = int(np.count_nonzero(x > PEAK_MARGIN * s_star))
    below = int(np.count_nonzero((x > 0) & (x < s_star)))
    return beyond >= max(5, 0.05 * x.size) and below >= 5


def _start(k: FloatArray, mu: FloatArray, fnomin: float, mu_peak: float | None, slip_peak: float | None
           ) -> LongitudinalMF61:
    """Start values: the maneuvers' own peak where they give one, else the slope of the points below 3 % slip."""
    small = np.abs(k) < 0.03
    slope = float(np.sum(k[small] * mu[small]) / np.sum(k[small] ** 2)) if np.count_nonzero(small) >= 5 else 20.0
    d = mu_peak if mu_peak else float(np.percentile(np.abs(mu), 99))
    if slip_peak:
        kx = math.tan(math.pi / (2 * C_UNSEEN)) / slip_peak * C_UNSEEN * d
    else:
        kx = slope if slope > 1.0 else 20.0
    return LongitudinalMF61(fnomin=fnomin, pcx1=C_UNSEEN, pdx1=max(d, 0.1), pkx1=float(np.clip(kx, 2.0, 150.0)))


def linear_friction(model: LongitudinalMF61, edge_slip: float, tolerance: float = LINEARITY_TOLERANCE) -> float:
    """The least PDX1 with which the curve (PCX1, PKX1 of model, at FNOMIN) stays within `tolerance` of its slope
    up to |slip| = edge_slip (bisection: Fx0/(Kxk·s) rises with PDX1)."""
    lo, hi = BOUNDS["pdx1"]
    fz = model.fnomin
    line = float(model.slip_stiffness(fz)) * edge_slip
    for _ in range(60):
        mid = 0.5 * (lo + hi)
        if float(abs(dataclasses.replace(model, pdx1=mid).fx0(edge_slip, fz))) >= (1.0 - tolerance) * line:
            hi = mid
        else:
            lo = mid
    return hi


def fit_mf61(slip: npt.ArrayLike, fx_n: npt.ArrayLike, fz_n: npt.ArrayLike, fnomin_n: float, *,
             sample_period_s: float = 0.01, mu_peak: float | None = None, slip_at_mu_peak: float | None = None,
             cx_per_fz: float | None = None) -> MF61Fit | None:
    """One tire's coefficients (module docstring) from its points: slip (signed, braking < 0), Fx (N, signed), Fz
    (N); mu_peak / slip_at_mu_peak: the maneuvers' own peak (a start value); cx_per_fz: the force-slip lines' slope
    per unit load (linearity.py), taken for PKX1 where the peak was not passed and the points do not determine it.
    None with fewer than MIN_POINTS."""
    k = np.asarray(slip, dtype=float).ravel()
    fx = np.asarray(fx_n, dtype=float).ravel()
    fz = np.asarray(fz_n, dtype=float).ravel()
    ok = np.isfinite(k) & np.isfinite(fx) & np.isfinite(fz) & (fz > 0)
    k, fx, fz = k[ok], fx[ok], fz[ok]
    if k.size < MIN_POINTS:
        return None
    mu = fx / fz
    n_eff = max(float(k.size) * sample_period_s / EFFECTIVE_SAMPLE_S, 8.0)
    start = _start(k, mu, fnomin_n, mu_peak, slip_at_mu_peak)
    names: tuple[str, ...] = ("pcx1", "pdx1", "pkx1")
    model, j, ssr = _fit(start, names, k, fx, fz)
    main_sign = -1.0 if np.median(k) < 0 else 1.0
    s_star = model.peak(fnomin_n, main_sign)[1]
    passed = _passed(main_sign * k, s_star)
    if passed:  # the curvature where it explains the points better (C and E trade off along the sliding branch)
        model_e, j_e, ssr_e = _fit(model, (*names, "pex1"), k, fx, fz)
        if _f_stat(ssr, ssr_e, 1, k.size, n_eff) > F_CRITICAL:
            model, j, ssr, names = model_e, j_e, ssr_e, (*names, "pex1")
    stiffness_from = "the points"
    if not passed:  # the peak not measured: C held, D at least what the points reached
        names = ("pdx1", "pkx1")
        seen = float(np.percentile(np.abs(mu), 99))
        start = dataclasses.replace(start, pcx1=C_UNSEEN, pex1=0.0, pdx1=max(start.pdx1, seen))
        model, j, ssr = _fit(start, names, k, fx, fz, lower={"pdx1": seen})
        se_k = _stderr(j, ssr, n_eff, names)["PKX1"]
        loose = not BOUNDS["pkx1"][0] < model.pkx1 < BOUNDS["pkx1"][1] or not Z95 * se_k <= 0.5 * model.pkx1 \
            or np.count_nonzero(main_sign * k > ASYM_SLIP) < MIN_SIDE_POINTS
        if loose and cx_per_fz is not None:  # slip noise flattens the points' slope: the force-slip line's instead
            edge = max(-float(np.percentile(k, 0.5)), float(np.percentile(k, 99.5)), 1e-3)
            base = dataclasses.replace(model, pkx1=cx_per_fz)
            names, stiffness_from = ("pdx1",), "the force-slip line"
            model, j, ssr = _fit(base, names, k, fx, fz, lower={"pdx1": linear_friction(base, edge)})
    asym = bool(np.count_nonzero(k > ASYM_SLIP) >= MIN_SIDE_POINTS and np.count_nonzero(k < -ASYM_SLIP) >= MIN_SIDE_POINTS
                and passed)
    if asym:
        names = (*names, "pex4")
        model, j, ssr = _fit(model, names, k, fx, fz)
    dfz = model.dfz(fz)
    span = float(np.percentile(dfz, 95) - np.percentile(dfz, 5))
    load_terms, note = False, f"load dependence not identified: the load varied over {100 * span:.0f} % of FNOMIN"
    if span >= MIN_DFZ_SPAN and passed:
        names_l = (*names, "pdx2", "pkx2")
        model_l, j_l, ssr_l = _fit(model, names_l, k, fx, fz)
        f_stat = _f_stat(ssr, ssr_l, 2, k.size, n_eff)
        se = _stderr(j_l, ssr_l, n_eff, names_l)
        clear = all(abs(getattr(model_l, n)) > Z95 * se[n.upper()] and BOUNDS[n][0] < getattr(model_l, n) < BOUNDS[n][1]
                    for n in ("pdx2", "pkx2"))
        if f_stat > F_CRITICAL and clear:
            model, j, ssr, names, load_terms = model_l, j_l, ssr_l, names_l, True
            note = f"load dependence from load transfer: dfz over {100 * span:.0f} % of FNOMIN, F = {f_stat:.1f}"
        else:
            note = (f"load dependence not identified: dfz over {100 * span:.0f} % of FNOMIN; with PDX2, PKX2 F = "
                    f"{f_stat:.1f} (needs > {F_CRITICAL:g}), PDX2 = {model_l.pdx2:.3g} +- {Z95 * se['PDX2']:.2g}, "
                    f"PKX2 = {model_l.pkx2:.3g} +- {Z95 * se['PKX2']:.2g} (each needs its 95 % interval clear of 0)")
    return MF61Fit(model=model, stderr=_stderr(j, ssr, n_eff, names), n_points=int(k.size), n_effective=n_eff,
                   rms_mu=math.sqrt(ssr / k.size), peak_passed=passed,
                   slip_min=float(min(np.percentile(k, 0.5), 0.0)), slip_max=float(max(np.percentile(k, 99.5), 0.0)),
                   load_terms=load_terms, load_note=note, asymmetry=asym, dfz_span=span, stiffness_from=stiffness_from)
