"""The second pass's reference speed (estimator/reference_speed.py) against the simulator's truth."""

from __future__ import annotations

import numpy as np
import pytest

from slipdaq.config import load_config
from slipdaq.estimator.reference_speed import _parabola_slope, reference_speed_mps, wheel_speed_mps
from slipdaq.estimator.smoother import smooth_speed
from slipdaq.offline.run import _FirstPassSink, process
from slipdaq.sim.emit import SimSettings, generate
from support.paths import CONFIG

SETTINGS = SimSettings(gps_latency_s=0.0, gps_noise_mps=0.03, can_jitter_s=0.0005, seed=5)


@pytest.fixture(scope="module")
def run():  # type: ignore[no-untyped-def]
    cfg = load_config(CONFIG)
    events = list(generate(cfg, "cycle", "paved", SETTINGS, 30.0, r0_offset_m=-0.008))
    seen = _FirstPassSink()
    process(cfg, [e.record for e in events if e.record is not None], [seen])
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


def test_the_parabola_slope_is_polyfits_bit_for_bit() -> None:
    """wheel_speed_mps's fit equals numpy's polyfit(x, y, 2)[1] to the bit (the second pass's speeds do not change),
    on windows of 5 to 80 samples at any scale."""
    rng = np.random.default_rng(7)
    for _ in range(3000):
        n = int(rng.integers(5, 80))
        x = np.sort(rng.normal(0.0, 0.1, n)) * rng.choice([1e-3, 1.0, 1e3])
        y = np.cumsum(rng.random(n)) * rng.choice([1e-3, 1.0, 1e4]) + rng.choice([0.0, 1e6])
        want = np.polynomial.polynomial.polyfit(x, y, 2)[1]
        assert np.float64(_parabola_slope(x, y)).tobytes() == np.float64(want).tobytes()
