"""An MTi's samples placed on the host's clock by their SampleTimeFine (decode/sample_clock.py), and the pipeline
taking its acceleration at those times."""

from __future__ import annotations

from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

from slipdaq.decode.sample_clock import DRIFT_S, HISTORY_S, RESET_S, TICKS_PER_S, WRAP, SampleClock

RATE_HZ = 100
FASTEST_READ_S = 0.0012


def loaded_arrivals(n: int, seed: int = 3) -> tuple[np.ndarray, np.ndarray]:
    """True sample times at 100 Hz and their arrivals on a loaded host: each read late by the fastest read plus an
    exponential delay (mean 8 ms), and a 300 ms stall every 2 s whose samples all arrive at its end."""
    rng = np.random.default_rng(seed)
    true = 1.8e9 + np.arange(n) / RATE_HZ
    arrival = true + FASTEST_READ_S + rng.exponential(0.008, n)
    for start in np.arange(true[0] + 1.0, true[-1], 2.0):
        stalled = (true >= start) & (true < start + 0.3)
        arrival[stalled] = np.maximum(arrival[stalled], start + 0.3 + FASTEST_READ_S)
    return true, np.maximum.accumulate(arrival)


def test_samples_are_placed_at_their_own_time_plus_the_fastest_read_whatever_the_load() -> None:
    true, arrival = loaded_arrivals(3000)
    clock = SampleClock()
    placed = np.array([clock.place(float(a), round(k * TICKS_PER_S / RATE_HZ)) for k, a in enumerate(arrival)])
    late = arrival - true
    assert late.max() > 0.25 and np.median(late) > 0.005  # the host read them late, in bursts
    settled = slice(int(RATE_HZ), None)  # one second of samples for the envelope to find a fast read
    off = placed[settled] - true[settled] - FASTEST_READ_S
    assert off.min() >= 0.0 and off.max() < 0.0005
    assert np.all(np.diff(placed[settled]) > 0.0095)  # 10 ms apart, as sampled, not bunched like the arrivals
    assert np.all(placed <= arrival)
    assert clock.resets == 0


def test_the_counter_wraps_at_2_to_the_32() -> None:
    clock = SampleClock()
    start = WRAP - 250  # SampleTimeFine wraps 25 ms in
    placed = [clock.place(100.0 + 0.001 + k * 0.01, (start + k * 100) % WRAP) for k in range(10)]
    assert np.allclose(np.diff(placed), 0.01) and clock.resets == 0


def test_a_restarted_sensor_or_a_stepped_host_clock_starts_the_envelope_again() -> None:
    clock = SampleClock()
    for k in range(50):
        clock.place(10.0 + k * 0.01 + 0.002, 5_000_000 + k * 100)
    assert clock.place(10.6, 1_000) == 10.6  # the counter went back: the sensor restarted
    assert clock.resets == 1
    for k in range(1, 50):
        clock.place(10.6 + k * 0.01, 1_000 + k * 100)
    assert clock.place(13.6 + 0.5, 1_000 + 50 * 100) == 14.1  # the host's clock stepped 3 s
    assert clock.resets == 2


def test_an_imported_capture_keeps_its_stamps_exactly() -> None:
    """Real MTi captures (tests/data/xsens-mti), stamped by the import from the MTi's own UTCTime and SampleTimeFine:
    the estimator's samples take those stamps, not within a rounding of them."""
    from slipdaq.decode.mti_accel import MtiAccel
    from slipdaq.sources.xbus_file import iter_xbus_capture

    captures = sorted((Path(__file__).resolve().parents[1] / "data" / "xsens-mti").glob("*/output.bin"))
    assert len(captures) == 3
    for capture in captures:
        mti = MtiAccel(SimpleNamespace(source="serial", axis="x", sign=1))
        pairs = [(s[0], r.timestamp_s) for r in iter_xbus_capture(capture) if (s := mti.sample(r)) is not None]
        assert len(pairs) > 50 and all(placed == stamp for placed, stamp in pairs)


@pytest.mark.parametrize("pace", [0.25, 0.98, 1.02, 4.0])
def test_a_counter_at_another_pace_than_the_host_s_is_not_held_back(pace: float) -> None:
    """A capture played into a port at another pace than it was sampled (its counter advancing `pace` times as fast as
    the host's clock): no sample is placed more than the drift bound before its read."""
    clock = SampleClock()
    arrival = 1_000.0 + 0.001 + np.arange(1000) / RATE_HZ
    placed = [clock.place(float(a), round(k * pace * TICKS_PER_S / RATE_HZ)) for k, a in enumerate(arrival)]
    lag = arrival - np.array(placed)
    assert lag.min() >= 0.0 and lag.max() <= RESET_S + 1.0 / RATE_HZ
    if abs(pace - 1.0) <= 0.02:  # DRIFT_S, and the drift over the last RECENT_S
        assert lag.max() <= DRIFT_S + 0.03
    assert np.all(np.diff(placed) >= 0.0)


def test_a_host_that_stalls_longer_than_a_second_falls_back_to_the_reads() -> None:
    """1.5 s without a read, then the samples in a burst: the recent fastest read is the stall's, and the envelope
    starts again there rather than place the burst by a read 1.5 s old."""
    clock = SampleClock()
    true = 500.0 + np.arange(600) / RATE_HZ
    arrival = true + 0.002
    arrival[200:350] = true[350] + 0.002  # the host read nothing from 2.0 s to 3.5 s
    placed = np.array([clock.place(float(a), k * 100) for k, a in enumerate(arrival)])
    assert clock.resets >= 1 and np.all(placed <= arrival) and np.all(np.diff(placed) >= 0.0)
    assert np.abs(placed[400:] - true[400:] - 0.002).max() < 0.001  # placed by their own time again after it


def test_a_sample_without_a_counter_keeps_its_arrival() -> None:
    assert SampleClock().place(12.5, None) == 12.5


def test_a_fast_read_leaves_the_envelope_after_its_span() -> None:
    """The envelope forgets: a host whose fastest read has grown (another load for minutes) is followed."""
    clock = SampleClock()
    n = int(2 * HISTORY_S * RATE_HZ)
    placed = [clock.place(k / RATE_HZ + (0.001 if k < 10 else 0.004), k * 100) for k in range(n)]
    assert abs(placed[20] - 20 / RATE_HZ - 0.001) < 1e-9
    assert abs(placed[-1] - (n - 1) / RATE_HZ - 0.004) < 1e-9


@given(st.lists(st.tuples(st.floats(0.0, 0.5), st.integers(1, 400)), min_size=1, max_size=200))
def test_placed_times_never_pass_the_arrival_nor_go_back(steps: list[tuple[float, int]]) -> None:
    clock = SampleClock()
    arrival, ticks, last = 1_000.0, 7, -np.inf
    for wait_s, tick_step in steps:
        arrival += wait_s
        ticks += tick_step
        t = clock.place(arrival, ticks)
        assert last <= t <= arrival
        last = t
