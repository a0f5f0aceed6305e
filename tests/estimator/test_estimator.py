"""The estimator's equations against hand-computed values, and its windowing on synthetic streams."""

from __future__ import annotations

import math

import numpy as np
import pytest

from slipdaq.estimator.ring import SeriesRing
from slipdaq.estimator.slip import (
    EstimatorParams,
    SlipEstimator,
    integrate_speed_m,
    slip_from_distances,
    tire_forces,
)
from slipdaq.records import GpsFix, WheelSample
from support.estimator_params import params

WHEELS = ("FL", "FR", "RL", "RR")


def test_slip_from_distances_hand_values() -> None:
    assert slip_from_distances(10.3, 10.0) == pytest.approx(0.03)  # driving: wheel went further
    assert slip_from_distances(9.5, 10.0) == pytest.approx(-0.05)  # braking
    assert slip_from_distances(10.0, 10.0) == 0.0


@pytest.mark.parametrize(
    "fx, axle, share, expected",
    [
        (4000.0, "front", 0.7, {"FL": 2000.0, "FR": 2000.0, "RL": 0.0, "RR": 0.0}),
        (4000.0, "rear", 0.7, {"FL": 0.0, "FR": 0.0, "RL": 2000.0, "RR": 2000.0}),
        (4000.0, "all", 0.7, {"FL": 1000.0, "FR": 1000.0, "RL": 1000.0, "RR": 1000.0}),
        (-10000.0, "front", 0.7, {"FL": -3500.0, "FR": -3500.0, "RL": -1500.0, "RR": -1500.0}),
        (-10000.0, "rear", 0.6, {"FL": -3000.0, "FR": -3000.0, "RL": -2000.0, "RR": -2000.0}),
    ],
)
def test_tire_forces(fx: float, axle: str, share: float, expected: dict[str, float]) -> None:
    got = tire_forces(fx, axle, share)
    assert got == pytest.approx(expected)
    assert sum(got.values()) == pytest.approx(fx)


def test_integrate_speed_piecewise_linear() -> None:
    t = np.array([0.0, 1.0, 2.0, 3.0])
    v = np.array([0.0, 10.0, 10.0, 20.0])
    assert integrate_speed_m(t, v, 0.0, 3.0) == pytest.approx(5.0 + 10.0 + 15.0)
    # from 0.5 to 2.5: 0.5 s rising 5->10 (3.75 m), 1 s at 10 (10 m), 0.5 s rising 10->15 (6.25 m)
    assert integrate_speed_m(t, v, 0.5, 2.5) == pytest.approx(3.75 + 10.0 + 6.25)


def test_ring_keeps_order_when_dropping_and_growing() -> None:
    r = SeriesRing(8)
    for i in range(100):
        r.drop_before = i - 5
        r.append(float(i), float(10 * i))
    assert list(r.times[-3:]) == [97.0, 98.0, 99.0]
    assert list(r.values[-3:]) == [970.0, 980.0, 990.0]
    assert len(r) <= 16 and r.times[0] >= 80  # old samples dropped on compaction: bounded, not kept forever
    r2 = SeriesRing(4)  # nothing may be dropped: it grows
    for i in range(50):
        r2.append(float(i), float(i))
    assert len(r2) == 50 and list(r2.times) == [float(i) for i in range(50)]


def _run(est_params: EstimatorParams, speed_of_t, slip_of_w, duration_s=6.0, wheel_hz=200.0, gps_hz=10.0,
         start_count=0, gps_delay_s=None, stored=None):
    """Feed a synthetic constant-slip stream; wheel counts are exact floors of the true angle (stored: the
    calibration the estimator starts from)."""
    est = SlipEstimator(est_params, stored)
    out = []
    events = []
    dt = 1.0 / wheel_hz
    n_wheel = int(duration_s * wheel_hz)
    # distance(t) by fine integration of speed
    fine_t = np.linspace(0.0, duration_s, 60001)
    fine_d = np.concatenate(([0.0], np.cumsum(np.diff(fine_t) * 0.5 * (speed_of_t(fine_t[1:]) + speed_of_t(fine_t[:-1])))))
    for k in range(n_wheel):
        t = k * dt
        d = float(np.interp(t, fine_t, fine_d))
        for i, w in enumerate(WHEELS):
            revs = d * (1 + slip_of_w[w]) / (2 * math.pi * est_params.r_ref_m)
            count = start_count + math.floor(revs * est_params.pulses_per_rev)
            events.append((t + i * 1e-5, 0, WheelSample(t + i * 1e-5, w, count / est_params.pulses_per_rev, count,
                                                         count, 0, 0)))
    delay_s = est_params.gps_latency_s if gps_delay_s is None else gps_delay_s
    for k in range(int(duration_s * gps_hz)):
        t = k / gps_hz
        events.append((t + 2e-5 + delay_s, 1, GpsFix(t + 2e-5 + delay_s, float(speed_of_t(np.array([t]))[0]))))
    events.sort(key=lambda e: (e[0], e[1]))
    for _, kind, rec in events:
        out += est.add_wheel(rec) if kind == 0 else est.add_gps(rec)
    return out


def test_constant_speed_and_slip_recovered_exactly() -> None:
    p = params(window_s=0.5, r_ref_m=0.3, pulses_per_rev=1000, cx_slip_min=0.005)
    slips = {"FL": 0.03, "FR": 0.02, "RL": 0.0, "RR": -0.01}
    est = _run(p, lambda t: np.full_like(t, 20.0), slips)
    assert len(est) > 40
    mid = [e for e in est if 1.0 < e.time_s - 2e-5 < 5.0]
    for e in mid:
        assert e.speed_mps == pytest.approx(20.0)
        assert e.accel_mps2 == pytest.approx(0.0, abs=1e-9)
        for w, s in slips.items():
            # count quantisation: one pulse in 10 m/(2*pi*0.3 m)*1000 ~ 5300 pulses -> 2e-4
            assert e.wheels[w].slip == pytest.approx(s, abs=3e-4)
            assert e.wheels[w].re_m == pytest.approx(0.3 / (1 + s), rel=3e-4)  # Re = V/omega
            assert e.wheels[w].r0_m == 0.3


def test_accel_force_and_cx_hand_values() -> None:
    # v = 10 + 2 t: a = 2 m/s^2, Fx = 1300 * 1.03 * 2 = 2678 N (the rotating masses' default factor 1.03);
    # front-driven -> 1339 N per front tire.
    p = params(window_s=0.5, mass_kg=1300.0, r_ref_m=0.3, driven_axle="front")
    assert p.rotating_mass_factor == 1.03
    slips = {"FL": 0.02, "FR": 0.04, "RL": 0.0, "RR": 0.0}
    est = _run(p, lambda t: 10.0 + 2.0 * t, slips)
    mid = [e for e in est if 1.0 < e.time_s < 5.0]
    assert mid
    for e in mid:
        assert e.accel_mps2 == pytest.approx(2.0, abs=1e-9)
        assert e.force_n == pytest.approx(2678.0, abs=1e-6)
        assert e.wheels["FL"].force_n == pytest.approx(1339.0)
        assert e.wheels["FL"].cx_n == pytest.approx(1339.0 / 0.02, rel=0.02)  # Cx = Fx_tire / s
        assert e.wheels["FR"].cx_n == pytest.approx(1339.0 / 0.04, rel=0.02)
        assert e.wheels["RL"].cx_n is None  # no force on a non-driven wheel: no stiffness
        assert e.speed_mps == pytest.approx(10.0 + 2.0 * (e.time_s - 2e-5), abs=1e-9)


def test_cx_only_in_linear_region_and_below_min_speed_undefined() -> None:
    p = params(window_s=0.5, r_ref_m=0.3, cx_slip_min=0.005, cx_slip_max=0.10, min_speed_mps=1.0)
    slips = {"FL": 0.003, "FR": 0.15, "RL": 0.05, "RR": 0.05}
    est = [e for e in _run(p, lambda t: 5.0 + 1.0 * t, slips, duration_s=4.0) if 1 < e.time_s < 3]
    assert est
    for e in est:
        assert e.wheels["FL"].cx_n is None  # |s| below cx_slip_min
        assert e.wheels["FR"].cx_n is None  # |s| above cx_slip_max
        assert e.wheels["FR"].slip == pytest.approx(0.15, abs=5e-4)
    slow = _run(p, lambda t: np.full_like(t, 0.5), slips, duration_s=3.0)
    assert slow and all(e.wheels[w].slip is None for e in slow for w in WHEELS)


def test_counts_near_wrap_and_latency_shift() -> None:
    """A fixed GPS latency is removed: fixes stamped late by 0.2 s give the same slips as on-time ones."""
    slips = {"FL": 0.03, "FR": 0.03, "RL": 0.0, "RR": 0.0}
    speed = lambda t: 10.0 + 2.0 * t  # noqa: E731
    base = _run(params(r_ref_m=0.3), speed, slips)
    late = _run(params(r_ref_m=0.3, gps_latency_s=0.2), speed, slips)
    a = {round(e.time_s, 6): e.wheels["FL"].slip for e in base if e.wheels["FL"].slip is not None}
    b = {round(e.time_s, 6): e.wheels["FL"].slip for e in late if e.wheels["FL"].slip is not None}
    common = sorted(set(a) & set(b))
    assert len(common) > 30
    assert max(abs(a[t] - b[t]) for t in common) < 1e-12


def test_uncompensated_latency_biases_slip() -> None:
    """Fixes that arrive 0.2 s late, read without compensation, bias slip while accelerating (the method's flaw)."""
    slips = {"FL": 0.03, "FR": 0.03, "RL": 0.0, "RR": 0.0}
    late = _run(params(r_ref_m=0.3), lambda t: 10.0 + 2.0 * t, slips, gps_delay_s=0.2)
    s_rl = np.median([e.wheels["RL"].slip for e in late if e.wheels["RL"].slip is not None and e.time_s > 1])
    # GPS speed read 0.2 s late at 2 m/s^2 is 0.4 m/s too low at ~15 m/s: a free-rolling wheel shows ~ +2.7 %
    assert 0.015 < s_rl < 0.04


@pytest.mark.parametrize("gps_latency_s", [None, 0.03])
def test_estimate_released_by_the_fix_that_ends_its_window(gps_latency_s: float | None) -> None:
    """At 20 Hz and W = 0.5 s the fix 0.25 s after an epoch closes its window: the estimate comes with that fix,
    whatever the fix's read jitter or the float rounding of epoch-second UTC times, not one GPS interval later.
    (Before, a fix read 1 ms early against the median offset made the estimate wait for the next one: 50 ms.)"""
    p = params(window_s=0.5, r_ref_m=0.3, gps_latency_s=gps_latency_s)
    est = SlipEstimator(p)
    utc0 = 1_763_800_000.0  # epoch seconds: one ulp is 2.4e-7 s
    jitter = [0.0, -0.002, 0.0015, -0.001, 0.002, 0.0005, -0.0015]
    events: list[tuple[float, int, object]] = []
    for k in range(1, 8000):  # wheels at 1 kHz, stamped on the host clock (= UTC here)
        t = utc0 + k * 1e-3
        for i, w in enumerate(WHEELS):
            revs = 20.0 * (t - utc0) / (2 * math.pi * 0.3)
            events.append((t + i * 1e-6, 0, WheelSample(t + i * 1e-6, w, revs, int(revs * 1000), 0, 0, 0)))
    for k in range(160):  # 20 Hz fixes, read 30 ms after their UTC time with jitter
        utc = utc0 + k * 0.05
        arrival = utc + 0.03 + jitter[k % len(jitter)]
        events.append((arrival, 1, (k, GpsFix(arrival, 20.0, fix_time_utc_s=utc))))
    events.sort(key=lambda e: (e[0], e[1]))
    released_by_fix: list[tuple[int, float]] = []  # (index of the releasing fix, estimate centre)
    by_wheels = []
    for _, kind, rec in events:
        if kind == 0:
            by_wheels += est.add_wheel(rec)  # type: ignore[arg-type]
        else:
            k, fix = rec  # type: ignore[misc]
            released_by_fix += [(k, e.time_s) for e in est.add_gps(fix)]
    late = [(k, t_c) for k, t_c in released_by_fix if t_c > utc0 + 1.0]
    assert len(late) > 100
    for k, t_c in late:
        centre_k = round((t_c - utc0) / 0.05)
        assert k == centre_k + 5, f"estimate at epoch {centre_k} waited for fix {k}"
    assert not [e for e in by_wheels if e.time_s > utc0 + 1.0]  # the wheels were there before the fix


def test_a_fix_with_a_nan_utc_time_counts_as_one_without() -> None:
    """A decoder that hands over NaN for the UTC time (instead of None) must not crash the estimate (it did:
    max() of an empty sequence in the coverage check); the estimates equal those of fixes without UTC."""
    def run(utc_of_k):  # type: ignore[no-untyped-def]
        est = SlipEstimator(params(window_s=0.5, r_ref_m=0.3, gps_latency_s=None))
        out = []
        rev = 20.0 / (2 * math.pi * 0.3)
        for k in range(1, 4000):
            t = k * 1e-3
            for w in WHEELS:
                out += est.add_wheel(WheelSample(t, w, rev * t, int(rev * t * 1000), 0, 0, 0))
            if k % 50 == 0:
                out += est.add_gps(GpsFix(t + 0.0005, 20.0, fix_time_utc_s=utc_of_k(k)))
        return out

    with_nan = run(lambda k: math.nan if k % 100 == 0 else k * 1e-3)  # the host clock keeps UTC here
    without = run(lambda k: None if k % 100 == 0 else k * 1e-3)
    assert len(with_nan) > 50
    assert with_nan == without
