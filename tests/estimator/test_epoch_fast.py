"""The estimator's readiness constants and arcs give what the code they replaced gives, bit for bit (random
inputs)."""

from __future__ import annotations

import math

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st

from slipdaq import WHEELS
from slipdaq.estimator import SlipEstimator
from slipdaq.estimator.gps_track import TIME_TOL_S
from slipdaq.records import GpsFix
from support.estimator_params import params


def _head_reference(est: SlipEstimator) -> tuple[int, float, float]:
    """_head_consts as before the UTC times were kept with the epochs: each smoothed arrival looked up in the ring."""

    def smooth(arrival_s: float) -> float:
        if est._utc_offset_s is None:
            return arrival_s
        utc = est._track.utc.values[int(np.searchsorted(est._track.utc.times, arrival_s))]
        return arrival_s if math.isnan(utc) else float(utc) + est._utc_offset_s

    lat = est.latency.latency_s
    arrival_s = est._pending[0][0]
    half = 0.5 * est.p.window_s
    t1 = smooth(arrival_s) - lat + half
    gps_last = smooth(est._track.last_t) - lat
    if gps_last < t1 - TIME_TOL_S:
        return (0, 0.0, 0.0)
    if gps_last >= t1 + max(est.p.window_s, 0.5):
        return (1, 0.0, 0.0)
    return (2, max(t1, arrival_s) if est.p.gps_latency_s is None else t1, t1 - 3 * half)


@settings(max_examples=200, deadline=None)
@given(
    fixes=st.lists(
        st.tuples(st.floats(0.02, 0.3), st.floats(-0.05, 0.2), st.sampled_from(["utc", "none"])),
        min_size=1, max_size=60,
    ),
    latency=st.sampled_from([None, 0.0, 0.08]),
    wheel_every=st.integers(1, 7),
)
def test_head_consts(fixes: list[tuple[float, float, str]], latency: float | None, wheel_every: int) -> None:
    """The head epoch's readiness constants, after every fix and estimate, equal the ring-based computation."""
    est = SlipEstimator(params(gps_latency_s=latency))
    t, rev = 1000.0, 0.0
    for k, (step, lag, utc_kind) in enumerate(fixes):
        for _ in range(int(step / 0.002)):
            t += 0.002
            rev += 0.02
            for w in range(len(WHEELS)):
                if k % wheel_every or w:  # now and then a wheel stays silent
                    est.add_wheel_at(w, t, rev)
        utc = round(t - 0.05 - lag, 2) if utc_kind == "utc" else None  # (a NaN UTC time fails the base too)
        est.add_gps(GpsFix(t, 10.0, utc))
        if est._pending:
            est._head = None
            assert est._head_consts() == _head_reference(est)


@settings(max_examples=200, deadline=None)
@given(
    samples=st.lists(st.tuples(st.integers(0, 3), st.floats(0.0, 0.02), st.floats(-0.01, 0.05)), max_size=200),
    window=st.tuples(st.floats(-0.1, 1.5), st.floats(0.0, 0.6)),
)
def test_arcs_m(samples: list[tuple[int, float, float]], window: tuple[float, float]) -> None:
    """All wheels' arcs over a window at once equal the arc wheel by wheel (np.interp on the ring's views)."""
    est = SlipEstimator(params())
    t, rev = [0.0] * 4, [0.0] * 4
    for w, dt, drev in samples:
        t[w] += dt
        rev[w] += drev
        est._windows.rings[w].append(t[w], rev[w])
    t0, width = window
    got = est._windows.arcs_m(t0, t0 + width)
    want = {w: _arc_reference(est._windows.by_wheel[w], t0, t0 + width) for w in WHEELS}
    assert repr(got) == repr(want)


def _arc_reference(ring, t0: float, t1: float) -> float | None:  # type: ignore[no-untyped-def]
    """One wheel's arc as the estimator computed it before arcs_m: np.interp on the ring's views."""
    if len(ring) < 2 or ring.first_time > t0 or ring.last_time < t1:
        return None
    times = ring.times.tolist()  # a gap in the samples around the window: withheld (windows.MIN_GAP_S, GAP_INTERVALS)
    first = max(i for i, t in enumerate(times) if t <= t0)
    last = min(i for i, t in enumerate(times) if t >= t1)
    mean = (times[-1] - times[0]) / (len(times) - 1)
    if max([b - a for a, b in zip(times[first:last + 1], times[first + 1:last + 1])] or [0.0]) > max(0.05, 4 * mean):
        return None
    rev0, rev1 = np.interp((t0, t1), ring.times, ring.values).tolist()
    return 2.0 * math.pi * (rev1 - rev0)
