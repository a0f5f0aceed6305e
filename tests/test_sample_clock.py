"""An MTi's samples placed on the host's clock by their SampleTimeFine (decode/sample_clock.py), and the pipeline
taking its acceleration at those times."""

from __future__ import annotations

import numpy as np
from hypothesis import given
from hypothesis import strategies as st

from slipdaq.decode.sample_clock import HISTORY_S, TICKS_PER_S, WRAP, SampleClock

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
