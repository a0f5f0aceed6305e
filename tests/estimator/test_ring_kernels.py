"""The sample rings' kernels (estimator/ring.py), compiled and as Python, against numpy written the plain way."""

from __future__ import annotations

import math

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st

from slipdaq.estimator.ring import SeriesRing
from support.paths import kernels


def ring_of(times: list[float], values: list[float]) -> SeriesRing:
    r = SeriesRing(8)  # small: the kept samples move and the arrays grow on the way
    for t, v in zip(times, values):
        r.append(t, v)
    return r


series = st.lists(st.tuples(st.floats(0.0, 0.05), st.floats(-1.0, 3.0)), min_size=1, max_size=80).map(
    lambda steps: (np.cumsum([s[0] for s in steps]).tolist(), np.cumsum([s[1] for s in steps]).tolist()))


@settings(max_examples=150, deadline=None)
@given(series=series, span=st.tuples(st.floats(-0.2, 2.0), st.floats(0.0, 1.0)))
def test_longest_gap(series, span) -> None:  # type: ignore[no-untyped-def]
    times, values = series
    t0, t1 = span[0], span[0] + span[1]
    t = np.array(times)
    i = max(int(t.searchsorted(t0, "right")) - 1, 0)
    j = min(int(t.searchsorted(t1, "left")) + 1, len(t))
    want = float(np.diff(t[i:j]).max()) if j - i >= 2 else 0.0
    got = []
    for compiled_ in (True, False):
        with kernels(compiled_):
            got.append(ring_of(times, values).longest_gap(t0, t1))
    assert got == [want, want]


@settings(max_examples=150, deadline=None)
@given(series=series, queries=st.lists(st.floats(-0.2, 2.5), min_size=1, max_size=50), half=st.integers(0, 6))
def test_local_linear(series, queries, half) -> None:  # type: ignore[no-untyped-def]
    times, values = series
    q = np.array(sorted(queries, reverse=True))  # as the latency rows ask: lags 0.. max, times falling
    got = []
    for compiled_ in (True, False):
        with kernels(compiled_):
            got.append(ring_of(times, values).local_linear(q, half))
    if len(times) < 2 * half + 1:
        assert got == [None, None]
        return
    assert got[0] is not None and got[1] is not None
    assert np.array_equal(got[0], got[1])  # compiled and Python: the same bits
    t, v = np.array(times), np.array(values)
    for k, x in enumerate(q.tolist()):
        c = min(max(int(t.searchsorted(x)), half), len(t) - half - 1)
        tt, vv = t[c - half: c + half + 1], v[c - half: c + half + 1]
        if tt[-1] - tt[0] > 1e-6:
            slope, icpt = np.polyfit(tt - tt.mean(), vv, 1)
            want = icpt + slope * (x - tt.mean())
        else:
            want = vv.mean()
        assert abs(got[0][k] - want) <= 1e-6 * (1.0 + abs(want))


def lines_one_by_one(t: list[float], v: list[float], q: list[float], half: int) -> tuple[list[float], list[float]]:
    """local_lines with each time's sample found by bisecting (numpy's searchsorted) and its line summed in the
    kernel's order, in Python floats."""
    k = 2 * half + 1
    out, slopes = [], []
    for x in q:
        c = min(max(int(np.searchsorted(t, x)), half), len(t) - half - 1)
        st = sv = 0.0
        for j in range(c - half, c + half + 1):  # left to right, as the kernel (not sum(): compensated in 3.12)
            st += t[j]
            sv += v[j]
        t_mean, v_mean = st / k, sv / k
        sxx = sxy = 0.0
        for j in range(c - half, c + half + 1):
            d = t[j] - t_mean
            sxx += d * d
            sxy += d * (v[j] - v_mean)
        slope = sxy / sxx if t[c + half] - t[c - half] > 1e-6 else 0.0
        out.append(v_mean + slope * (x - t_mean))
        slopes.append(slope)
    return out, slopes


@settings(max_examples=150, deadline=None)
@given(series=series, queries=st.lists(st.floats(-0.2, 2.5), min_size=1, max_size=50), half=st.integers(0, 6),
       order=st.sampled_from(["falling", "rising", "as drawn"]))
def test_local_lines_bit_for_bit(series, queries, half, order) -> None:  # type: ignore[no-untyped-def]
    """Times in any order (the kernel steps from one time's sample to the next): the same bits as each time's line
    found by bisection and summed in order."""
    times, values = series
    q = sorted(queries, reverse=order == "falling") if order != "as drawn" else queries
    if len(times) < 2 * half + 1:
        return
    want = lines_one_by_one(times, values, q, half)
    for compiled_ in (True, False):
        with kernels(compiled_):
            got = ring_of(times, values).local_lines(np.array(q), half)
        assert got is not None
        assert [x.hex() for x in got[0].tolist()] == [x.hex() for x in want[0]]
        assert [x.hex() for x in got[1].tolist()] == [x.hex() for x in want[1]]


def wheel_speeds_numpy(ring: SeriesRing, r0_m: float, times: np.ndarray) -> list[float | None]:
    """FastSlipRows._wheel_speeds written with numpy (the code the line_speeds kernel replaced)."""
    from slipdaq.estimator.fast_slip import FAST_LINE_HALF
    from slipdaq.estimator.wheel_revolutions import GAP_INTERVALS, MIN_GAP_S, TWO_PI

    half, n = FAST_LINE_HALF, len(ring)
    if n < 2 * half + 1:
        return [None] * len(times)
    lines = ring.local_lines(times, half)
    assert lines is not None
    t = ring.times
    first = np.searchsorted(t, times)
    c = np.clip(first, half, n - half - 1)
    k = np.add.outer(c - half, np.arange(2 * half))
    longest = (t[k + 1] - t[k]).max(axis=1)
    ok = (n - first >= half + 1) & (first >= half) & (longest <= max(MIN_GAP_S, GAP_INTERVALS * ((t[-1] - t[0]) / (n - 1))))
    speeds = TWO_PI * r0_m * lines[1]
    return [float(x) if good else None for x, good in zip(speeds.tolist(), ok.tolist())]


@settings(max_examples=150, deadline=None)
@given(series=series, queries=st.lists(st.floats(-0.2, 2.5), min_size=1, max_size=12),
       r0=st.floats(0.2, 0.4))
def test_fast_wheel_speeds(series, queries, r0) -> None:  # type: ignore[no-untyped-def]
    from slipdaq.estimator.fast_slip import FastSlipRows

    times, values = series
    q = np.array(sorted(queries))
    want = wheel_speeds_numpy(ring_of(times, values), r0, q)
    for compiled_ in (True, False):
        with kernels(compiled_):
            assert FastSlipRows._wheel_speeds(ring_of(times, values), r0, q) == want


def slip_spread_numpy(ring: SeriesRing, t0: float, t1: float) -> float | None:
    """linear_region.slip_spread written with numpy and Python's sums (the code the spread kernel replaced)."""
    import math

    from slipdaq.estimator.linear_region import LOCAL_HALF, SPREAD_PARTS

    revs = ring.local_linear(np.linspace(t0, t1, SPREAD_PARTS + 1), LOCAL_HALF)
    if revs is None:
        return None
    r = revs.tolist()
    dt = (t1 - t0) / SPREAD_PARTS
    speeds = [(b - a) / dt for a, b in zip(r, r[1:])]
    mean = sum(speeds) / SPREAD_PARTS
    if not mean > 0:
        return None
    xs = [k - 0.5 * (SPREAD_PARTS - 1) for k in range(SPREAD_PARTS)]
    slope = sum(x * v for x, v in zip(xs, speeds)) / sum(x * x for x in xs)
    rss = sum((v - mean - slope * x) ** 2 for x, v in zip(xs, speeds))
    return math.sqrt(rss / SPREAD_PARTS) / mean


@settings(max_examples=300, deadline=None)
@given(series=series, t0=st.floats(-0.2, 2.0), span=st.floats(1e-6, 1.0))  # a window has a length
def test_slip_spread(series, t0, span) -> None:  # type: ignore[no-untyped-def]
    from slipdaq.estimator.linear_region import slip_spread

    times, values = series
    want = slip_spread_numpy(ring_of(times, values), t0, t0 + span)
    for compiled_ in (True, False):
        with kernels(compiled_):
            got = slip_spread(ring_of(times, values), t0, t0 + span)
            assert (got is None) == (want is None)
            if want is not None:
                assert got is not None and np.array_equal(np.float64(got), np.float64(want), equal_nan=True)
                assert math.copysign(1.0, got) == math.copysign(1.0, want)


def test_slip_spread_residuals_squared_as_python_squares() -> None:
    """Residuals whose square libm's pow and a multiplication round differently (1 value in about 1,200): the same
    spread as Python's ** (the kernel takes the power as an argument, so numba does not turn it into d * d)."""
    from slipdaq.estimator.linear_region import slip_spread

    rng = np.random.default_rng(7)
    t = np.cumsum(rng.uniform(0.0005, 0.0015, 20000))
    v = np.cumsum(rng.uniform(0.005, 0.02, 20000))
    ring = ring_of(t.tolist(), v.tolist())
    starts = rng.uniform(0.05, float(t[-1]) - 0.6, 3000).tolist()
    want = [slip_spread_numpy(ring, t0, t0 + 0.5) for t0 in starts]
    for compiled_ in (True, False):
        with kernels(compiled_):
            assert [slip_spread(ring, t0, t0 + 0.5) for t0 in starts] == want


@settings(max_examples=150, deadline=None)
@given(data=st.data(), capacity=st.sampled_from([4, 8, 64]), batches=st.integers(1, 6))
def test_wheel_windows_append_is_append_one_by_one(data, capacity, batches) -> None:  # type: ignore[no-untyped-def]
    """WheelWindows.append of batches of samples (some not kept, rings small enough to fill, drop_before set on the
    way) keeps in each ring the samples, last time and count dropped that SeriesRing.append one by one keeps; compiled
    and as Python."""
    from slipdaq.estimator.wheel_revolutions import WheelWindows

    cuts = []
    t = 0.0
    for _ in range(batches):
        n = data.draw(st.integers(1, 40))
        some = data.draw(st.lists(st.integers(0, 3), min_size=1, max_size=4, unique=True))  # one ring may fill alone
        wheel = np.array(data.draw(st.lists(st.sampled_from(some), min_size=n, max_size=n)), dtype=np.int64)
        keep = np.array(data.draw(st.lists(st.booleans(), min_size=n, max_size=n)), dtype=np.bool_)
        times = t + np.cumsum(data.draw(st.lists(st.floats(0.0, 0.01), min_size=n, max_size=n)))
        t = float(times[-1])
        start = data.draw(st.integers(0, n - 1))
        stop = data.draw(st.integers(start + 1, n))
        cuts.append((wheel, times, times * 3.0, keep, start, stop, data.draw(st.floats(0.0, t))))

    def state(rings: list[SeriesRing]) -> list[tuple[list[float], list[float], float, int]]:
        return [(r.times.tolist(), r.values.tolist(), r.last_t, r.dropped) for r in rings]

    want = [SeriesRing(capacity) for _ in range(4)]
    for wheel, times, revs, keep, start, stop, drop in cuts:
        for i in range(start, stop):
            if keep[i]:
                want[wheel[i]].append(float(times[i]), float(revs[i]))
        for r in want:
            r.drop_before = drop
    for compiled_ in (True, False):
        with kernels(compiled_):
            ww = WheelWindows()
            ww.rings[:] = [SeriesRing(capacity) for _ in range(4)]
            for wheel, times, revs, keep, start, stop, drop in cuts:
                ww.append(wheel, times, revs, keep, start, stop)
                ww.drop_before(drop)
            assert state(ww.rings) == state(want)
