"""The second pass's reference speed (estimator/reference_speed.py) against the simulator's truth."""

from __future__ import annotations

import numpy as np
import pytest

from slipdaq.config import load_config
from slipdaq.estimator.reference_speed import (
    SPEED_HALF_WINDOW_S,
    parabola_slopes,
    reference_speed_mps,
    wheel_speed_mps,
)
from slipdaq.estimator.smoother import smooth_speed
from slipdaq.estimator.wheel_revolutions import TWO_PI
from slipdaq.offline.run import _FirstPassSink, process
from slipdaq.sim.emit import SimSettings, generate
from support.paths import CONFIG, kernels

SETTINGS = SimSettings(gps_latency_s=0.0, gps_noise_mps=0.03, can_jitter_s=0.0005, seed=5)


@pytest.fixture(scope="module")
def drive():  # type: ignore[no-untyped-def]
    """The simulated drive's events and what a first pass keeps of it (fixes, wheel samples)."""
    cfg = load_config(CONFIG)
    events = list(generate(cfg, "cycle", "paved", SETTINGS, 30.0, r0_offset_m=-0.008))
    seen = _FirstPassSink()
    process(cfg, [e.record for e in events if e.record is not None], [seen])
    return events, seen


@pytest.fixture(scope="module")
def run(drive):  # type: ignore[no-untyped-def]
    events, seen = drive
    truth = [e.truth for e in events if e.truth is not None]
    t_truth = np.array([t.time_s for t in truth]) + SETTINGS.start_utc_s
    fix_t = np.array([f.fix_time_utc_s for f in seen.fixes])
    true_v = np.interp(fix_t, t_truth, [t.speed_mps for t in truth])
    true_a = np.interp(fix_t, t_truth, [t.accel_mps2 for t in truth])
    gps = np.array([f.speed_mps for f in seen.fixes])
    r0 = truth[-1].wheels["RL"].r0_m
    wheels = np.mean([wheel_speed_mps(fix_t, *seen.wheel_series(w), r0) for w in ("RL", "RR")], axis=0)
    return fix_t, gps, wheels, true_v, true_a


def rms(x: np.ndarray) -> float:
    return float(np.sqrt(np.mean(x**2)))


def test_free_rolling_wheel_speed_follows_the_truth(run) -> None:  # type: ignore[no-untyped-def]
    fix_t, gps, wheels, true_v, true_a = run
    accelerating = np.isfinite(wheels) & (true_a > 1.0) & (true_v > 1.0)  # the rear wheels roll freely
    assert accelerating.sum() > 50
    assert rms((wheels - true_v)[accelerating]) < 0.012  # quantisation and timestamp jitter, well below GPS noise


def test_reference_speed_beats_the_gps_and_the_gps_smoothed_alone(run) -> None:  # type: ignore[no-untyped-def]
    fix_t, gps, wheels, true_v, true_a = run
    fused = reference_speed_mps(fix_t, gps, wheels)
    alone = smooth_speed(fix_t, gps).speed_mps
    moving = true_v > 1.0
    raw_err, alone_err, fused_err = (rms((x - true_v)[moving]) for x in (gps, alone, fused))
    assert raw_err == pytest.approx(0.03, rel=0.25)
    assert fused_err < 0.6 * raw_err and fused_err < 0.85 * alone_err
    # where the wheels are unknown (every wheel driven), it is the GPS smoothed alone
    assert np.array_equal(reference_speed_mps(fix_t, gps, None), alone)
    some = wheels.copy()
    some[:40] = np.nan  # no wheel samples there: those fixes keep the GPS-alone smoothing
    mixed = reference_speed_mps(fix_t, gps, some)
    assert np.array_equal(mixed[:40], alone[:40]) and not np.array_equal(mixed[40:], alone[40:])


def test_the_wheel_speed_is_polyfits_parabola_on_real_fixes(drive, run) -> None:  # type: ignore[no-untyped-def]
    """wheel_speed_mps's fits, all fixes in one kernel call (compiled and as Python, the same bits), against numpy's
    polyfit(x, y, 2)[1] per fix on the run's fixes and rear-wheel samples: within 1e-9 m/s (polyfit's own rounding
    of the cumulated revolutions is about 1e-12; the counts' quantisation is about 1e-3)."""
    fix_t, *_ = run
    _, seen = drive
    times, revs = seen.wheel_series("RL")
    r0 = 0.31
    got = []
    for compiled_ in (True, False):
        with kernels(compiled_):
            got.append(wheel_speed_mps(fix_t, times, revs, r0))
    assert got[0].tobytes() == got[1].tobytes()
    want = np.full(len(fix_t), np.nan)
    h = SPEED_HALF_WINDOW_S
    for k, t in enumerate(fix_t):
        a, m, b = (int(np.searchsorted(times, t - h)), int(np.searchsorted(times, t)),
                   int(np.searchsorted(times, t + h, side="right")))
        if m - a >= 5 and b - m >= 5:
            want[k] = r0 * TWO_PI * np.polynomial.polynomial.polyfit(times[a:b] - t, revs[a:b], 2)[1]
    assert np.array_equal(np.isnan(got[0]), np.isnan(want)) and np.isfinite(want).sum() > 250
    assert np.nanmax(np.abs(got[0] - want)) < 1e-9


def test_the_parabola_slope_on_synthetic_windows() -> None:
    """The fit at any scale of time and revolutions, 5 to 150 samples a side: polyfit's slope to 1e-9 of the slope's
    scale (the revolutions' spread over the window divided by its half width), plus polyfit's own rounding of the
    largest revolutions (64 eps of them over the half width)."""
    rng = np.random.default_rng(7)
    checked = 0
    for _ in range(300):
        n = int(rng.integers(10, 160))
        h = float(rng.choice([1e-3, 0.2, 30.0]))
        x = np.sort(rng.uniform(-h, h, n))
        y = np.cumsum(rng.random(n)) * rng.choice([1e-3, 1.0, 1e4]) + rng.choice([0.0, 1e6])
        at = np.array([0.0])
        out = np.full(1, np.nan)
        lo, mid, hi = (np.searchsorted(x, at - h), np.searchsorted(x, at), np.searchsorted(x, at + h, side="right"))
        if mid[0] - lo[0] < 5 or hi[0] - mid[0] < 5:
            continue
        parabola_slopes()(x, y, at, lo, mid, hi, h, out)
        want = np.polynomial.polynomial.polyfit(x, y, 2)[1]
        assert abs(out[0] - want) <= (1e-9 * np.ptp(y) + 64 * np.finfo(float).eps * np.abs(y).max()) / h
        checked += 1
    assert checked > 200
