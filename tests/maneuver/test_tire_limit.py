"""The tire at its limit: mu–slip from every wheel at once (maneuver/mu_joint.py, tire_limit.py) against the
simulator's tire, on an ABS stop where every wheel cycles around the peak and on one where only one axle does; the
flags that keep an implausible or undetermined peak from being given; the 95 % intervals."""

from __future__ import annotations

from typing import Any

import numpy as np
import pytest

from slipdaq import WHEELS
from slipdaq.config import Config
from slipdaq.live.demo import demo_config, demo_settings
from slipdaq.maneuver.mu_joint import fit_joint, force_lag_s
from slipdaq.maneuver.mu_slip import normal_loads_n
from slipdaq.maneuver.record import Maneuver, determined
from slipdaq.maneuver.tire_limit import flagged
from slipdaq.pipeline import Pipeline
from slipdaq.sim.emit import generate
from slipdaq.sim.truth import tire_peak
from slipdaq.sinks import CollectingSink


def stop(scenario: str, road: str, cfg: Config | None = None) -> tuple[Maneuver, CollectingSink]:
    cfg = cfg or demo_config("/dev/null", "chan", scenario)
    sink = CollectingSink()
    events = generate(cfg, scenario, road, demo_settings(scenario), 14.0)  # type: ignore[arg-type]
    Pipeline(cfg, [sink]).run(e.record for e in events if e.record is not None)
    (m,) = sink.maneuvers
    return m, sink


@pytest.mark.parametrize("road", ["paved", "sand"])
def test_every_wheel_at_its_limit(road: str) -> None:
    """All four wheels cycle around the peak (brake-abs-all): the hydraulic split would put rear mu far above the
    tire's; the joint fit gives every tire's mu peak within 5 %, and its slip within 2 points (the force aligned with
    the slips by its delay: without it the slip at the peak came out 1-2 points high)."""
    m, _sink = stop("brake-abs-all", road)
    truth = tire_peak(road)
    for w in WHEELS:
        mw = m.wheels[w]
        assert mw.mu_slip_method is not None and mw.mu_slip_method.startswith("joint"), (w, mw)
        assert mw.mu_peak is not None and abs(mw.mu_peak / truth.mu_peak - 1.0) <= 0.05, (w, mw.mu_peak)
        assert mw.slip_at_mu_peak is not None
        assert abs(mw.slip_at_mu_peak - truth.slip_at_mu_peak) <= 0.02
        assert mw.mu_peak_lo is not None and mw.mu_peak_hi is not None
        assert mw.mu_peak_lo <= mw.mu_peak <= mw.mu_peak_hi and mw.mu_flag is None
        assert mw.slip_at_mu_peak_lo is not None and mw.slip_at_mu_peak_hi is not None
        assert mw.slip_at_mu_peak_lo <= mw.slip_at_mu_peak <= mw.slip_at_mu_peak_hi


def test_one_axle_at_its_limit_keeps_the_split() -> None:
    """brake-abs: only the rear axle cycles, the front stays on its hydraulic share in the linear region: the rear's
    peak right, with its 95 % interval, the front's none (its points never passed it), and no mu above the tire's."""
    m, _sink = stop("brake-abs", "paved")
    truth = tire_peak("paved")
    for w in ("RL", "RR"):
        mw = m.wheels[w]
        assert mw.mu_slip_method == "hydraulic split"
        assert mw.mu_peak is not None and abs(mw.mu_peak / truth.mu_peak - 1.0) <= 0.05
        assert mw.slip_at_mu_peak is not None and abs(mw.slip_at_mu_peak - truth.slip_at_mu_peak) <= 0.02
        assert mw.mu_peak_lo is not None and mw.mu_peak_hi is not None  # the split's fit carries its interval too
        assert mw.mu_peak_lo <= mw.mu_peak <= mw.mu_peak_hi and mw.mu_peak_hi - mw.mu_peak_lo < 0.2
        assert mw.slip_at_mu_peak_lo is not None and mw.slip_at_mu_peak_hi is not None
        assert mw.slip_at_mu_peak_lo <= mw.slip_at_mu_peak <= mw.slip_at_mu_peak_hi
    for w in ("FL", "FR"):
        assert m.wheels[w].mu_peak is None and m.wheels[w].mu_flag == "peak not passed"
    assert all((m.wheels[w].mu_peak or 0.0) <= 1.5 for w in WHEELS)


def test_a_peak_above_what_a_tire_gives_is_flagged_not_given() -> None:
    """tire.mu_max below the road's friction: every peak flagged, none given."""
    cfg = demo_config("/dev/null", "chan", "brake-abs-all")
    cfg = cfg.with_overrides(tire={"mu_max": 0.8})
    m, _sink = stop("brake-abs-all", "paved", cfg)
    for w in WHEELS:
        assert m.wheels[w].mu_peak is None and m.wheels[w].slip_at_mu_peak is None
        assert m.wheels[w].mu_flag == "mu above 0.8"


def test_brake_figures_carry_their_intervals() -> None:
    m, _sink = stop("brake-abs", "sand")
    assert m.stopping_distance_m is not None and m.stopping_distance_m_lo is not None and m.stopping_distance_m_hi
    assert m.stopping_distance_m_lo <= m.stopping_distance_m <= m.stopping_distance_m_hi
    assert m.mfdd_mps2 is not None and m.mfdd_mps2_lo is not None and m.mfdd_mps2_hi is not None
    assert m.mfdd_mps2_lo <= m.mfdd_mps2 <= m.mfdd_mps2_hi
    for w in WHEELS:
        mw = m.wheels[w]
        if mw.cx_line_n is not None:
            assert mw.cx_line_n_lo is not None and mw.cx_line_n_hi is not None
            assert mw.cx_line_n_lo <= mw.cx_line_n <= mw.cx_line_n_hi


def test_an_interval_wider_than_its_value_is_not_determined() -> None:
    assert determined(10.0, 9.0, 11.0) == 10.0
    assert determined(10.0, 2.0, 13.0) is None
    assert determined(-5.0, -6.0, -4.0) == -5.0 and determined(None, 1.0, 2.0) is None
    assert determined(3.0, None, None) == 3.0
    from slipdaq.maneuver.mu_slip import MuSlipFit

    fit = MuSlipFit(1.0, 20.0, 1.0, 0.95, 0.12, 0.01, 100, True, -1.0, 0.3, mu_peak_lo=0.2, mu_peak_hi=1.9)
    f = flagged(fit, 1.5)
    assert f.flag == "not determined" and f.mu_peak is None and f.slip_at_mu_peak is None
    assert flagged(fit.__class__(**{**fit.__dict__, "mu_peak_lo": 0.9, "mu_peak_hi": 1.0}), 1.5).mu_peak == 0.95


def test_joint_fit_recovers_a_known_curve_from_total_force() -> None:
    """Synthetic: four wheels at different slips on one Burckhardt curve, only their total force seen: the peak is
    found where the curve has it; two axles on different curves are told apart (per axle)."""
    rng = np.random.default_rng(1)
    n = 600
    t = np.arange(n) * 0.01
    phase = 7.0 * t
    slips = {w: -0.04 - 0.18 * ((phase + k / 4) % 1.0) for k, w in enumerate(WHEELS)}
    a = np.full(n, -8.0)
    fz = {w: normal_loads_n(w, a, 1300.0, 0.6, 0.55, 2.6) for w in WHEELS}

    def burck(x: np.ndarray, c1: float, c2: float, c3: float) -> np.ndarray:
        return c1 * (1 - np.exp(-c2 * x)) - c3 * x

    curves = {"FL": (1.1, 25.0, 0.5), "FR": (1.1, 25.0, 0.5), "RL": (0.8, 30.0, 0.3), "RR": (0.8, 30.0, 0.3)}
    force = sum(-burck(np.abs(slips[w]), *curves[w]) * fz[w] for w in WHEELS) + rng.normal(0.0, 30.0, n)
    fit = fit_joint(t, slips, fz, force, -1.0)
    assert fit is not None and fit.method == "joint per axle"
    for w in WHEELS:
        c1, c2, c3 = curves[w]
        s_star = np.log(c1 * c2 / c3) / c2
        mu_star = burck(np.array([s_star]), c1, c2, c3)[0]
        got = fit.curves[w]
        assert got.mu_peak is not None and abs(got.mu_peak / mu_star - 1.0) < 0.05, (w, got.mu_peak, mu_star)
        assert got.slip_at_mu_peak is not None and abs(got.slip_at_mu_peak - s_star) < 0.02


def test_the_force_delay_behind_the_slips_is_found_where_the_force_cycles() -> None:
    """Synthetic: four wheels cycling on one Magic Formula curve, each on a phase of its own, their total force seen
    12 ms late (a causal filter's delay): force_lag_s finds the delay within 2 ms, and the fit over the realigned
    force puts the peak where it is with the force on time (the delayed force's gives none, or one off by more than a point); a
    slowly varying force (a launch's) pins no delay down: 0."""
    rng = np.random.default_rng(2)
    n = 600
    t = np.arange(n) * 0.01
    phases = {"FL": 0.0, "FR": 0.1, "RL": 0.45, "RR": 0.6}
    slips = {w: -0.03 - 0.2 * np.abs(2.0 * ((7.0 * t + phases[w]) % 1.0) - 1.0) for w in WHEELS}
    a = np.full(n, -8.0)
    fz = {w: normal_loads_n(w, a, 1300.0, 0.6, 0.55, 2.6) for w in WHEELS}

    def total(s: dict[str, np.ndarray]) -> np.ndarray:
        return sum(-np.sin(1.9 * np.arctan(10.0 * np.abs(s[w]))) * fz[w] for w in WHEELS)  # type: ignore[return-value]

    force = total(slips)
    late = np.interp(t - 0.012, t, force) + rng.normal(0.0, 150.0, n)
    lag = force_lag_s(t, slips, fz, late, -1.0)
    assert abs(lag - 0.012) < 0.002, lag

    def peak_slip(f: np.ndarray) -> float | None:
        got = fit_joint(t, slips, fz, f, -1.0)
        return None if got is None else got.curves["FL"].slip_at_mu_peak

    on_time = peak_slip(force + rng.normal(0.0, 150.0, n))
    assert on_time is not None and abs(on_time - np.tan(np.pi / 3.8) / 10.0) < 0.005
    aligned = peak_slip(np.interp(t + lag, t, late))
    assert aligned is not None and abs(aligned - on_time) < 0.005
    delayed = peak_slip(late)  # the delay's own harm, which the alignment takes out: no curve, or one off
    assert delayed is None or abs(delayed - on_time) > 0.01

    ramp = {w: -0.02 - 0.2 * t / t[-1] for w in WHEELS}
    assert force_lag_s(t, ramp, fz, np.interp(t - 0.012, t, total(ramp)) + rng.normal(0.0, 150.0, n), -1.0) == 0.0


def test_the_force_delay_is_a_whole_sample_where_a_neighbour_of_the_best_has_no_fit(monkeypatch) -> None:
    """The parabola through the best three delays needs the neighbours' fits: where one has none (its error is
    infinite), the delay is the best whole sample, not NaN."""
    from slipdaq.maneuver import mu_joint

    n = 600
    t = np.arange(n) * 0.01
    phases = {"FL": 0.0, "FR": 0.1, "RL": 0.45, "RR": 0.6}
    slips = {w: -0.03 - 0.2 * np.abs(2.0 * ((7.0 * t + phases[w]) % 1.0) - 1.0) for w in WHEELS}
    fz = {w: normal_loads_n(w, np.full(n, -8.0), 1300.0, 0.6, 0.55, 2.6) for w in WHEELS}
    force = sum(-np.sin(1.9 * np.arctan(10.0 * np.abs(slips[w]))) * fz[w] for w in WHEELS)
    late = np.interp(t - 0.01, t, force)  # one sample late: the best delay is index k_max + 1 of the search
    assert abs(force_lag_s(t, slips, fz, late, -1.0) - 0.01) < 0.002
    k_max = round(mu_joint.LAG_MAX_S / 0.01)
    fit, calls = mu_joint._fit, []

    def no_fit_after_the_best(*args: Any) -> Any:
        calls.append(None)
        return None if len(calls) == k_max + 3 else fit(*args)  # the search's index k_max + 2: the best's right neighbour

    monkeypatch.setattr(mu_joint, "_fit", no_fit_after_the_best)
    assert force_lag_s(t, slips, fz, late, -1.0) == pytest.approx(0.01, abs=1e-12)
