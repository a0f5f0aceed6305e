"""The estimator's per-epoch maths: each part against a formulation written out here as the reference."""

from __future__ import annotations

import math
from collections import deque

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st

from slipdaq.estimator.latency import UtcLatency
from slipdaq.estimator.slip import integrate_speed_m
from slipdaq.estimator.stiffness import StiffnessFit


def same(a: float | None, b: float | None) -> bool:
    """Equal bits: equal and the same sign of zero, or both NaN, or both None."""
    if a is None or b is None:
        return a is b
    return (a == b and math.copysign(1.0, a) == math.copysign(1.0, b)) or (a != a and b != b)


FINITE = st.floats(-1e6, 1e6, allow_nan=False)
ANY = st.one_of(FINITE, st.sampled_from([0.0, -0.0, math.inf, -math.inf, 1e308, -1e308, 5e-324]))


@given(st.lists(st.floats(0.01, 0.3), min_size=1, max_size=60), st.data())
def test_integrate_speed(steps: list[float], data: st.DataObject) -> None:
    """The distance under the piecewise-linear speed equals the exact integral of each linear piece (and of the
    constant speed beyond the first and last fix)."""
    times = np.cumsum([1000.0, *steps])
    speeds = np.array(data.draw(st.lists(st.floats(0, 80), min_size=len(times), max_size=len(times))))
    t0 = data.draw(st.floats(times[0] - 0.1, times[-1] + 0.1))
    t1 = t0 + data.draw(st.sampled_from([0.5, 0.2, 1.0, 2.0, 0.05]))
    knots = sorted({t0, t1, *[x for x in times.tolist() if t0 < x < t1]})
    exact = 0.0
    for a, b in zip(knots[:-1], knots[1:]):
        va, vb = np.interp([a, b], times, speeds)
        exact += (b - a) * (va + vb) / 2.0
    assert math.isclose(integrate_speed_m(times, speeds, t0, t1), exact, rel_tol=1e-12, abs_tol=1e-9)


class UtcLatencyReference:
    """UtcLatency with numpy over the deque: the second smallest value (sorted), the median for the spread."""

    def __init__(self, max_latency_s: float, history: int) -> None:
        self.max_latency_s = max_latency_s
        self.d: deque[float] = deque(maxlen=history)

    def add(self, arrival_s: float, fix_utc_s: float | None) -> None:
        if fix_utc_s is not None:
            self.d.append(arrival_s - fix_utc_s)

    def offset_s(self) -> float | None:
        if not self.d:
            return None
        d = np.fromiter(self.d, float)
        return math.nan if np.isnan(d).any() else float(np.sort(d)[min(1, len(d) - 1)])

    def estimate(self) -> float | None:
        if len(self.d) < 5:
            return None
        d = np.fromiter(self.d, float)
        low = self.offset_s()
        assert low is not None
        med = float(np.median(d))
        spread = float(np.median(np.abs(d - med)))
        return max(low, 0.0) if -0.02 <= low <= self.max_latency_s and spread <= 0.02 else None


DEVIATION = st.one_of(st.floats(-0.05, 0.05), st.sampled_from([0.0, -0.0, 0.01, -0.01, 0.02, math.nan, math.inf,
                                                                -math.inf, 3.0]))


@settings(max_examples=300, deadline=None)
@given(st.integers(1, 60), st.sampled_from([0.4, 0.1]), st.sampled_from([0.05, 0.0, -0.01, 3.0]),
       st.lists(st.one_of(st.none(), DEVIATION), max_size=150))
def test_utc_latency(history: int, max_latency_s: float, latency_s: float, deviations: list[float | None]) -> None:
    fast, ref = UtcLatency(max_latency_s, history), UtcLatencyReference(max_latency_s, history)
    for k, dev in enumerate(deviations):
        arrival = 1000.0 + 0.05 * k
        utc = None if dev is None else arrival - latency_s - dev
        fast.add(arrival, utc)
        ref.add(arrival, utc)
        with np.errstate(all="ignore"):
            assert same(fast.offset_s(), ref.offset_s())
            assert same(fast.estimate(), ref.estimate())


class StiffnessReference:
    """StiffnessFit with numpy 2x2 normal equations (its products through BLAS, which may fuse a multiply and an add:
    StiffnessFit rounds each once, so the two agree to the solve's rounding)."""

    def __init__(self) -> None:
        self.a, self.b, self.yy, self.w, self.windows = np.zeros((2, 2)), np.zeros(2), 0.0, 0.0, 0
        self.cx_n: float | None = None
        self.confidence = 0.0
        self.radius_m: float | None = None

    def add(self, force_n: float, q: float, weight: float) -> None:
        x = np.array([force_n / 1000.0, 1.0])
        self.a = 0.998 * self.a + weight * np.outer(x, x)
        self.b = 0.998 * self.b + weight * x * q
        self.yy = 0.998 * self.yy + weight * q * q
        self.w = 0.998 * self.w + 1.0
        self.windows += 1
        if self.windows < 20:
            return
        a = self.a
        det = a[0, 0] * a[1, 1] - a[0, 1] * a[1, 0]
        if det <= 1e-12 * max(a[0, 0] * a[1, 1], 1e-300):
            return
        inv = np.array([[a[1, 1], -a[0, 1]], [-a[1, 0], a[0, 0]]]) / det
        theta = inv @ self.b
        beta, alpha = float(theta[0]), float(theta[1])
        resid = max(self.yy - float(theta @ self.b), 0.0)
        cov = inv * (resid / max(self.w - 2.0, 1.0))
        if beta <= 0 or alpha <= 0:
            self.cx_n, self.confidence = None, 0.0
            return
        rel_var = cov[1, 1] / alpha**2 + cov[0, 0] / beta**2 - 2.0 * cov[0, 1] / (alpha * beta)
        self.confidence = float(min(max(1.0 - 10.0 * math.sqrt(max(rel_var, 0.0)), 0.0), 1.0))
        self.radius_m = 1.0 / alpha
        self.cx_n = 1000.0 * alpha / beta if self.confidence > 0 else None


@settings(max_examples=200, deadline=None)
@given(st.floats(1e4, 3e5), st.floats(0.29, 0.32),
       st.lists(st.tuples(st.floats(-8000, 8000), st.floats(-0.002, 0.002), st.sampled_from([1.0, 0.1, 10.0, 2.5])),
                max_size=80))
def test_stiffness_fit(cx_n: float, r0_m: float, windows: list[tuple[float, float, float]]) -> None:
    """The fit equals numpy's normal equations: the same windows and decisions; Cx and r0 within 1e-9 and 1e-12 of
    them and the confidence within 1e-6 where the normal equations are well conditioned (the solve's rounding, not the
    sums': the sums are the same bits)."""
    fast, ref = StiffnessFit(), StiffnessReference()
    for force, noise, weight in windows:
        q = (1.0 + force / cx_n) / r0_m + noise
        fast.add(force, q, weight)
        ref.add(force, q, weight)
        assert fast.windows == ref.windows
        assert (fast._a00, fast._a01, fast._a11, fast._b0, fast._b1) == (
            ref.a[0, 0], ref.a[0, 1], ref.a[1, 1], ref.b[0], ref.b[1])
        if ref.radius_m is None or np.linalg.cond(ref.a) > 1e6:
            assert (fast.radius_m is None) == (ref.radius_m is None) or ref.windows >= 20
            continue
        assert fast.radius_m is not None and math.isclose(fast.radius_m, ref.radius_m, rel_tol=1e-12)
        assert math.isclose(fast.confidence, ref.confidence, abs_tol=1e-6)
        if fast.cx_n is None or ref.cx_n is None:  # a confidence of 0 on one side: near 0 on the other
            assert max(fast.confidence, ref.confidence) < 1e-6
        else:
            assert math.isclose(fast.cx_n, ref.cx_n, rel_tol=1e-9)


def test_stiffness_fit_solve_rounds_each_step_once() -> None:
    """The solve is the same arithmetic on every machine: theta = A^-1 b with each product and sum rounded once (the
    expected bits written out here), not numpy's matrix product, which BLAS fuses by the CPU."""
    fit = StiffnessFit(forgetting=1.0, min_windows=2)
    for force, noise in ((1000.0, 1e-4), (-2500.0, -2e-4), (4000.0, 0.0), (-500.0, 3e-4), (2500.0, -1e-4)):
        fit.add(force, (1.0 + force / 80_000.0) / 0.3 + noise)
    a00, a01, a11, b0, b1, yy = fit._a00, fit._a01, fit._a11, fit._b0, fit._b1, fit._yy
    det = a00 * a11 - a01 * a01
    i00, i01, i11 = a11 / det, -a01 / det, a00 / det
    beta, alpha = i00 * b0 + i01 * b1, i01 * b0 + i11 * b1
    assert fit.radius_m == 1.0 / alpha and fit.cx_n == 1000.0 * alpha / beta and fit.confidence > 0.5
    scale = max(yy - (beta * b0 + alpha * b1), 0.0) / max(fit._w - 2.0, 1.0)
    rel_var = i11 * scale / alpha**2 + i00 * scale / beta**2 - 2.0 * (i01 * scale) / (alpha * beta)
    assert fit.confidence == min(max(1.0 - 10.0 * math.sqrt(max(rel_var, 0.0)), 0.0), 1.0)
