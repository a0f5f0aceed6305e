"""Batched ingest gives what one-by-one processing (tests/reference_readiness.py) gives, bit for bit, wherever the
batches are cut, with the readiness kernel compiled or interpreted."""

from __future__ import annotations

import functools

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from slipdaq import WHEELS
from slipdaq.config import load_config
from slipdaq.decode.can_wheels import WheelDecoder
from slipdaq.decode.nmea import NmeaDecoder
from slipdaq.estimator import EstimatorParams, SlipEstimator
from slipdaq.estimator.ring import SeriesRing
from slipdaq.records import CanFrame, NmeaLine
from slipdaq.sim.emit import SimSettings, generate
from support.paths import CONFIG, kernels
from support.reference_readiness import ReferenceEstimator

GPS_OUTAGE_S = (6.0, 8.0)
"""Sim time without NMEA: the estimator goes on the wheels' clock, then GPS comes back."""
RR_SILENT_S = (3.0, 4.0)
WHEEL_DELAY_S = (0.0, 0.012, 0.031, 0.047)


@functools.cache
def _stream() -> tuple[object, list[tuple]]:
    """A drive as estimator input: ('w', wheel index, t, revolutions) and ('g', GpsFix), in record order."""
    cfg = load_config(CONFIG)
    wheels, nmea = WheelDecoder(cfg), NmeaDecoder()
    items: list[tuple] = []
    t0 = None
    for ev in generate(cfg, "cycle", "paved", SimSettings(wpt_rate_hz=100.0, gps_rate_hz=10.0), duration_s=14.0):
        r = ev.record
        if isinstance(r, CanFrame):
            for s in wheels.decode(r):
                items.append(("w", WHEELS.index(s.wheel), s.timestamp_s, s.revolutions))
        elif isinstance(r, NmeaLine):
            t0 = r.timestamp_s - ev.time_s if t0 is None else t0
            if GPS_OUTAGE_S[0] <= ev.time_s < GPS_OUTAGE_S[1]:
                continue
            fix = nmea.decode(r)
            if fix is not None:
                items.append(("g", fix))
    # Records in the order a busy loop might see them: each wheel's frames up to WHEEL_DELAY_S behind the GPS, so
    # that estimates wait for wheels (and are released by a wheel sample in the middle of a batch); RR silent for
    # a while (it stops and starts reporting); a few samples out of order (skipped, in bulk too).
    keyed = []
    for n, it in enumerate(items):
        if it[0] == "w":
            w, t = it[1], it[2]
            if w == 3 and RR_SILENT_S[0] <= t - t0 < RR_SILENT_S[1]:
                continue
            keyed.append((t + WHEEL_DELAY_S[w], n, it))
        else:
            keyed.append((it[1].timestamp_s, n, it))
    keyed.sort(key=lambda k: (k[0], k[1]))
    items = [k[2] for k in keyed]
    for k in range(300, len(items), 997):
        if items[k][0] == "w":
            _, w, t, rev = items[k]
            items[k] = ("w", w, t - 0.05, rev)
    return EstimatorParams.from_config(cfg), items


def _one_by_one(params, items) -> tuple[SlipEstimator, list]:  # type: ignore[no-untyped-def]
    """(index of the releasing item, estimate) for every estimate."""
    est = ReferenceEstimator(params)
    out: list = []
    for i, it in enumerate(items):
        out += [(i, e) for e in (est.add_wheel_at(it[1], it[2], it[3]) if it[0] == "w" else est.add_gps(it[1]))]
    return est, out


@functools.cache
def _reference() -> tuple[SlipEstimator, str]:
    params, items = _stream()
    est, out = _one_by_one(params, items)
    return est, repr(out)


def _batched(params, items, cuts: set[int], jit: bool) -> tuple[SlipEstimator, list]:  # type: ignore[no-untyped-def]
    with kernels(jit):
        return _batched_now(params, items, cuts)


def _batched_now(params, items, cuts: set[int]) -> tuple[SlipEstimator, list]:  # type: ignore[no-untyped-def]
    est = SlipEstimator(params)
    out: list = []
    run: list[tuple] = []
    first = 0  # item index of run[0]

    def flush() -> None:
        nonlocal out
        if run:
            w = np.array([r[1] for r in run], dtype=np.int64)
            t = np.array([r[2] for r in run], dtype=np.float64)
            v = np.array([r[3] for r in run], dtype=np.float64)
            out += [(first + i, e) for i, e in est.add_wheels(w, t, v)]
            run.clear()

    for i, it in enumerate(items):
        if i in cuts:
            flush()
        if it[0] == "w":
            if not run:
                first = i
            run.append(it)
        else:
            flush()
            out += [(i, e) for e in est.add_gps(it[1])]
    flush()
    return est, out


def _rings_equal(a: SeriesRing, b: SeriesRing) -> bool:
    return (a.times.tobytes() == b.times.tobytes() and a.values.tobytes() == b.values.tobytes()
            and a.last_time == b.last_time)


def test_reference_stream_has_estimates_on_both_clocks() -> None:
    _, out = _one_by_one(*_stream())
    sources = {e.source for _, e in out}
    assert len(out) > 100 and sources == {"gps", "wheels"}
    items = _stream()[1]
    by_wheel = sum(items[i][0] == "w" for i, e in out if e.source == "gps")
    assert by_wheel > 50  # released by a wheel sample, not by the fix


@settings(max_examples=25, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(
    cut_every=st.lists(st.integers(min_value=1, max_value=700), min_size=1, max_size=40),
    jit=st.booleans(),
)
def test_estimates_do_not_depend_on_where_batches_are_cut(cut_every: list[int], jit: bool) -> None:
    params, items = _stream()
    cuts, pos = set(), 0
    while pos < len(items):
        for step in cut_every:
            pos += step
            cuts.add(pos)
    ref_est, ref = _reference()
    est, out = _batched(params, items, cuts, jit)
    assert repr(out) == ref  # the same releasing items, every field bit for bit (repr of a float is exact)
    for w in WHEELS:
        assert _rings_equal(est._windows.by_wheel[w], ref_est._windows.by_wheel[w])


@pytest.mark.parametrize("jit", [True, False])
def test_one_batch_per_gps_interval_equals_one_by_one(jit: bool) -> None:
    params, items = _stream()
    _, out = _batched(params, items, set(), jit)
    assert repr(out) == _reference()[1]


def test_ring_extend_equals_appends() -> None:
    rng = np.random.default_rng(3)
    a, b = SeriesRing(8), SeriesRing(8)
    t = 0.0
    for _ in range(200):
        n = int(rng.integers(0, 20))
        ts = t + np.cumsum(rng.random(n))
        vs = rng.random(n)
        t = float(ts[-1]) if n else t
        a.drop_before = b.drop_before = t - 10.0
        for x, y in zip(ts.tolist(), vs.tolist()):
            a.append(x, y)
        b.extend(ts, vs)
        assert _rings_equal(a, b) and len(a._t) == len(b._t)
