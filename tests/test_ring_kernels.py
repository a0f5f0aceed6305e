"""The sample rings' kernels (estimator/ring.py), compiled and as Python, against numpy written the plain way."""

from __future__ import annotations

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st

from conftest import kernels
from slipdaq.estimator.ring import SeriesRing


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


@settings(max_examples=150, deadline=None)
@given(series=series, queries=st.lists(st.floats(-0.2, 2.5), min_size=1, max_size=50), half=st.integers(0, 6))
def test_local_quadratic(series, queries, half) -> None:  # type: ignore[no-untyped-def]
    times, values = series
    q = np.array(sorted(queries, reverse=True))
    got, lines = [], None
    for compiled_ in (True, False):
        with kernels(compiled_):
            got.append(ring_of(times, values).local_quadratic(q, half))
            lines = ring_of(times, values).local_linear(q, half)
    if len(times) < 2 * half + 1:
        assert got == [None, None]
        return
    assert got[0] is not None and got[1] is not None and lines is not None
    assert np.array_equal(got[0], got[1])  # compiled and Python: the same bits
    t, v = np.array(times), np.array(values)
    for k, x in enumerate(q.tolist()):
        c = min(max(int(t.searchsorted(x)), half), len(t) - half - 1)
        tt, vv = t[c - half: c + half + 1] - t[c], v[c - half: c + half + 1]
        vander = np.vander(tt / max(np.abs(tt).max(), 1e-300), 3)
        if len(np.unique(tt)) >= 3 and np.linalg.cond(vander) < 1e3:  # a parabola well determined: numpy's
            want = float(np.polyval(np.polyfit(tt, vv, 2), x - t[c]))
            assert abs(got[0][k] - want) <= 1e-6 * (1.0 + abs(want) + abs(vv).max())
        elif len(np.unique(tt)) < 3:  # too few instants for a parabola: the line
            assert abs(got[0][k] - lines[k]) <= 1e-9 * (1.0 + abs(lines[k]))


def test_local_quadratic_is_exact_under_a_steady_acceleration_where_a_line_is_not() -> None:
    """Revolutions of a wheel accelerating steadily, sampled at 25 Hz with jitter: the parabola gives them at any
    instant; the line is off by an amount that depends on where the instant falls between samples."""
    rng = np.random.default_rng(3)
    t = np.arange(0.0, 2.0, 0.04) + rng.uniform(0.0, 0.002, 50)
    revs = 5.0 * t + 0.8 * t**2
    ring = ring_of(t.tolist(), revs.tolist())
    x = np.linspace(1.5, 0.5, 101)
    quad, line = ring.local_quadratic(x, 5), ring.local_linear(x, 5)
    assert quad is not None and line is not None
    truth = 5.0 * x + 0.8 * x**2
    assert np.abs(quad - truth).max() < 1e-9
    assert np.abs(line - truth).max() > 1e-3
