"""Maneuvers decided online (/maneuver): against the simulator's truth, against the report of the same log (one
rule for live, replay and report), their validity against the test day's targets, and their CSV."""

from __future__ import annotations

import csv
import json
from pathlib import Path

import jsonschema
import numpy as np
import pytest
from mcap.reader import make_reader

from slipdaq import WHEELS
from slipdaq.cli import main
from slipdaq.config import Config, load_config
from slipdaq.export.csv_file import MANEUVER_CSV_COLUMNS
from slipdaq.live.demo import demo_config, demo_settings
from slipdaq.logformat.reader import iter_topic
from slipdaq.logformat.registry import TOPIC_FORMATS
from slipdaq.logformat.topics import TOPIC_MANEUVER
from slipdaq.maneuver.detector import ManeuverDetector
from slipdaq.maneuver.record import Maneuver
from slipdaq.pipeline import Pipeline
from slipdaq.sim import vehicle
from slipdaq.sim.emit import SimEvent, SimSettings, generate
from slipdaq.sim.truth import mfdd_mps2, speed_at_onset_mps, stopping_distance_m, truth_series
from slipdaq.sinks import CollectingSink
from slipdaq.sinks.mcap_log import McapLogSink
from support.paths import CONFIG

SETTINGS = SimSettings(gps_latency_s=0.0, gps_noise_mps=0.02, can_jitter_s=0.0005, seed=3)


def with_targets(cfg: Config, targets: list[float], tolerance: float) -> Config:
    return cfg.with_overrides(test={"target_speeds_kmh": targets, "speed_tolerance_kmh": tolerance})


def simulate(cfg: Config, scenario: str, duration_s: float, settings: SimSettings = SETTINGS, road: str = "paved"
             ) -> tuple[list[SimEvent], CollectingSink]:
    events = list(generate(cfg, scenario, road, settings, duration_s))  # type: ignore[arg-type]
    sink = CollectingSink()
    Pipeline(cfg, [sink]).run([e.record for e in events if e.record is not None])
    return events, sink


def truth_stops(events: list[SimEvent], windows: list[tuple[float, float]]) -> list[dict[str, float | None]]:
    """Brake speed, stopping distance and MFDD of the truth's stop in each (from, to) of sim time, the onset where
    the deceleration begins (the profile model has no brake pedal)."""
    series = truth_series([e.truth for e in events if e.truth is not None], 0.0)
    out = []
    for t0, t1 in windows:
        keep = (series["time_s"] >= t0) & (series["time_s"] < t1)
        part = {k: v[keep] for k, v in series.items()}
        part["brake_pressed"] = part["accel_mps2"] < -1e-9
        v0 = speed_at_onset_mps(part)
        out.append({"brake_speed_kmh": None if v0 is None else v0 * 3.6, "stopping_distance_m": stopping_distance_m(part),
                    "mfdd_mps2": mfdd_mps2(part)})
    return out


def write_log(cfg: Config, events: list[SimEvent], path: Path) -> None:
    sink = McapLogSink(path, cfg, "import")
    Pipeline(cfg, [sink]).run([e.record for e in events if e.record is not None])
    sink.close()


def logged_maneuvers(path: Path) -> list[tuple[float, dict]]:
    """(log time s, record) of each /maneuver message."""
    return [(t / 1e9, d) for _topic, t, d in iter_topic(path, (TOPIC_MANEUVER,))]


# ---- the simulator's drives against their truth --------------------------------------------------------------

def test_abs_stop_from_80_live_against_truth() -> None:
    """ABS stop from 80 km/h with the brake switch: MFDD within 1 %, stopping distance within 0.5 m, brake speed
    within 1 km/h of the truth; valid against a target of 80 +- 2, decided within 2 s of the stop."""
    cfg = with_targets(demo_config("/dev/null", "chan", "brake-abs"), [80.0], 2.0)
    events, sink = simulate(cfg, "brake-abs", 14.0, demo_settings("brake-abs"))
    truth = [e.truth for e in events if e.truth is not None]
    assert [m.kind for m in sink.maneuvers] == ["brake"]
    m = sink.maneuvers[0]
    v0, d, mfdd = speed_at_onset_mps(truth), stopping_distance_m(truth), mfdd_mps2(truth)
    assert v0 is not None and d is not None and mfdd is not None
    assert m.brake_speed_kmh is not None and abs(m.brake_speed_kmh - v0 * 3.6) <= 1.0
    assert m.stopping_distance_m is not None and abs(m.stopping_distance_m - d) <= 0.5
    assert m.mfdd_mps2 is not None and abs(m.mfdd_mps2 / mfdd - 1.0) <= 0.01
    assert m.valid and m.invalid_reasons == () and m.target_speed_kmh == 80.0
    assert m.abs_cycles is not None and m.abs_cycles >= 10 and m.abs_frequency_hz is not None
    assert abs(m.abs_frequency_hz - 7.0) < 0.5
    assert m.speed_to_kmh < 1.0 and abs(m.speed_from_kmh - 80.0) < 3.0


def test_abs_stop_is_decided_soon_after_the_car_stops(tmp_path: Path) -> None:
    """The /maneuver record's log time is when it was decided: after the stop, within 2.5 s of it."""
    cfg = demo_config("/dev/null", "chan", "brake-abs")
    events = list(generate(cfg, "brake-abs", "paved", demo_settings("brake-abs"), 14.0))
    write_log(cfg, events, tmp_path / "abs.mcap")
    (t_log, rec), = logged_maneuvers(tmp_path / "abs.mcap")
    truth = truth_series([e.truth for e in events if e.truth is not None], 0.0)
    stop = float(truth["time_s"][np.flatnonzero(truth["speed_mps"] <= 0.0)[0]])
    t0 = next(e.record.timestamp_s for e in events if e.record is not None)
    assert 0.0 < (t_log - t0) - stop < 2.5


def test_test_day_drive_two_accelerations_two_stops() -> None:
    """0–60, 60–0, 0–33, 33–0 km/h: exactly 2 + 2 maneuvers in order, speeds within 3 km/h, MFDD within 3 %; every
    one valid against targets 60 and 33 +- 3. No brake signal here: the onset comes from the deceleration's rise and
    the stopping distance is within 1.5 m (0.5 m with the brake switch, test_abs_stop_from_80_live_against_truth)."""
    cfg = with_targets(load_config(CONFIG), [60.0, 33.0], 3.0)
    events, sink = simulate(cfg, "test-day", 36.0)
    ms = sink.maneuvers
    assert [m.kind for m in ms] == ["accelerate", "brake", "accelerate", "brake"]
    assert [m.index for m in ms] == [1, 2, 3, 4]
    expected = [(0.0, 60.0), (60.0, 0.0), (0.0, 33.0), (33.0, 0.0)]
    for m, (v_from, v_to) in zip(ms, expected):
        assert abs(m.speed_from_kmh - v_from) <= 3.0 and abs(m.speed_to_kmh - v_to) <= 3.0, m
        assert m.valid, m.invalid_reasons
    assert [m.target_speed_kmh for m in ms] == [60.0, 60.0, 33.0, 33.0]
    stops = truth_stops(events, [(9.0, 19.0), (24.0, 34.0)])
    for m, t in zip((ms[1], ms[3]), stops):
        assert t["mfdd_mps2"] is not None and m.mfdd_mps2 is not None
        assert abs(m.mfdd_mps2 / t["mfdd_mps2"] - 1.0) <= 0.03
        assert m.stopping_distance_m is not None and t["stopping_distance_m"] is not None
        assert abs(m.stopping_distance_m - t["stopping_distance_m"]) <= 1.5
        assert m.brake_speed_kmh is not None and t["brake_speed_kmh"] is not None
        assert abs(m.brake_speed_kmh - t["brake_speed_kmh"]) <= 1.0
    # time to speed: the profile's 0 -> 60 km/h takes the ramps (2 x 0.5 s) and dv / a at 2.8 m/s^2
    true_0_60 = 2 * vehicle.JERK_RAMP_S + (60.0 / 3.6) / vehicle.ACCEL_MPS2["paved"] - vehicle.JERK_RAMP_S
    assert ms[0].time_to_speed_s is not None and abs(ms[0].time_to_speed_s - true_0_60) < 0.4
    # the same drive against a target of 50 +- 2: no stop began there, and the 0-33 never reached it
    cfg50 = with_targets(cfg, [50.0], 2.0)
    sink50 = CollectingSink()
    Pipeline(cfg50, [sink50]).run([e.record for e in events if e.record is not None])
    by_index = {m.index: m for m in sink50.maneuvers}
    for i in (2, 4):
        m = by_index[i]
        assert not m.valid and m.target_speed_kmh is None
        assert any("brake speed" in r and "50 km/h" in r and f"{m.brake_speed_kmh:.1f}" in r for r in m.invalid_reasons)
    assert by_index[1].valid and by_index[1].target_speed_kmh == 50.0
    assert not by_index[3].valid and any("below the lowest target 50 km/h" in r for r in by_index[3].invalid_reasons)


@pytest.mark.parametrize(("scenario", "duration_s", "kinds"), [
    ("cycle", 29.0, ["accelerate", "brake", "accelerate", "brake"]),
    ("brake", 12.0, ["brake"]),
    ("accelerate", 16.0, ["accelerate"]),
    ("brake-lock", 10.0, ["brake"]),
    ("launch-spin", 12.0, ["accelerate"]),
])
def test_scenarios_give_their_maneuvers(scenario: str, duration_s: float, kinds: list[str]) -> None:
    """Each scenario's maneuvers, in order, with a speed range the truth passed through."""
    cfg = demo_config("/dev/null", "chan", scenario)
    settings = demo_settings(scenario) if scenario in ("brake-lock", "launch-spin") else SETTINGS
    events, sink = simulate(cfg, scenario, duration_s, settings)
    assert [m.kind for m in sink.maneuvers] == kinds
    speeds = truth_series([e.truth for e in events if e.truth is not None], 0.0)["speed_mps"] * 3.6
    for m in sink.maneuvers:
        lo, hi = sorted((m.speed_from_kmh, m.speed_to_kmh))
        assert speeds.min() - 3.0 <= lo and hi <= speeds.max() + 3.0 and hi - lo > 20.0
        if m.kind == "brake" and m.stopping_distance_m is not None:
            assert m.brake_speed_kmh is not None and m.brake_speed_kmh > 20.0


# ---- one rule: live, replay and report -------------------------------------------------------------------------

def test_live_maneuvers_equal_the_report_and_replay(tmp_path: Path) -> None:
    """The log's /maneuver records equal `report --live`'s records of the same log field by field, replay gives the
    same records, and each validates against the schema the log carries."""
    cfg = demo_config("/dev/null", "chan", "brake-abs")
    events = list(generate(cfg, "brake-abs", "sand", demo_settings("brake-abs"), 14.0))
    log = tmp_path / "abs.mcap"
    write_log(cfg, events, log)
    live = [d for _t, d in logged_maneuvers(log)]
    assert [d["kind"] for d in live] == ["brake"]
    assert main(["report", str(log), "--live", "-o", str(tmp_path / "rep")]) == 0
    doc = json.loads((tmp_path / "rep" / "summary.json").read_text())
    assert doc["logs"][0]["maneuver_records"] == live
    assert "maneuver #1 brake" not in (tmp_path / "rep" / "index.html").read_text()  # the page has its own table
    assert main(["replay", str(log), "-o", str(tmp_path / "again.mcap")]) == 0
    assert [d for _t, d in logged_maneuvers(tmp_path / "again.mcap")] == live
    with open(log, "rb") as f:
        schemas = {c.topic: json.loads(s.data) for s, c, _m in make_reader(f).iter_messages(topics=[TOPIC_MANEUVER])
                   for _ in (0,)}
    assert json.loads(TOPIC_FORMATS[TOPIC_MANEUVER].schema_data) == schemas[TOPIC_MANEUVER]
    for d in live:
        jsonschema.validate(d, schemas[TOPIC_MANEUVER])


def test_report_lists_the_same_maneuvers_over_two_pass(tmp_path: Path) -> None:
    """The default (two-pass) report lists its maneuvers by the same rule: the same kinds and count as live."""
    cfg = load_config(CONFIG)
    events = list(generate(cfg, "test-day", "paved", SETTINGS, 36.0))
    log = tmp_path / "day.mcap"
    write_log(cfg, events, log)
    assert main(["report", str(log), "-o", str(tmp_path / "rep")]) == 0
    doc = json.loads((tmp_path / "rep" / "summary.json").read_text())
    recs = doc["logs"][0]["maneuver_records"]
    assert [r["kind"] for r in recs] == [d["kind"] for _t, d in logged_maneuvers(log)]
    html = (tmp_path / "rep" / "index.html").read_text()
    assert html.count('<table class="records">') == 1


def test_maneuvers_csv_is_the_records(tmp_path: Path) -> None:
    cfg = with_targets(load_config(CONFIG), [50.0], 2.0)
    events = list(generate(cfg, "test-day", "paved", SETTINGS, 36.0))
    log = tmp_path / "day.mcap"
    write_log(cfg, events, log)
    out = tmp_path / "m.csv"
    assert main(["export", str(log), "--maneuvers-csv", str(out)]) == 0
    with open(out, newline="") as f:
        rows = list(csv.DictReader(f))
    assert tuple(rows[0]) == MANEUVER_CSV_COLUMNS
    assert {"mean_slip_FL", "cx_line_n_RR", "mu_peak_FR", "slip_at_mu_peak_RL", "max_abs_slip_FL"} <= set(rows[0])
    live = [d for _t, d in logged_maneuvers(log)]
    assert len(rows) == len(live) == 4
    for row, d in zip(rows, live):
        assert row["kind"] == d["kind"] and int(row["index"]) == d["index"]
        assert row["valid"] == ("true" if d["valid"] else "false")
        assert row["invalid_reasons"] == "; ".join(d["invalid_reasons"])
        for w in WHEELS:
            v = d[f"mean_slip_{w}"]
            assert (row[f"mean_slip_{w}"] == "") if v is None else float(row[f"mean_slip_{w}"]) == v
        assert float(row["speed_from_kmh"]) == d["speed_from_kmh"]


# ---- validity beyond the speed -------------------------------------------------------------------------------

def test_a_reader_stall_inside_a_maneuver_invalidates_it() -> None:
    """A CAN reader stall during the 0-60 acceleration: its windows are disturbed and the maneuver says so."""
    cfg = load_config(CONFIG)
    settings = SimSettings(gps_latency_s=0.0, gps_noise_mps=0.02, can_jitter_s=0.0005, seed=3, can_stall=(5.0, 0.3))
    _events, sink = simulate(cfg, "test-day", 12.0, settings)
    m = next(m for m in sink.maneuvers if m.kind == "accelerate")
    assert not m.valid and any("disturbed windows" in r for r in m.invalid_reasons)


def test_records_are_valid_without_targets_and_state_why_not() -> None:
    """Without [test] targets no speed is judged; the reasons are short texts, empty when valid."""
    cfg = load_config(CONFIG)
    _events, sink = simulate(cfg, "test-day", 36.0)
    assert all(m.valid and m.target_speed_kmh is None for m in sink.maneuvers)
    assert all(isinstance(m, Maneuver) and m.invalid_reasons == () for m in sink.maneuvers)


# ---- the detector's closing rule --------------------------------------------------------------------------------

def _row(t: float, phase: str) -> dict:
    return {"time_s": t, "phase": phase, "speed_mps": 10.0, "window_s": 0.5, "slip_FL": 0.01, "force_FL_n": 100.0}


def test_an_acceleration_is_decided_once_nothing_can_join_it() -> None:
    """A run of accelerate rows followed by cruise stays open until MERGE_GAP_S of cruise have passed (a gear change
    joins two runs), then is decided once its span's end is covered; a brake run after it closes it at once."""
    det = ManeuverDetector(None, phases=("accelerate", "brake"))
    t = 0.0
    for _ in range(20):
        det.add_estimate(_row(t, "accelerate"))
        t += 0.1
    decided = []
    for _ in range(10):  # 1 s of cruise: a gear change could still join the next run
        decided += det.add_estimate(_row(t, "cruise"))
        decided += det.add_fast([{"time_s": t, "speed_mps": 10.0, "accel_mps2": 0.0}])
        t += 0.1
    assert not decided
    for _ in range(5):  # accelerate again: one event with the first run
        det.add_estimate(_row(t, "accelerate"))
        t += 0.1
    for _ in range(25):
        decided += det.add_estimate(_row(t, "cruise"))
        decided += det.add_fast([{"time_s": t, "speed_mps": 10.0, "accel_mps2": 0.0}])
        t += 0.1
    (m,) = [job() for job in decided]
    assert m.phase == "accelerate" and len(m.rows) == 25
    decided = []
    for _ in range(10):
        decided += det.add_estimate(_row(t, "brake"))
        t += 0.1
    for _ in range(3):
        decided += det.add_estimate(_row(t, "accelerate"))
        decided += det.add_fast([{"time_s": t + 5.0, "speed_mps": 10.0, "accel_mps2": 0.0}])
        t += 0.1
    (b,) = [job() for job in decided]
    assert b.phase == "brake" and len(b.rows) == 10
    assert [job().phase for job in det.finish()] == []  # 3 rows: too few for a maneuver


def test_noise_rows_inside_a_short_cruise_do_not_keep_an_acceleration_open() -> None:
    """Acceleration, 0.7 s of cruise, one brake row and one accelerate row (noise on a: two lone rows of different
    phases, which debouncing keeps), more cruise: nothing can join the acceleration any more, so it is decided; and
    so is every maneuver after it (kept open, it held every later row until the end of the run)."""
    det = ManeuverDetector(None, phases=("accelerate", "brake"))
    t = 0.0
    decided: list = []

    def rows(phase: str, n: int) -> None:
        nonlocal t
        for _ in range(n):
            decided.extend(det.add_estimate(_row(t, phase)))
            decided.extend(det.add_fast([{"time_s": t, "speed_mps": 10.0, "accel_mps2": 0.0}]))
            t += 0.1

    def take() -> list:
        out = [job() for job in decided]
        decided.clear()
        return out

    rows("accelerate", 20)
    rows("cruise", 7)
    rows("brake", 1)
    rows("accelerate", 1)
    rows("cruise", 21)
    (m,) = take()
    assert m.phase == "accelerate" and len(m.rows) == 20
    for _ in range(50):
        rows("brake", 10)
        rows("cruise", 30)
    assert [m.phase for m in take()] == ["brake"] * 50
    assert len(det._rows) < 40  # only the open event's rows are kept


# ---- on the car: the live daemon on python-can's virtual bus, the status stream and the terminal view ----------

def test_demo_brake_abs_prints_the_stop_as_it_ends(tmp_path: Path) -> None:
    """`slipdaq demo --scenario brake-abs` live: the stop's line on the status stream (no terminal) once decided,
    before the run ends; the log's /maneuver record is the one the run reports."""
    import asyncio
    import io

    from rich.console import Console

    from slipdaq.live.demo import run_demo_async
    from slipdaq.sinks.status import SourceStatus, StatusSink, _Rates, render

    status_path = tmp_path / "status.txt"
    with open(status_path, "w") as status:
        result, _err, _cfg = asyncio.run(run_demo_async(11.0, "brake-abs", "paved", tmp_path, status_stream=status,
                                                        status_every_s=2.0))
    lines = status_path.read_text().splitlines()
    stop_lines = [ln for ln in lines if ln.startswith("maneuver #1 brake")]
    # the verdict is there: valid, or on a host too busy for the real-time simulator, invalid for its gaps
    assert len(stop_lines) == 1 and "MFDD" in stop_lines[0] and "ABS" in stop_lines[0]
    assert "| valid" in stop_lines[0] or "| INVALID: " in stop_lines[0] and "disturbed windows" in stop_lines[0]
    assert lines.index(stop_lines[0]) < len(lines) - 1  # printed while the run went on, not only at its end
    (rec,) = result.maneuvers
    assert [d for _t, d in logged_maneuvers(result.log_path)] == [rec.as_row()]
    assert rec.kind == "brake" and rec.abs_cycles and rec.brake_speed_kmh and abs(rec.brake_speed_kmh - 80.0) < 2.0
    # the terminal view: the maneuvers table under the wheels, newest first
    sink = StatusSink(SourceStatus())
    for m in (rec, Maneuver(**{**{f: getattr(rec, f) for f in rec.__slots__}, "index": 2, "valid": False,  # type: ignore[attr-defined]
                                "invalid_reasons": ("too short to judge (0.4 s, 3 km/h)",)})):
        sink.on_maneuver(m, 0.0)
    out = io.StringIO()
    Console(file=out, width=200).print(render(sink, _Rates()))
    rows = [ln for ln in out.getvalue()[out.getvalue().index("maneuvers"):].splitlines() if " brake " in ln]
    assert len(rows) == 2 and "INVALID: too short" in rows[0] and "INVALID" not in rows[1] and "valid" in rows[1]


def test_summaries_on_a_thread_give_the_same_records_in_order() -> None:
    """The live daemon computes each maneuver's summary on a thread (its fits never hold up reading): the records are
    those of the synchronous pipeline, in the same order, each delivered with a record processed after the one that
    decided it."""
    from concurrent.futures import ThreadPoolExecutor

    from slipdaq.records import Estimate

    cfg = load_config(CONFIG)
    events = list(generate(cfg, "test-day", "paved", SETTINGS, 36.0))
    records = [e.record for e in events if e.record is not None]
    sync = CollectingSink()
    Pipeline(cfg, [sync]).run(records)

    class Timed(CollectingSink):
        def __init__(self) -> None:
            super().__init__()
            self.times: list[float] = []
            self.last_estimate_s = 0.0

        def on_estimate(self, estimate: Estimate, log_time_s: float) -> None:
            super().on_estimate(estimate, log_time_s)
            self.last_estimate_s = log_time_s

        def on_maneuver(self, maneuver: Maneuver, log_time_s: float) -> None:
            super().on_maneuver(maneuver, log_time_s)
            self.times.append(log_time_s)

    threaded = Timed()
    with ThreadPoolExecutor(max_workers=1) as pool:
        Pipeline(cfg, [threaded], maneuver_executor=pool).run(records)
    assert [m.as_row() for m in threaded.maneuvers] == [m.as_row() for m in sync.maneuvers]
    assert len(threaded.maneuvers) == 4 and threaded.times == sorted(threaded.times)
