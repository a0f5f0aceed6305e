"""The wheel decoder (numpy layouts, cantools, the unwrap kernel interpreted and compiled) against the rule written
frame by frame (tests/reference_wheels.py), and Pipeline.process_can_batch against the one-by-one path, on random
streams."""

from __future__ import annotations

import functools
import inspect
import random
import struct
from pathlib import Path

from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from slipdaq.config import Config, load_config
from slipdaq.decode.can_wheels import WheelDecoder
from slipdaq.pipeline import Pipeline
from slipdaq.records import CanFrame, CanFrameBatch
from slipdaq.sim.emit import SimSettings, generate
from slipdaq.sinks import Sink
from support.paths import CONFIG, ROOT, kernels, write_config
from support.reference_wheels import ReferenceWheelDecoder

MIXED_DBC = (ROOT / "config" / "wpt.dbc").read_text() + '''
BO_ 800 WPT_RL_SMALL: 8 WPT_NODE
 SG_ Count16 : 8|16@1+ (1,0) [0|65535] "pulses" SLIPDAQ
 SG_ Seq4 : 60|4@1+ (1,0) [0|15] "" SLIPDAQ

BO_ 801 WHEEL_SPEED_RR: 8 ABS
 SG_ SPEED_RR : 0|16@1+ (0.01,0) [0|655] "km/h" SLIPDAQ
'''
MIXED_CONFIG = '''[wheels.RL]
kind = "count"
message = "WPT_RL_SMALL"
signal = "Count16"
seq_signal = "Seq4"
[wheels.RR]
kind = "speed"
message = "WHEEL_SPEED_RR"
signal = "SPEED_RR"
[can]
dbc = "wpt.dbc"
'''


def _random_frames(seed: int, n: int = 1500) -> list[CanFrame]:
    """WPT-like traffic with every oddity: wraps at 2^32 (and 2^16), Seq gaps, counter resets (jumps), backwards
    rolling, wrong DLC, excess bytes, unknown and extended IDs, error frames, repeated and backwards timestamps."""
    rng = random.Random(seed)
    count = {784: 2**32 - 300, 785: 17, 786: 2**31, 787: 2**32 - 1, 800: 65000}
    seq = {k: rng.randrange(256) for k in count}
    t = 1000.0
    out = []
    for _ in range(n):
        t += rng.choice([0.00025, 0.00025, 0.0005, 0.0, -0.0001, 0.002, 0.3])
        r = rng.random()
        if r < 0.04:
            out.append(CanFrame(t, rng.choice([0x123, 0x7FF, 0x0]), bytes(rng.randrange(256) for _ in range(8))))
            continue
        if r < 0.06:
            out.append(CanFrame(t, 0x20000080, bytes(4), is_error_frame=True, is_extended_id=True))
            continue
        if r < 0.07:
            out.append(CanFrame(t, 784, bytes(8), is_extended_id=True))
            continue
        fid = rng.choice([784, 785, 786, 787, 800, 801])
        if fid == 801:
            data = struct.pack("<H", rng.randrange(0, 12000)) + bytes(6)
        else:
            step = rng.choice([0, 3, 5, 8, 12, -2, 40])
            if rng.random() < 0.005:
                step = rng.choice([50000, -90000, 2**31])  # counter resets
            count[fid] = (count[fid] + step) % (2**16 if fid == 800 else 2**32)
            seq[fid] = (seq[fid] + rng.choice([1, 1, 1, 1, 2, 5, 0])) % 256
            if fid == 800:
                data = bytes([0]) + struct.pack("<H", count[fid]) + bytes(4) + bytes([(seq[fid] % 16) << 4])
            else:
                data = struct.pack("<I", count[fid]) + bytes(3) + bytes([seq[fid]])
        d = rng.random()
        if d < 0.02:
            data = data[:7]  # wrong DLC
        elif d < 0.03:
            data = data + bytes(4)  # excess bytes: cantools decodes the first 8
        out.append(CanFrame(t, fid, data))
    return out


@functools.cache
def _configs() -> dict[str, Config]:
    import tempfile
    d = Path(tempfile.mkdtemp(prefix="slipdaq-batch-"))
    return {"wpt": load_config(CONFIG), "mixed": load_config(write_config(d, MIXED_CONFIG, dbc=MIXED_DBC))}


def _cuts(rng: random.Random, n: int, max_len: int) -> list[tuple[int, int]]:
    out, i = [], 0
    while i < n:
        j = min(n, i + rng.randint(1, max_len))
        out.append((i, j))
        i = j
    return out


def _counters(dec: WheelDecoder) -> tuple:
    return (dec.frames, dec.lost_frames, dec.count_wraps, dec.counter_resets, dec.bad_frames)


def test_fast_layout_only_for_simple_signals() -> None:
    assert WheelDecoder(_configs()["wpt"]).fast_messages == ["WPT_FL", "WPT_FR", "WPT_RL", "WPT_RR"]
    assert WheelDecoder(_configs()["mixed"]).fast_messages == ["WPT_FL", "WPT_FR"]  # Seq4 and km/h: cantools


@settings(max_examples=20, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(seed=st.integers(0, 2**31), cut_seed=st.integers(0, 2**31), max_len=st.sampled_from([1, 7, 64, 600]),
       config=st.sampled_from(["wpt", "mixed"]), jit=st.booleans())
def test_decode_batch_equals_reference(seed: int, cut_seed: int, max_len: int, config: str, jit: bool) -> None:
    """Any cut into batches, the kernel compiled or interpreted: the reference's samples and counters."""
    cfg = _configs()[config]
    frames = _random_frames(seed)
    one, many = ReferenceWheelDecoder(cfg), WheelDecoder(cfg)
    ref = [s for f in frames for s in one.decode(f)]
    got = []
    with kernels(jit):
        for i, j in _cuts(random.Random(cut_seed), len(frames), max_len):
            b = many.decode_batch(CanFrameBatch.from_frames(frames[i:j]))
            assert all(0 <= k < j - i for k in b.frame.tolist())
            got += list(b.samples(("FL", "FR", "RL", "RR")))
    assert repr(got) == repr(ref)
    assert _counters(many) == _counters(one)


def test_random_frames_have_every_oddity() -> None:
    for config in ("wpt", "mixed"):
        dec = ReferenceWheelDecoder(_configs()[config])
        for f in _random_frames(0):
            dec.decode(f)
        for counter in (dec.counter_resets, dec.count_wraps, dec.lost_frames):
            assert sum(counter.values()) > 0
        assert dec.bad_frames > 0


class _Recorder(Sink):
    """Every call a sink gets, with its log time (batch sinks are expanded to records by the pipeline)."""

    def __init__(self) -> None:
        self.calls: list[tuple] = []

    def on_raw(self, r) -> None:  # type: ignore[no-untyped-def]
        self.calls.append(("raw", r))

    def on_wheel(self, s) -> None:  # type: ignore[no-untyped-def]
        self.calls.append(("wheel", s))

    def on_fix(self, f) -> None:  # type: ignore[no-untyped-def]
        self.calls.append(("fix", f))

    def on_estimate(self, e, t) -> None:  # type: ignore[no-untyped-def]
        self.calls.append(("estimate", e, t))

    def on_diagnostics(self, d, t) -> None:  # type: ignore[no-untyped-def]
        self.calls.append(("diagnostics", d, t))


@functools.cache
def _drive() -> list:
    cfg = _configs()["wpt"]
    return [ev.record for ev in generate(cfg, "cycle", "paved", SimSettings(wpt_rate_hz=250.0, gps_rate_hz=10.0),
                                         duration_s=12.0) if ev.record is not None]


def _run(records: list, cuts: list[tuple[int, int]] | None) -> tuple[list, Pipeline]:
    sink = _Recorder()
    p = Pipeline(_configs()["wpt"], [sink])
    if cuts is None:
        for r in records:
            p.process(r)
    else:
        for i, j in cuts:
            p.process_can_batch(records[i:j]) if isinstance(records[i], CanFrame) else p.process(records[i])
    p.finish()
    return sink.calls, p


@settings(max_examples=8, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(cut_seed=st.integers(0, 2**31), max_len=st.sampled_from([3, 50, 400, 5000]))
def test_pipeline_batches_equal_records(cut_seed: int, max_len: int) -> None:
    records = _drive()
    rng = random.Random(cut_seed)
    cuts: list[tuple[int, int]] = []  # runs of CAN frames, cut at random; NMEA lines one by one
    i = 0
    while i < len(records):
        if not isinstance(records[i], CanFrame):
            cuts.append((i, i + 1))
            i += 1
            continue
        j = i
        while j < len(records) and isinstance(records[j], CanFrame) and j - i < rng.randint(1, max_len):
            j += 1
        cuts.append((i, j))
        i = j
    ref, p_ref = _run(records, None)
    got, p = _run(records, cuts)
    for kind in ("raw", "wheel", "fix", "estimate", "diagnostics"):  # a batch's records come before its samples
        assert repr([c for c in got if c[0] == kind]) == repr([c for c in ref if c[0] == kind])
    assert p.diagnostics() == p_ref.diagnostics()
    assert sum(c[0] == "estimate" for c in ref) > 50 and sum(c[0] == "diagnostics" for c in ref) >= 10


@functools.cache
def _odd_drive() -> list:
    """The drive with _random_frames' oddities mixed in (at the drive's times): resets, wraps, Seq gaps, bad DLC,
    unknown, extended and error frames; the CAN frames come 150 ms after the GPS lines of their time, so that wheel
    frames release estimates (in the middle of a batch)."""
    odd = iter(_random_frames(3, n=4000))
    out: list = []
    for k, r in enumerate(_drive()):
        out.append(r)
        if k % 3 == 0:
            f = next(odd, None)
            if f is not None:
                out.append(CanFrame(r.timestamp_s, f.arbitration_id, f.data, f.is_extended_id, f.is_error_frame))
    order = sorted(range(len(out)), key=lambda k: (out[k].timestamp_s + (0.15 if isinstance(out[k], CanFrame) else 0),
                                                    k))
    return [out[k] for k in order]


def _items(records: list, rng: random.Random, max_len: int, as_batches: bool) -> list:
    """Runs of CAN frames cut at random (as CanFrameBatch or lists), the other records one by one."""
    items: list = []
    i = 0
    while i < len(records):
        if not isinstance(records[i], CanFrame):
            items.append(records[i])
            i += 1
            continue
        j = i
        limit = rng.randint(1, max_len)
        while j < len(records) and isinstance(records[j], CanFrame) and j - i < limit:
            j += 1
        run = list(records[i:j])
        items.append(CanFrameBatch.from_frames(run) if as_batches else run)
        i = j
    return items


@settings(max_examples=10, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(cut_seed=st.integers(0, 2**31), max_len=st.sampled_from([20, 120, 700]),
       config=st.sampled_from(["wpt", "mixed"]), odd=st.booleans(), merge=st.sampled_from([40, 8192]),
       as_batches=st.booleans(), run_len=st.sampled_from([1, 7, 300]))
def test_process_all_makes_the_same_calls_in_the_same_order(cut_seed: int, max_len: int, config: str, odd: bool,
                                                            merge: int, as_batches: bool, run_len: int) -> None:
    """Pipeline.process_all (consecutive batches decoded and estimated as one) against feeding the same items one
    by one: every sink call in the same order, and the same counters."""
    import slipdaq.pipeline as pipeline_module

    records = _odd_drive() if odd else _drive()
    rng = random.Random(cut_seed)
    items = _items(records, rng, max_len, as_batches)
    cfg = _configs()[config]
    ref_sink, got_sink = _Recorder(), _Recorder()
    ref, got = Pipeline(cfg, [ref_sink]), Pipeline(cfg, [got_sink])
    for it in items:
        ref.process_can_batch(it) if isinstance(it, (list, CanFrameBatch)) else ref.process(it)
    ref.finish()
    saved, pipeline_module.MERGE_MAX_FRAMES = pipeline_module.MERGE_MAX_FRAMES, merge
    try:
        for k in range(0, len(items), run_len):
            got.process_all(items[k : k + run_len])
    finally:
        pipeline_module.MERGE_MAX_FRAMES = saved
    got.finish()
    assert repr(got_sink.calls) == repr(ref_sink.calls)
    assert got.diagnostics() == ref.diagnostics()
    assert sum(c[0] == "diagnostics" for c in ref_sink.calls) >= 10


def test_kernels_are_compiled_unless_jit_is_off() -> None:
    """The equality tests above run each kernel both ways: check that 'both ways' are two different functions."""
    from slipdaq.decode.wheel_unwrap import unwrap
    from slipdaq.estimator.readiness import scan_samples

    for k in (unwrap, scan_samples):
        with kernels(True):
            assert k() is not k.py_func and not inspect.isfunction(k())  # compiled: ahead of time, or numba's JIT
        with kernels(False):
            assert k() is k.py_func
