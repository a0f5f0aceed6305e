"""The online stiffness fit keeps to the tire's linear region (estimator/linear_region.py): an ABS stop, whose
windows can have a small mean slip while the wheels cycle through the peak, neither drags the stored Cx nor stores
one of its own; the rule's measure, the wheels' slip spread within a window, on a smooth and an ABS-cycled wheel."""

from __future__ import annotations

import math

import numpy as np
import pytest

from slipdaq import WHEELS
from slipdaq.config import Config
from slipdaq.config.calibration import Calibration, merged
from slipdaq.estimator.linear_region import slip_spread
from slipdaq.estimator.ring import SeriesRing
from slipdaq.estimator.run_calibration import CX_CONFIDENT
from slipdaq.live.demo import demo_config, demo_settings
from slipdaq.pipeline import Pipeline
from slipdaq.sim.emit import SimSettings, generate
from slipdaq.sim.truth import linear_stiffness_truth, truth_series
from slipdaq.sinks import CollectingSink

ABS = "brake-abs-all"
CYCLE_SETTINGS = SimSettings(imu_rate_hz=100.0, brake_rate_hz=50.0, gps_noise_mps=0.03, can_jitter_s=0.0005, seed=3)


def drive(cfg: Config, scenario: str, settings: SimSettings, duration_s: float,
          calibration: Calibration | None = None):  # type: ignore[no-untyped-def]
    events = list(generate(cfg, scenario, "paved", settings, duration_s))  # type: ignore[arg-type]
    sink = CollectingSink()
    pipeline = Pipeline(cfg, [sink], calibration=calibration)
    pipeline.run(e.record for e in events if e.record is not None)
    rows = [e.as_row() | {"window_s": e.window_s} for e in sink.estimates]
    truth = truth_series([e.truth for e in events if e.truth is not None], settings.start_utc_s)
    return pipeline, rows, truth


@pytest.fixture(scope="module")
def learned_on_a_cycle():  # type: ignore[no-untyped-def]
    """The calibration a paved cycle stores, and each wheel's linear truth (the fit's slope through the true
    window means)."""
    cfg = demo_config("/dev/null", "chan", ABS)
    pipeline, rows, truth = drive(cfg, "cycle", CYCLE_SETTINGS, 40.0)
    cal = merged(None, pipeline.estimator.learned(), cfg, "cycle.mcap")
    expected = {w: linear_stiffness_truth(rows, truth, w) for w in WHEELS}
    return cfg, cal, expected


def test_the_cycle_stores_the_linear_cx(learned_on_a_cycle) -> None:  # type: ignore[no-untyped-def]
    _cfg, cal, expected = learned_on_a_cycle
    for w in WHEELS:
        assert expected[w] is not None
        assert cal.cx[w].cx_n == pytest.approx(expected[w], rel=0.05), w


def test_an_abs_stop_keeps_the_stored_cx(learned_on_a_cycle) -> None:  # type: ignore[no-untyped-def]
    """Every wheel cycles through the peak: its windows stay out of the fit, so the run's own Cx stays too uncertain
    to be stored and the stored one stays, within 5 % of the linear truth; the rule off (every window with |s| <= cx_slip_max, as
    before), the stop's windows across the brake's onset take every wheel's fit 30 % or more below it, confidently
    enough to be stored."""
    cfg, cal, expected = learned_on_a_cycle
    pipeline, _rows, _truth = drive(cfg, ABS, demo_settings(ABS), 14.0, calibration=cal)
    learned = pipeline.estimator.learned()
    assert learned.cx == {}
    after = merged(cal, learned, cfg, "abs.mcap")
    for w in WHEELS:
        assert after.cx[w].cx_n == cal.cx[w].cx_n == pytest.approx(expected[w], rel=0.05)
        assert pipeline.estimator.status()["cx_fit_conf"][w] < CX_CONFIDENT  # type: ignore[index]

    old_rule = cfg.with_overrides(estimator={"cx_fit_slip_spread_max": 1e9})
    pipeline, _rows, _truth = drive(old_rule, ABS, demo_settings(ABS), 14.0, calibration=cal)
    dragged = pipeline.estimator.learned().cx
    for w in WHEELS:
        assert dragged[w][0] < 0.7 * expected[w], (w, dragged[w])


def _ring(speed_mps, rate_hz: float = 100.0, t_end_s: float = 1.0, radius_m: float = 0.3) -> SeriesRing:
    """A wheel's revolutions sampled at rate_hz, from its speed over time."""
    ring = SeriesRing()
    t = np.arange(0.0, t_end_s, 1.0 / rate_hz)
    fine = np.linspace(0.0, t_end_s, 20001)
    revs = np.concatenate(([0.0], np.cumsum(np.diff(fine) * speed_mps(fine[1:]) / (2 * math.pi * radius_m))))
    ring.extend(t, np.interp(t, fine, revs))
    return ring


def test_slip_spread_small_when_the_wheel_follows_the_car_large_when_abs_cycles_it() -> None:
    """A wheel braking steadily with the car (constant deceleration, 2 % slip): its speed is a line, spread about 0. A
    wheel whose slip ABS cycles between 6 % and 18 % at 7 Hz (a sawtooth): about 2 %, above the default limit."""
    limit = Config().estimator.cx_fit_slip_spread_max
    car = lambda t: 20.0 - 6.0 * t  # noqa: E731
    steady = _ring(lambda t: car(t) * 0.98)
    assert slip_spread(steady, 0.25, 0.75) < 0.02 * limit
    saw = lambda t: 0.06 + 0.12 * ((t * 7.0) % 1.0)  # noqa: E731
    cycled = _ring(lambda t: car(t) * (1.0 - saw(t)))
    for t0 in (0.2, 0.25, 0.3, 0.37):  # wherever the window falls in the cycle
        spread = slip_spread(cycled, t0, t0 + 0.5)
        assert spread is not None and spread > limit
