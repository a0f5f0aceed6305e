"""Simulated CAN reader stall (SimSettings.can_stall): frames arriving in the stall are stamped at its end, in order,
1 us apart; frames after it, GPS lines and truth are unchanged."""

from __future__ import annotations

from dataclasses import replace
from functools import cache
from pathlib import Path

import pytest

from slipdaq.config import load_config
from slipdaq.records import CanFrame, NmeaLine
from slipdaq.sim.emit import SimEvent, SimSettings, generate

CONFIG_PATH = Path(__file__).parents[2] / "config" / "slipdaq.toml"
START_UTC_S = SimSettings().start_utc_s
BASE = SimSettings(gps_latency_s=0.085, can_jitter_s=0.0005, seed=5)
STALL = (2.0, 0.5)


@cache
def events(settings: SimSettings, duration_s: float = 4.0) -> list[SimEvent]:
    return list(generate(load_config(CONFIG_PATH), "cycle", "paved", settings, duration_s))


def frames(evs: list[SimEvent]) -> list[CanFrame]:
    return [ev.record for ev in evs if isinstance(ev.record, CanFrame)]


def key(f: CanFrame) -> tuple[int, bytes]:
    return f.arbitration_id, f.data  # the payload carries Seq and the pulse count: unique within these seconds


def test_frames_in_the_stall_are_stamped_at_its_end_in_order() -> None:
    plain = frames(events(BASE))
    stalled_evs = events(replace(BASE, can_stall=STALL))
    stalled = frames(stalled_evs)
    assert sorted(map(key, plain)) == sorted(map(key, stalled))  # the same frames, none lost or added
    start, end = STALL[0], STALL[0] + STALL[1]
    arrival = {key(ev.record): ev.time_s for ev in events(BASE) if isinstance(ev.record, CanFrame)}
    stamp = {key(ev.record): ev.time_s for ev in stalled_evs if isinstance(ev.record, CanFrame)}  # sim seconds: exact
    inside = sorted((k for k in arrival if start <= arrival[k] < end), key=lambda k: arrival[k])
    assert len(inside) == pytest.approx(400 * STALL[1], abs=2)
    # read at the stall's end, in arrival order, 1 us apart
    assert [stamp[k] for k in inside] == pytest.approx([end + i * 1e-6 for i in range(len(inside))], abs=1e-12)
    inside_set = set(inside)
    assert [key(f) for f in stalled if key(f) in inside_set] == inside  # in the log in arrival order
    backlog_end = end + (len(inside) - 1) * 1e-6
    queued = 0
    for k, t in arrival.items():
        if t < start or t > backlog_end:  # before the stall, or after its backlog is read: unchanged, bit for bit
            assert stamp[k] == t, k
        elif t >= end:  # arrived while the backlog was read: read after it
            assert stamp[k] == pytest.approx(backlog_end + 1e-6, abs=1e-12)
            queued += 1
    assert queued == 1  # seed 5: the frame sampled at 2.5 s arrives 7 us later, within the 200 us backlog
    # the log stays in time order, and each wheel's frames keep their order
    times = [ev.time_s for ev in stalled_evs]
    assert times == sorted(times)
    for ev in stalled_evs:
        if ev.record is not None:
            assert ev.record.timestamp_s == START_UTC_S + ev.time_s
    for arb in {f.arbitration_id for f in stalled}:
        seqs = [f.data for f in stalled if f.arbitration_id == arb]
        assert seqs == [f.data for f in plain if f.arbitration_id == arb]


def test_gps_and_truth_unchanged_by_a_stall() -> None:
    plain, stalled = events(BASE), events(replace(BASE, can_stall=STALL))
    gps = lambda evs: [(ev.time_s, ev.record) for ev in evs if isinstance(ev.record, NmeaLine)]  # noqa: E731
    truth = lambda evs: [(ev.time_s, ev.truth) for ev in evs if ev.truth is not None]  # noqa: E731
    assert gps(stalled) == gps(plain) and gps(plain)
    assert truth(stalled) == truth(plain)


def test_no_stall_and_an_empty_stall_change_nothing() -> None:
    assert events(BASE) == events(replace(BASE, can_stall=None))
    assert events(BASE) == events(replace(BASE, can_stall=(2.0, 0.0)))


def test_a_stall_past_the_run_end_drops_its_frames() -> None:
    plain, stalled = frames(events(BASE)), frames(events(replace(BASE, can_stall=(3.5, 2.0))))
    assert stalled == [f for f in plain if f.timestamp_s - START_UTC_S < 3.5]


def test_bad_stall_rejected() -> None:
    with pytest.raises(ValueError):
        next(generate(load_config(CONFIG_PATH), "cycle", "paved", SimSettings(can_stall=(1.0, -0.5)), 1.0))
