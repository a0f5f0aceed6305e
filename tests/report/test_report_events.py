"""The report's maneuvers are events: a log with two accelerations has two accelerate maneuvers."""

from __future__ import annotations

import pytest

from slipdaq.config import load_config
from slipdaq.maneuver.events import MERGE_GAP_S, events
from slipdaq.pipeline import Pipeline
from slipdaq.report.summary import summarize_log
from slipdaq.sim.emit import SimSettings, generate
from slipdaq.sinks import CollectingSink
from support.paths import CONFIG


def test_a_cycle_log_has_one_maneuver_per_acceleration_and_per_braking() -> None:
    cfg = load_config(CONFIG)
    settings = SimSettings(gps_latency_s=0.0, gps_noise_mps=0.02, seed=3)
    sink = CollectingSink()
    Pipeline(cfg, [sink]).run([e.record for e in generate(cfg, "cycle", "paved", settings, 45.0) if e.record is not None])
    rows = [e.as_row() | {"window_s": e.window_s} for e in sink.estimates]
    log = summarize_log(rows, {}, None, path="x.mcap", name="x", labels={})
    accelerations = [m for m in log.maneuvers if m.phase == "accelerate"]
    brakings = [m for m in log.maneuvers if m.phase == "brake"]
    # the cycle: 0-60 km/h, 3 s cruise, brake to a stop, again: three starts in 45 s, and two or three stops
    assert len(accelerations) == 3 and len(brakings) >= 2
    assert [m.title for m in accelerations] == [f"accelerate 0–60 km/h #{k}" for k in (1, 2, 3)]
    assert [m.key for m in accelerations] == ["accelerate-1", "accelerate-2", "accelerate-3"]
    for a, b in zip(accelerations, accelerations[1:]):
        assert a.t_end_s < b.t_start_s  # one event each, in time order
    for m in accelerations:
        assert m.t_end_s - m.t_start_s < 8.0  # 60 km/h at 2.8 m/s²: 6 s, not the whole log
        assert all(r["phase"] == "accelerate" for r in m.rows)
    assert len({m.key for m in log.maneuvers}) == len(log.maneuvers)


def test_a_short_cruise_inside_an_acceleration_does_not_split_it() -> None:
    t = [0.1 * i for i in range(60)]
    phases = ["accelerate"] * 20 + ["cruise"] * 5 + ["accelerate"] * 15 + ["brake"] * 20
    ev = events(phases, t)
    assert [(p, len(rows)) for p, rows in ev] == [("accelerate", 35), ("brake", 20)]
    gap = int(MERGE_GAP_S / 0.1) + 1  # a cruise as long as MERGE_GAP_S: two events
    phases = ["accelerate"] * 20 + ["cruise"] * gap + ["accelerate"] * 15
    ev = events(phases, [0.1 * i for i in range(len(phases))])
    assert [p for p, _ in ev] == ["accelerate", "cruise", "accelerate"]
    phases = ["accelerate"] * 20 + ["standstill"] * 3 + ["accelerate"] * 15  # a stop between: two events
    assert [p for p, _ in events(phases, [0.1 * i for i in range(len(phases))])] == [
        "accelerate", "standstill", "accelerate"]


def test_the_report_line_is_the_consistent_fit_and_a_slip_offset_does_not_move_it() -> None:
    """Slip on force with an intercept (errors in variables, the noise from the cruise windows), anchored by the cruise
    windows: against the truth's stiffness over the run
    (1 / the slope of true slip on true force), and unmoved by a radius error (every slip offset by 0.4 points),
    which moves the line through the origin by tens of percent."""
    from slipdaq.maneuver.linearity import fit_through_origin
    from slipdaq.sim.truth import linear_stiffness_truth, truth_series

    cfg = load_config(CONFIG)
    settings = SimSettings(gps_latency_s=0.085, gps_noise_mps=0.03, can_jitter_s=0.0005, seed=7)
    events_ = list(generate(cfg, "cycle", "paved", settings, 45.0, r0_offset_m=-0.008))
    sink = CollectingSink()
    Pipeline(cfg, [sink]).run([e.record for e in events_ if e.record is not None])
    rows = [e.as_row() | {"window_s": e.window_s} for e in sink.estimates]
    truth = truth_series([e.truth for e in events_ if e.truth is not None], settings.start_utc_s)
    shifted = [r | {f"slip_{w}": None if r[f"slip_{w}"] is None else r[f"slip_{w}"] + 0.004 for w in ("FL", "FR")}
               for r in rows]
    log, log_shifted = (summarize_log(x, {"config_toml": cfg.to_toml()}, None, path="x", name="x", labels={})
                        for x in (rows, shifted))
    for w in ("FL", "FR"):
        truth_cx = linear_stiffness_truth(rows, truth, w)
        assert truth_cx is not None
        lines = [m.wheels[w].linearity.line for m in log.maneuvers if m.phase == "accelerate"]
        moved = [m.wheels[w].linearity.line for m in log_shifted.maneuvers if m.phase == "accelerate"]
        assert len(lines) == 3 and all(x is not None and x.method == "errors-in-variables" for x in lines + moved)
        for k, (line, other) in enumerate(zip(lines, moved)):
            if k:  # the first acceleration changes radius midway (tire size, then calibrated): its slips move
                assert line.cx_n == pytest.approx(truth_cx, rel=0.10)
            assert other.cx_n == pytest.approx(line.cx_n, rel=0.01)
            assert other.slip_offset == pytest.approx(line.slip_offset + 0.004, abs=0.0005)
        m = next(m for m in log_shifted.maneuvers if m.phase == "accelerate")
        origin = fit_through_origin([(r[f"slip_{w}"], r[f"force_{w}_n"]) for r in m.rows
                                     if r[f"slip_{w}"] is not None and r[f"force_{w}_n"] and r[f"slip_{w}"] > 0.005])
        assert origin is not None and origin.cx_n < 0.8 * truth_cx  # what the line through the origin made of it
