"""numpy's np.interp and np.sum written out for kernels (estimator/numpy_rules.py), and the per-fix kernels built on
them (the GPS distance, a wheel's arc over a window, the latency rows' revolutions), compiled and as Python, against
numpy written the plain way (the code the kernels replaced): the same bits."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from slipdaq.estimator.gps_track import integrate_speed_m
from slipdaq.estimator.latency import LOCAL_FIT_HALF_SAMPLES, ring_revolutions
from slipdaq.estimator.numpy_rules import interp_into, pairwise_sum
from slipdaq.estimator.ring import LINE_CACHE_SIZE, SeriesRing, new_line_cache
from slipdaq.estimator.wheel_revolutions import GAP_INTERVALS, MIN_GAP_S, TWO_PI, WheelWindows
from support.paths import kernels


def bits(x: float) -> str:
    return "nan" if math.isnan(x) else float(x).hex()


def both(fn):  # type: ignore[no-untyped-def]
    """fn() compiled and as Python."""
    out = []
    for compiled_ in (True, False):
        with kernels(compiled_):
            out.append(fn())
    return out


@pytest.mark.parametrize("n", [0, 1, 7, 8, 9, 15, 16, 17, 127, 128, 129, 255, 256, 257, 1000, 1029, 4096, 10001])
def test_pairwise_sum_is_np_sum(n: int) -> None:
    rng = np.random.default_rng(n)
    for _ in range(20):
        a = rng.normal(size=n) * 10.0 ** rng.uniform(-8, 8, size=n)
        assert bits(pairwise_sum(a)) == bits(float(np.sum(a)))
    assert bits(pairwise_sum(np.full(n, -0.0))) == bits(float(np.sum(np.full(n, -0.0))))


floats = st.floats(-1e3, 1e3, allow_nan=False, allow_infinity=False)


@pytest.mark.filterwarnings("ignore:overflow encountered in scalar divide:RuntimeWarning")  # the Python kernel's
# numpy scalars, at the extreme floats drawn here, say what np.interp's C code does silently: the same value
@settings(max_examples=300, deadline=None)
@given(xp=st.lists(floats, min_size=1, max_size=40), fp_seed=st.integers(0, 2**31),
       x=st.lists(st.one_of(floats, st.just(math.nan)), min_size=1, max_size=30),
       order=st.sampled_from(["sorted", "as drawn", "ties"]))
def test_interp_is_np_interp(xp, fp_seed, x, order) -> None:  # type: ignore[no-untyped-def]
    """Sorted, unsorted and tied sample times, NaN and exact hits, an infinite value: np.interp's bits."""
    xs = np.array(sorted(xp) if order != "as drawn" else xp)
    if order == "ties" and len(xs) > 2:
        xs[1] = xs[0]
    rng = np.random.default_rng(fp_seed)
    fs = rng.normal(size=len(xs)) * 100.0
    if fp_seed % 5 == 0:
        fs[fp_seed % len(fs)] = np.inf
    q = np.array(x + [float(xs[fp_seed % len(xs)])])
    out = np.empty(len(q))
    with np.errstate(invalid="ignore"):
        interp_into(q, xs, fs, out)
        want = np.interp(q, xs, fs)
    assert [bits(a) for a in out] == [bits(b) for b in want]


def integrate_numpy(times_s: np.ndarray, speeds_mps: np.ndarray, t0: float, t1: float) -> float:
    """integrate_speed_m as numpy had it."""
    i0 = int(np.searchsorted(times_s, t0, side="right"))
    i1 = int(np.searchsorted(times_s, t1, side="left"))
    t = np.concatenate(([t0], times_s[i0:i1], [t1]))
    v = np.interp(t, times_s, speeds_mps)
    return float(np.sum((t[1:] - t[:-1]) * (v[1:] + v[:-1])) * 0.5)


@settings(max_examples=300, deadline=None)
@given(steps=st.lists(st.floats(0.001, 0.3), min_size=2, max_size=300), seed=st.integers(0, 2**31),
       epoch=st.sampled_from([0.0, 1.767e9]), start=st.floats(-0.5, 2.0), width=st.floats(0.0, 3.0),
       shuffled=st.booleans())
def test_gps_distance(steps, seed, epoch, start, width, shuffled) -> None:  # type: ignore[no-untyped-def]
    times = epoch + np.cumsum(steps)
    if shuffled:  # fix times out of order: whatever numpy made of them
        np.random.default_rng(seed).shuffle(times)
    speeds = np.random.default_rng(seed).uniform(0.0, 40.0, size=len(times))
    t0 = epoch + start
    for t1 in (t0 + width, float(times[seed % len(times)])):
        want = integrate_numpy(times, speeds, t0, t1)
        got = both(lambda: integrate_speed_m(times, speeds, t0, t1))  # noqa: B023
        assert [bits(g) for g in got] == [bits(want)] * 2
        assert all(type(g) is float for g in got)


def ring_of(times: np.ndarray, values: np.ndarray, drop_before: float) -> SeriesRing:
    r = SeriesRing(8)  # small: the kept samples move and the arrays grow on the way
    r.drop_before = drop_before
    for t, v in zip(times.tolist(), values.tolist()):
        r.append(t, v)
    return r


def has_gap(ring: SeriesRing, t0: float, t1: float) -> bool:
    """The samples spanning [t0, t1] have an interval over max(MIN_GAP_S, GAP_INTERVALS * the mean interval), as
    numpy had it."""
    t = ring.times
    i = max(int(t.searchsorted(t0, "right")) - 1, 0)
    j = min(int(t.searchsorted(t1, "left")) + 1, len(t))
    longest = float(np.diff(t[i:j]).max()) if j - i >= 2 else 0.0
    return longest > max(MIN_GAP_S, GAP_INTERVALS * ((ring.last_t - float(t[0])) / (len(t) - 1)))


def window_numpy(ring: SeriesRing, t0: float, t1: float) -> tuple[float | None, bool]:
    """One wheel's (arc, gap) of WheelWindows.window as numpy had it (np.interp at both ends, then the gap)."""
    t, v = ring.times, ring.values
    if len(t) < 2 or t[0] > t0 or ring.last_t < t1:
        return None, bool(len(ring) and ring.first_time <= t0 and ring.last_t < t1)
    revs = np.interp(np.array((t0, t1)), t, v).tolist()
    if has_gap(ring, t0, t1):
        return None, True
    return TWO_PI * (revs[1] - revs[0]), False


samples = st.lists(st.tuples(st.floats(0.0, 0.03), st.floats(0.0, 0.05)), min_size=0, max_size=80)


@settings(max_examples=300, deadline=None)
@given(wheels=st.lists(samples, min_size=4, max_size=4), stall=st.floats(0.0, 1.0), epoch=st.sampled_from([0.0, 1.767e9]),
       start=st.floats(-0.1, 1.1), width=st.floats(0.0, 1.2), drop=st.floats(0.0, 0.5))
def test_window_arcs(wheels, stall, epoch, start, width, drop) -> None:  # type: ignore[no-untyped-def]
    """Rings with and without a stall (a 0.2 s interval), windows across their ends (start, width: fractions of the
    second wheel's span, its stall inside or not): each wheel's arc (a Python float) and whether its gap disturbs the
    window, as numpy had them."""
    rings = []
    for k, steps in enumerate(wheels):
        dt = np.array([s[0] for s in steps])
        if k == 1 and len(dt):
            dt[int(stall * (len(dt) - 1))] = 0.2
        times = epoch + np.cumsum(dt)
        span = (times[0], times[-1]) if k == 1 and len(times) else (epoch, epoch + 1.0)
        rings.append(ring_of(times, np.cumsum([s[1] for s in steps]), times[int(drop * (len(times) - 1))]
                             if len(times) else epoch))
    first, length = span[0], max(span[1] - span[0], 1e-3)
    t0 = first + start * length
    t1 = t0 + width * length

    def window() -> tuple[dict[str, float | None], tuple[str, ...]]:
        ww = WheelWindows()
        ww.rings[:] = rings
        ww.by_wheel = dict(zip(ww.by_wheel, rings))
        return ww.window(t0, t1)

    want = {w: window_numpy(r, t0, t1) for w, r in zip(("FL", "FR", "RL", "RR"), rings)}
    for arcs, gaps in both(window):
        assert {w: (None if a is None else bits(a)) for w, a in arcs.items()} == \
            {w: (None if a is None else bits(a)) for w, (a, _) in want.items()}
        assert all(a is None or type(a) is float for a in arcs.values())
        assert gaps == tuple(w for w, (_, gap) in want.items() if gap)


def test_window_arcs_cover_each_answer() -> None:
    """A 1 kHz wheel with a stall: an arc, a gap across the stall, a stall at the end, no samples before the
    window."""
    times = 100.0 + np.arange(2000) * 0.001
    times[1200:] += 0.3  # no samples from 101.2 to 101.5
    ring = ring_of(times, np.arange(2000) * 0.01, 0.0)
    cases = {(100.2, 101.0): "arc", (101.0, 101.8): "gap", (101.6, 102.9): "stalled", (99.0, 100.5): "none"}
    for (t0, t1), kind in cases.items():
        arc, gap = window_numpy(ring, t0, t1)
        assert kind == ("arc" if arc is not None else "gap" if gap and t1 < ring.last_t else "stalled" if gap
                        else "none")

        def window() -> tuple[dict[str, float | None], tuple[str, ...]]:
            ww = WheelWindows()
            ww.rings[0] = ring
            ww.by_wheel["FL"] = ring
            return ww.window(t0, t1)  # noqa: B023

        for arcs, gaps in both(window):
            assert (arcs["FL"] is None or bits(arcs["FL"])) == (arc is None or bits(arc))
            assert ("FL" in gaps) == gap


def revolutions_numpy(rings: list[SeriesRing], times: np.ndarray, first_needed_s: float, arrival_s: float
                      ) -> np.ndarray | None:
    """WheelLatencyRows.observe's arcs before the 2*pi/n, as numpy had them."""
    arcs = None
    for ring in rings:
        if len(ring) < 2 or ring.first_time > first_needed_s or ring.last_t < arrival_s \
                or has_gap(ring, times[-1], times[0]):
            return None
        revs = ring.local_linear(times, LOCAL_FIT_HALF_SAMPLES)
        if revs is None:
            return None
        if arcs is None:
            arcs = revs + 0.0
        else:
            arcs += revs
    return arcs


@settings(max_examples=200, deadline=None)
@given(wheels=st.lists(samples, min_size=1, max_size=4), stall=st.integers(0, 80), arrival=st.floats(0.0, 2.0),
       lags=st.integers(1, 40), zero=st.booleans())
def test_latency_rows_revolutions(wheels, stall, arrival, lags, zero) -> None:  # type: ignore[no-untyped-def]
    rings = []
    for k, steps in enumerate(wheels):
        dt = np.array([s[0] for s in steps])
        if k == 0 and stall < len(dt):
            dt[stall] = 0.2
        revs = np.cumsum([s[1] for s in steps])
        rings.append(ring_of(np.cumsum(dt), -0.0 * revs if zero else revs, 0.0))
    times = arrival - np.linspace(-0.02, 0.3, lags)
    first_needed = times[-1] - 0.5
    want = revolutions_numpy(rings, times, first_needed, arrival)

    def revolutions() -> np.ndarray | None:
        arcs = np.empty(len(times))
        add = ring_revolutions()
        for k, r in enumerate(rings):
            if not add(r.times, r.values, times, first_needed, arrival, LOCAL_FIT_HALF_SAMPLES, arcs, k == 0,
                       r.dropped, *new_line_cache(LINE_CACHE_SIZE)):  # a cache of its own: every line computed here
                return None
        return arcs

    for got in both(revolutions):
        if want is None:
            assert got is None
        else:
            assert got is not None and [bits(a) for a in got] == [bits(b) for b in want]


def test_latency_rows_revolutions_stall_inside_and_outside_the_lags() -> None:
    """Two 1 kHz reference wheels, one with a 0.2 s stall: no revolutions while the stall is between the lagged
    times, the lines' revolutions of both wheels once it is older than them."""
    times_s = 100.0 + np.arange(4000) * 0.001
    stalled = times_s.copy()
    stalled[2000:] += 0.2  # no samples from 102.0 to 102.2
    rings = [ring_of(times_s, np.arange(4000) * 0.011, 0.0), ring_of(stalled, np.arange(4000) * 0.012, 0.0)]
    lags = np.linspace(-0.02, 0.3, 33)
    for arrival, inside in ((102.25, True), (103.5, False)):
        times = arrival - lags
        first_needed = times[-1] - 0.5
        want = revolutions_numpy(rings, times, first_needed, arrival)
        assert (want is None) == inside

        def revolutions() -> np.ndarray | None:
            arcs = np.empty(len(times))  # noqa: B023
            add = ring_revolutions()
            for k, r in enumerate(rings):
                if not add(r.times, r.values, times, first_needed, arrival,  # noqa: B023
                           LOCAL_FIT_HALF_SAMPLES, arcs, k == 0, r.dropped, *new_line_cache(LINE_CACHE_SIZE)):
                    return None
            return arcs

        for got in both(revolutions):
            assert (got is None) == inside
            if got is not None and want is not None:
                assert [bits(a) for a in got] == [bits(b) for b in want]


@pytest.mark.parametrize("cache_size", [1, 8, LINE_CACHE_SIZE])
def test_latency_rows_revolutions_with_each_rings_line_cache(cache_size: int) -> None:
    """Fix after fix, 50 ms apart, over two jittered 1 kHz reference wheels whose small rings drop their old samples
    and move the rest on the way, each ring's line cache kept from fix to fix as WheelLatencyRows keeps it (of one
    line, of 8, whose slots the lines take from each other, and the ring's own): every fix's revolutions the bits of
    lines computed afresh (revolutions_numpy), compiled and as Python."""
    rng = np.random.default_rng(cache_size)
    n = 2400
    series = [(100.0 + np.cumsum(0.001 + rng.uniform(-3e-4, 3e-4, n)), np.cumsum(rng.uniform(0.010, 0.012, n)))
              for _ in range(2)]
    lags = np.linspace(-0.02, 0.3, 321)
    for compiled_ in (True, False):
        with kernels(compiled_):
            rings = [SeriesRing(64) for _ in series]
            caches = [r.line_cache(LOCAL_FIT_HALF_SAMPLES, len(lags)) if cache_size == LINE_CACHE_SIZE
                      else new_line_cache(cache_size) for r in rings]
            add = ring_revolutions()
            checked = dropped = 0
            for end in range(50, n + 1, 50):
                for ring, (t, v) in zip(rings, series):
                    ring.drop_before = float(t[end - 1]) - 0.9
                    ring.extend(t[end - 50:end], v[end - 50:end])
                arrival = min(r.last_t for r in rings) - 0.002
                times = arrival - lags
                first_needed = times[-1] - 0.5
                want = revolutions_numpy(rings, times, first_needed, arrival)
                arcs = np.empty(len(times))
                got: np.ndarray | None = arcs
                for k, (r, cache) in enumerate(zip(rings, caches)):
                    if not add(r.times, r.values, times, first_needed, arrival, LOCAL_FIT_HALF_SAMPLES, arcs, k == 0,
                               r.dropped, *cache):
                        got = None
                        break
                assert (got is None) == (want is None)
                if got is not None and want is not None:
                    assert [bits(a) for a in got] == [bits(b) for b in want]
                    checked += 1
                dropped = rings[0].dropped
            assert checked >= 30 and dropped > 0  # the lines outlived moves of the rings' samples


def test_line_cache_holds_twice_a_calls_lines() -> None:
    """A ring's line cache has room for twice the lines of a call (the latency rows' lagged times: about 420 with the
    default max_latency_s, 2,021 with the largest), so that a call's lines do not take each other's slots; it grows
    when a call asks for more, and is kept otherwise."""
    ring = SeriesRing(8)
    keys, lines = ring.line_cache(LOCAL_FIT_HALF_SAMPLES, 421)
    assert len(keys) == LINE_CACHE_SIZE and lines.shape == (LINE_CACHE_SIZE, 3) and (keys == -1).all()
    bigger, _ = ring.line_cache(LOCAL_FIT_HALF_SAMPLES, 2021)
    assert len(bigger) == 4096
    assert ring.line_cache(LOCAL_FIT_HALF_SAMPLES, 10)[0] is bigger
    assert ring.line_cache(2, 10)[0] is not bigger  # another line length: a cache of its own
