"""The report's mu–slip curve (maneuver/mu_slip.py) against tires of known truth, and the brake-test figures
(maneuver/brake_test.py) against synthetic, physically consistent brake runs with analytic answers."""

from __future__ import annotations

import math

import numpy as np
import pytest

from slipdaq import WHEELS
from slipdaq.maneuver.brake_test import AbsCycling, BrakeFigures, abs_cycling, brake_figures, brake_onset_s
from slipdaq.maneuver.mu_slip import G_MPS2, MuSlipFit, end_of_linearity_slip, fit_mu_slip, mu_from_force, normal_loads_n

# ---------------------------------------------------------------- mu–slip

DRY = (1.0, 1.65, 12.12)  # D, C, B of mu(s) = D·sin(C·atan(B·s))
SAND = (0.6, 1.65, 8.08)


def pacejka(s: np.ndarray, d: float, c: float, b: float) -> np.ndarray:
    return d * np.sin(c * np.arctan(b * s))


def pacejka_peak_slip(c: float, b: float) -> float:
    return math.tan(math.pi / (2 * c)) / b


def noisy(s: np.ndarray, tire: tuple[float, float, float], sign: float, seed: int) -> tuple[np.ndarray, np.ndarray]:
    """Points on the tire's curve at |s|, signed, with noise on mu (σ 0.02) and on slip (σ 0.005)."""
    rng = np.random.default_rng(seed)
    mu = pacejka(s, *tire)
    return sign * s + rng.normal(0, 0.005, s.size), sign * mu + rng.normal(0, 0.02, s.size)


def abs_cycle_slips(tire: tuple[float, float, float]) -> np.ndarray:
    """|s| of an ABS stop at 100 Hz: the ramp 0..s* (0.3 s), then 2 s cycling at 7 Hz between 0.5 s* and 1.6 s*."""
    sp = pacejka_peak_slip(tire[1], tire[2])
    t = np.arange(0.0, 2.0, 0.01)
    return np.concatenate([np.linspace(0.0, sp, 30), sp * (1.05 + 0.55 * np.sin(2 * np.pi * 7 * t))])


def lock_slips() -> np.ndarray:
    """|s| of a wheel locking: slip sweeps 0..1 (400 samples) and stays locked (50 samples)."""
    return np.concatenate([np.linspace(0.0, 1.0, 400), np.ones(50)])


def assert_peak_near_truth(fit: MuSlipFit | None, tire: tuple[float, float, float]) -> None:
    assert fit is not None and fit.peak_observed
    assert fit.mu_peak is not None and fit.slip_at_mu_peak is not None
    assert fit.mu_peak == pytest.approx(tire[0], rel=0.05)
    assert abs(fit.slip_at_mu_peak - pacejka_peak_slip(tire[1], tire[2])) < 0.02


def test_normal_loads_static_and_transfer() -> None:
    m, share, h, wb = 1500.0, 0.58, 0.55, 2.7
    a = np.array([0.0, -9.0, 3.0])
    loads = {w: normal_loads_n(w, a, m, share, h, wb) for w in WHEELS}
    np.testing.assert_allclose(sum(loads.values()), m * G_MPS2)  # transfer only shifts load between axles
    assert loads["FL"][0] == pytest.approx(m * G_MPS2 * share / 2)
    assert loads["RR"][0] == pytest.approx(m * G_MPS2 * (1 - share) / 2)
    np.testing.assert_allclose(loads["FL"], loads["FR"])
    assert loads["FL"][1] == pytest.approx(m * G_MPS2 * share / 2 + m * 9.0 * h / wb / 2)  # braking loads the front
    assert loads["RL"][2] == pytest.approx(m * G_MPS2 * (1 - share) / 2 + m * 3.0 * h / wb / 2)
    with pytest.raises(ValueError):
        normal_loads_n("XX", a, m, share, h, wb)


def test_mu_from_force() -> None:
    mu = mu_from_force([3000.0, -1500.0, 100.0, np.nan], [4000.0, 3000.0, 0.0, 3000.0])
    np.testing.assert_allclose(mu[:2], [0.75, -0.5])
    assert np.isnan(mu[2]) and np.isnan(mu[3])


@pytest.mark.parametrize("tire", [DRY, SAND], ids=["dry", "sand"])
def test_abs_cycle_peak_within_limits(tire: tuple[float, float, float]) -> None:
    s, mu = noisy(abs_cycle_slips(tire), tire, -1.0, seed=1)
    fit = fit_mu_slip(s, mu)
    assert_peak_near_truth(fit, tire)
    assert fit is not None and fit.model == "burckhardt" and fit.slip_sign == -1.0 and fit.n_points == s.size
    assert fit.rms_residual < 0.1


@pytest.mark.parametrize("tire", [DRY, SAND], ids=["dry", "sand"])
def test_lock_peak_within_limits(tire: tuple[float, float, float]) -> None:
    s, mu = noisy(lock_slips(), tire, -1.0, seed=2)
    fit = fit_mu_slip(s, mu)
    assert_peak_near_truth(fit, tire)
    assert fit is not None and fit.slip_at_mu_peak is not None
    # the peak comes from the points up to PEAK_WINDOW·s*; the sliding branch is left out and counted
    assert fit.points_beyond_window > 0 and fit.max_abs_slip <= 1.6 * fit.slip_at_mu_peak + 1e-12
    whole = fit_mu_slip(s, mu, peak_window=None)
    assert whole is not None and whole.points_beyond_window == 0 and whole.max_abs_slip > 0.99
    assert whole.n_points == fit.n_points + fit.points_beyond_window


@pytest.mark.parametrize("tire", [DRY, SAND], ids=["dry", "sand"])
def test_linear_region_only_gives_no_peak(tire: tuple[float, float, float]) -> None:
    s, mu = noisy(np.random.default_rng(3).uniform(0.0, 0.04, 200), tire, -1.0, seed=4)
    fit = fit_mu_slip(s, mu)
    assert fit is not None  # a curve, but no peak
    assert not fit.peak_observed and fit.mu_peak is None and fit.slip_at_mu_peak is None


def test_braking_and_driving_fit_alike() -> None:
    s, mu = noisy(abs_cycle_slips(DRY), DRY, 1.0, seed=5)
    drive = fit_mu_slip(s, mu)
    brake = fit_mu_slip(-s, -mu)
    assert drive is not None and brake is not None
    assert (drive.slip_sign, brake.slip_sign) == (1.0, -1.0)
    assert (brake.c1, brake.c2, brake.c3, brake.mu_peak) == pytest.approx((drive.c1, drive.c2, drive.c3, drive.mu_peak))
    assert brake.slip_at_mu_peak is not None and brake.slip_at_mu_peak > 0  # a magnitude
    grid = np.linspace(0.0, 0.2, 21)
    np.testing.assert_allclose(brake.mu(-grid), -drive.mu(grid))
    assert np.all(brake.mu(-grid[1:]) < 0)
    assert brake.mu(np.array([-brake.slip_at_mu_peak]))[0] == pytest.approx(-brake.mu_peak)


def test_exact_burckhardt_recovered_and_end_of_linearity() -> None:
    c1, c2, c3 = 1.2801, 23.99, 0.52  # Burckhardt's dry asphalt
    s = np.linspace(0.0, 0.6, 300)
    mu = c1 * (1 - np.exp(-c2 * s)) - c3 * s
    fit = fit_mu_slip(-s, -mu, peak_window=None)
    assert fit is not None
    assert (fit.c1, fit.c2, fit.c3) == pytest.approx((c1, c2, c3), rel=2e-3)
    assert fit.slip_at_mu_peak == pytest.approx(math.log(c1 * c2 / c3) / c2, rel=2e-3)
    assert fit.rms_residual < 1e-3
    # end of linearity, found independently on a dense grid: mu(s) < 0.9·(c1·c2 − c3)·s first
    dense = np.linspace(1e-6, 0.6, 600_001)
    ratio = (c1 * (1 - np.exp(-c2 * dense)) - c3 * dense) / ((c1 * c2 - c3) * dense)
    truth = dense[np.argmax(ratio < 0.9)]
    end = end_of_linearity_slip(fit)
    assert end is not None and end == pytest.approx(truth, abs=2e-4)
    assert end_of_linearity_slip(fit, tolerance=0.2) > end  # type: ignore[operator]


def test_end_of_linearity_not_extrapolated() -> None:
    s = np.linspace(0.0, 0.02, 50)
    fit = fit_mu_slip(s, 20.0 * s)  # straight: the 10 % departure lies beyond the points
    assert fit is not None and end_of_linearity_slip(fit) is None


def test_rejects_too_few_points_or_slip_range() -> None:
    s, mu = noisy(abs_cycle_slips(DRY), DRY, -1.0, seed=6)
    assert fit_mu_slip(s[::20][:19], mu[::20][:19]) is None
    assert fit_mu_slip(s[::10][:25], mu[::10][:25]) is not None
    rng = np.random.default_rng(7)
    narrow = 0.05 + rng.uniform(-0.004, 0.004, 100)
    assert fit_mu_slip(narrow, pacejka(narrow, *DRY)) is None
    with pytest.raises(ValueError):
        fit_mu_slip(s, mu[:-1])


# ---------------------------------------------------------------- brake test

V0 = 80 / 3.6
DECEL = 9.0
RAMP_S = 0.2
T_ON = 1.2345  # off the 100 Hz grid


def brake_run(v0: float = V0, t_on: float = T_ON, dt: float = 0.01, t_end: float = 5.0):
    """Speed and acceleration of a stop from v0: deceleration ramping 0 -> DECEL over RAMP_S from t_on, then
    constant to standstill. Returns t, v, a and the analytic (stopping distance, stop time)."""
    t = np.arange(0.0, t_end, dt)
    tau = t - t_on
    v1 = v0 - DECEL * RAMP_S / 2
    t_stop = t_on + RAMP_S + v1 / DECEL
    v = np.where(tau <= 0, v0, np.where(tau <= RAMP_S, v0 - DECEL * tau**2 / (2 * RAMP_S), v1 - DECEL * (tau - RAMP_S)))
    v = np.maximum(v, 0.0)
    a = np.where(tau <= 0, 0.0, np.where(tau <= RAMP_S, -DECEL * tau / RAMP_S, -DECEL))
    a = np.where(t >= t_stop, 0.0, a)
    dist = v0 * RAMP_S - DECEL * RAMP_S**2 / 6 + v1**2 / (2 * DECEL)
    return t, v, a, dist, t_stop


def test_stopping_distance_and_mfdd() -> None:
    t, v, a, dist, t_stop = brake_run()
    bt = np.arange(T_ON - 0.5, 4.0, 0.02)  # a 50 Hz brake signal with a sample at the onset
    bt[np.argmin(abs(bt - T_ON))] = T_ON
    fig = brake_figures(t, v, a, brake_time_s=bt, brake_value=(bt >= T_ON).astype(float))
    assert isinstance(fig, BrakeFigures)
    # the press lies between the last released and the first pressed sample: their midpoint, ± half their interval
    assert fig.onset_source == "brake signal" and fig.onset_s == pytest.approx(T_ON - 0.01)
    assert fig.onset_half_s == pytest.approx(0.01)
    assert fig.brake_speed_kmh == pytest.approx(80.0, abs=0.01)
    assert fig.stopping_distance_m is not None and abs(fig.stopping_distance_m - dist) < V0 * 0.01 + 0.1
    marked = brake_figures(t, v, a, brake_time_s=bt, brake_value=(bt >= T_ON).astype(float), mark_time_s=[T_ON])
    assert marked is not None and marked.onset_s == T_ON and marked.stopping_distance_m is not None
    assert abs(marked.stopping_distance_m - dist) < 0.1
    assert fig.stop_s == pytest.approx(t_stop, abs=0.02)
    assert fig.mfdd_mps2 == pytest.approx(DECEL, rel=0.01)  # the ramp ends before 0.8·v0
    assert fig.nominal_speed_kmh == 80.0
    assert fig.stopping_distance_corrected_m == pytest.approx(fig.stopping_distance_m * (80.0 / fig.brake_speed_kmh) ** 2)
    assert fig.abs_cycles == 0 and fig.abs_frequency_hz is None and fig.abs_wheel is None


def test_figures_from_deceleration_onset() -> None:
    t, v, a, dist, _ = brake_run()
    fig = brake_figures(t, v, a)
    assert fig is not None and fig.onset_source == "deceleration"
    assert abs(fig.onset_s - T_ON) < 0.03
    assert fig.stopping_distance_m is not None and abs(fig.stopping_distance_m - dist) < 0.1
    assert fig.mfdd_mps2 == pytest.approx(DECEL, rel=0.01)


@pytest.mark.parametrize(("v0_kmh", "nominal"), [(83.0, 80.0), (76.0, 80.0), (86.0, 90.0), (101.0, 100.0)])
def test_corrected_distance(v0_kmh: float, nominal: float) -> None:
    t, v, a, dist, _ = brake_run(v0=v0_kmh / 3.6)
    fig = brake_figures(t, v, a)
    assert fig is not None and fig.stopping_distance_m is not None
    assert fig.nominal_speed_kmh == nominal
    assert fig.stopping_distance_corrected_m == pytest.approx(fig.stopping_distance_m * (nominal / fig.brake_speed_kmh) ** 2)
    assert fig.stopping_distance_corrected_m == pytest.approx(dist * (nominal / v0_kmh) ** 2, abs=0.15)


def test_no_stop_within_span() -> None:
    t, v, a, _, t_stop = brake_run()
    cut = t < t_stop - 0.5
    fig = brake_figures(t[cut], v[cut], a[cut])
    assert fig is not None and fig.stop_s is None and fig.stopping_distance_m is None
    assert fig.stopping_distance_corrected_m is None
    assert fig.mfdd_mps2 is None  # 0.5 s before the stop the speed is still above 0.1·v0
    assert brake_figures(t, np.full_like(t, V0), np.zeros_like(t)) is None  # no brake at all


def test_onset_from_50hz_brake_signal() -> None:
    t, _, a, _, _ = brake_run()
    for phase in (0.0, 0.0037, 0.011, 0.0199):
        bt = np.arange(phase, 5.0, 0.02)
        onset = brake_onset_s(t, a, bt, (bt >= T_ON).astype(int))
        assert onset is not None and abs(onset - T_ON) <= 0.01 + 1e-12
        k = int(np.argmax(bt >= T_ON))  # the samples' own times, not rounded to the 100 Hz grid
        assert onset == pytest.approx(0.5 * (bt[k - 1] + bt[k]), abs=1e-12)
    # the first press after a release counts; a pedal pressed throughout the span falls back on the deceleration
    bt = np.arange(0.0, 5.0, 0.02)
    pressed = ((bt >= 0.5) & (bt < 0.7)) | (bt >= T_ON)
    assert brake_onset_s(t[t >= 0.6], a[t >= 0.6], bt, pressed) == pytest.approx(bt[np.argmax(bt >= T_ON)] - 0.01)
    assert brake_onset_s(t, a, bt, np.ones_like(bt)) == pytest.approx(T_ON, abs=0.03)


def test_onset_from_deceleration() -> None:
    for t_on in (1.0, 1.2345, 1.2399):
        t, _, a, _, _ = brake_run(t_on=t_on)
        onset = brake_onset_s(t, a)
        assert onset is not None and abs(onset - t_on) < 0.03
    # with IMU noise (σ 0.1 m/s²) and a pre-brake level (0.3 m/s² of coasting) still within 30 ms
    t, _, a, _, _ = brake_run()
    rng = np.random.default_rng(8)
    a_noisy = np.where(t < T_ON, -0.3, a - 0.3 * (t < T_ON + 0.5)) + rng.normal(0, 0.1, t.size)
    onset = brake_onset_s(t, a_noisy)
    assert onset is not None and abs(onset - T_ON) < 0.03
    assert brake_onset_s(t, np.full_like(t, -0.5)) is None  # never above the threshold


def test_abs_cycles_of_a_7hz_oscillation() -> None:
    t = np.arange(0.0, 3.0, 0.005)
    slip = -(0.12 + 0.06 * np.sin(2 * np.pi * 7.0 * t)) + np.random.default_rng(9).normal(0, 0.005, t.size)
    res = abs_cycling(t, slip)
    assert isinstance(res, AbsCycling)
    assert 20 <= res.cycles <= 21
    assert res.frequency_hz == pytest.approx(7.0, rel=0.05)


def test_no_abs_cycles_when_locked_or_light() -> None:
    t = np.arange(0.0, 3.0, 0.005)
    locked = np.where(t < 0.3, -t / 0.3, -1.0)
    assert abs_cycling(t, locked) == AbsCycling(0, None)
    assert abs_cycling(t, np.full_like(t, -1.0)) == AbsCycling(0, None)
    light = -0.02 + np.random.default_rng(10).normal(0, 0.005, t.size)
    assert abs_cycling(t, light) == AbsCycling(0, None)


def test_brake_figures_abs_from_the_cycling_wheel() -> None:
    t, v, a, _, t_stop = brake_run(dt=0.01)
    ts = np.arange(0.0, 5.0, 0.005)  # the slip at its own, higher rate
    braking = (ts > T_ON + 0.3) & (ts < t_stop)
    rng = np.random.default_rng(11)
    cycling = np.where(braking, -(0.12 + 0.06 * np.sin(2 * np.pi * 7.0 * (ts - T_ON))), -0.01)
    slips = {
        "FL": cycling + rng.normal(0, 0.005, ts.size),
        "FR": cycling + rng.normal(0, 0.005, ts.size),
        "RL": np.where(braking, -1.0, 0.0),  # locked
        "RR": np.where(braking, -0.03, 0.0) + rng.normal(0, 0.005, ts.size),  # light
    }
    fig = brake_figures(t, v, a, slip_time_s=ts, slips=slips)
    assert fig is not None and fig.abs_wheel in ("FL", "FR")
    # cycles counted from onset until the speed falls to 1.5 m/s
    t_end = T_ON + RAMP_S + (V0 - DECEL * RAMP_S / 2 - 1.5) / DECEL
    expected = 7.0 * (t_end - T_ON - 0.3)
    assert abs(fig.abs_cycles - expected) <= 1.5
    assert fig.abs_frequency_hz == pytest.approx(7.0, rel=0.05)
