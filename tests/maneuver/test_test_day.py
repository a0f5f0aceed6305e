"""A real test day on the simulator: the host clock off UTC, calibration that persists between runs, every estimate's
quality, disturbed windows (a CAN reader stall), and two-pass post-processing (issue: a real test day)."""

from __future__ import annotations

import csv
import tomllib
from pathlib import Path

import pytest

from slipdaq import WHEELS
from slipdaq.cli import main
from slipdaq.config import Config, load_config
from slipdaq.config.calibration import (
    Calibration,
    StoredRadius,
    for_run,
    load_calibration,
    merged,
    save_calibration,
)
from slipdaq.export.csv_file import ALL_COLUMNS
from slipdaq.logformat.reader import iter_estimates, read_metadata
from slipdaq.logformat.topics import TOPIC_ESTIMATE
from slipdaq.offline.run import first_pass
from slipdaq.pipeline import Pipeline
from slipdaq.records import SourceEvent
from slipdaq.sim.emit import SimSettings, generate
from slipdaq.sim.logs import write_drive_logs
from slipdaq.sim.truth import slip_error, slip_errors, truth_series
from slipdaq.sinks import CollectingSink
from support.paths import CONFIG, ROOT

R0_OFFSET_M = -0.008
OFF_UTC = SimSettings(gps_latency_s=0.085, gps_noise_mps=0.03, can_jitter_s=0.0005, host_clock_offset_s=3.0, seed=7)
"""The host clock 3 s off UTC: the UTC method of the latency is implausible, the wheels must find it."""


class _Events(CollectingSink):
    def __init__(self) -> None:
        super().__init__()
        self.events: list[SourceEvent] = []

    def on_source_event(self, event: SourceEvent) -> None:
        self.events.append(event)


def drive(cfg: Config, settings: SimSettings = OFF_UTC, duration_s: float = 30.0, calibration: Calibration | None = None,
          frozen: bool = False, gps_speeds: list[float] | None = None, scenario: str = "cycle",
          road: str = "paved"):  # type: ignore[no-untyped-def]
    events = list(generate(cfg, scenario, road, settings, duration_s, r0_offset_m=R0_OFFSET_M))
    records = [e.record for e in events if e.record is not None]
    truth = [e.truth for e in events if e.truth is not None]
    sink = _Events()
    pipeline = Pipeline(cfg, [sink], calibration=calibration, frozen=frozen, gps_speeds=gps_speeds)
    pipeline.run(records)
    rows = [e.as_row() | {"window_s": e.window_s} for e in sink.estimates]
    return sink, rows, truth_series(truth, settings.start_utc_s + settings.host_clock_offset_s), truth[-1], pipeline


@pytest.fixture(scope="module")
def cfg_() -> Config:
    return load_config(CONFIG)


@pytest.fixture(scope="module")
def cold(cfg_: Config):  # type: ignore[no-untyped-def]
    return drive(cfg_)


# ---- 2. cold start without UTC --------------------------------------------------------------------------------------

def test_cold_off_utc_finds_the_latency_early_and_flags_what_came_before(cold) -> None:  # type: ignore[no-untyped-def]
    sink, rows, truth, _, pipeline = cold
    assert pipeline.estimator.latency.source == "wheels"
    assert pipeline.estimator.latency.latency_s == pytest.approx(0.085, abs=0.005)
    before = [r for r in rows if r["latency_source"] == "none"]
    assert before, "the run starts with the latency unknown"
    assert all(r["quality"] != "ok" for r in before)
    # the latency is known within the first acceleration (the first ~6 s of the cycle), not a cycle later
    moving = [r for r in rows if r["speed_mps"] > 1.0]
    known = next(r for r in moving if r["latency_source"] == "wheels")
    assert known["time_s"] - moving[0]["time_s"] < 2.5
    # no window presents a slip far off: the ones whose speed changes with the latency unknown have none
    errors = slip_errors(rows, truth)
    assert len(errors) > 400 and abs(errors).max() * 100 < 5.0
    assert all(r[f"slip_{w}"] is None for r in before if abs(r["accel_mps2"] or 1.0) > 0.3 for w in WHEELS)
    ok = [r for r in rows if r["quality"] == "ok"]
    assert len(ok) > 0.6 * len(rows)
    assert slip_error(ok, truth).rms_points < 0.3


@pytest.mark.parametrize("wpt_rate_hz", [25.0, 100.0])
def test_cold_off_utc_finds_a_latency_near_zero(cfg_, wpt_rate_hz: float) -> None:  # type: ignore[no-untyped-def]
    """A receiver and reader with almost no delay (the lab, the HIL VM): the lag's minimum is at the grid's 0, which
    must still count as an estimate."""
    settings = SimSettings(gps_latency_s=0.0, gps_noise_mps=0.02, can_jitter_s=0.0005, host_clock_offset_s=3.0,
                           seed=1, wpt_rate_hz=wpt_rate_hz)
    _, rows, truth, _, pipeline = drive(cfg_, settings, duration_s=20.0)
    assert pipeline.estimator.latency.source == "wheels"
    assert pipeline.estimator.latency.latency_s == pytest.approx(0.0, abs=0.004)
    assert slip_error([r for r in rows if r["quality"] == "ok"], truth).rms_points < 0.3


def test_cold_off_utc_with_every_wheel_driven_finds_the_latency_too(cfg_) -> None:  # type: ignore[no-untyped-def]
    """No wheel rolls freely while the car accelerates: the fit takes their slip in proportion to the acceleration."""
    awd = cfg_.with_overrides(vehicle={"driven_axle": "all"})
    _, rows, truth, _, pipeline = drive(awd)
    assert pipeline.estimator.latency.source == "wheels"
    assert pipeline.estimator.latency.latency_s == pytest.approx(0.085, abs=0.005)
    moving = [r for r in rows if r["speed_mps"] > 1.0]
    known = next(r for r in moving if r["latency_source"] == "wheels")
    assert known["time_s"] - moving[0]["time_s"] < 3.0
    errors = slip_errors(rows, truth)
    fast = [r for r in rows if r["speed_mps"] > 5.0 and r["source"] == "gps"]
    assert len(errors) > 0.9 * 4 * len(fast), "slip in nearly every window, not withheld for an unknown latency"
    assert abs(errors).max() * 100 < 5.0
    assert slip_error([r for r in rows if r["quality"] == "ok"], truth).rms_points < 0.3


def test_a_wheel_latency_resting_on_a_slip_model_never_replaces_utc(cfg_) -> None:  # type: ignore[no-untyped-def]
    """Every wheel driven, on sand, the host on UTC: the UTC latency stays. The wheels' estimate, from a model of
    their slip that sand bends, is 20 ms off here and took over for a third of the run when it could."""
    awd = cfg_.with_overrides(vehicle={"driven_axle": "all"})
    settings = SimSettings(gps_latency_s=0.085, gps_noise_mps=0.03, can_jitter_s=0.0005, seed=7)
    _, rows, _, _, pipeline = drive(awd, settings, duration_s=30.0, road="sand")
    assert pipeline.estimator.status()["gps_latency_wheels_s"] is not None  # it has one
    assert {r["latency_source"] for r in rows[20:]} == {"utc"}


def test_quality_is_a_csv_column_after_the_others_and_a_field_of_the_estimate() -> None:
    names = list(ALL_COLUMNS)
    assert names[-2:] == ["quality", "accel_source"]  # columns added later come after it
    assert names.index("quality") > names.index("cx_fit_RR_conf")
    from slipdaq.logformat.schemas import SCHEMAS

    assert SCHEMAS[TOPIC_ESTIMATE]["properties"]["quality"]["enum"] == ["ok", "uncalibrated", "disturbed"]


# ---- 1. calibration that persists -----------------------------------------------------------------------------------

def test_learned_calibration_round_trips_and_starts_the_next_run_warm(cold, cfg_, tmp_path) -> None:  # type: ignore[no-untyped-def]
    _, _, _, last, pipeline = cold
    learned = pipeline.estimator.learned()
    assert learned.latency is not None and learned.latency[2] == "wheels"
    assert set(learned.r0) == set(WHEELS) and {"FL", "FR"} <= set(learned.cx)
    assert learned.host_clock_offset_s == pytest.approx(3.0, abs=0.01)
    path = tmp_path / "calibration.toml"
    save_calibration(path, merged(None, learned, cfg_, "drive-1.mcap", "2026-11-25T10:00:00Z"))
    data = tomllib.loads(path.read_text())  # a TOML file, read back by the standard library
    assert data["latency"]["method"] == "wheels" and data["r0"]["FL"]["learned_from"] == "drive-1.mcap"
    for w in WHEELS:
        assert data["r0"][w]["radius_m"] == pytest.approx(last.wheels[w].r0_m, abs=0.0003)
    stored = load_calibration(path)
    assert stored is not None

    # the next run of the same car, another drive, host clock still off UTC: right from its first window
    settings = SimSettings(gps_latency_s=0.085, gps_noise_mps=0.03, can_jitter_s=0.0005, host_clock_offset_s=-41.0,
                           seed=8)
    sink, rows, truth, _, warm = drive(cfg_, settings, calibration=stored)
    assert rows[0]["latency_source"] == "stored" and rows[0]["r0_source_FL"] == "stored"
    assert not sink.events, "a calibration the run agrees with is not replaced"
    first_accel = [r for r in rows if r["time_s"] - rows[0]["time_s"] < 6.0]
    assert all(r[f"slip_{w}"] is not None for r in first_accel if r["speed_mps"] > 5 for w in WHEELS)
    assert slip_error(rows, truth).rms_points < 0.2
    assert all(r["quality"] == "ok" for r in rows if r["source"] == "gps" and r["speed_mps"] > 1.0)


def test_a_stored_value_the_run_contradicts_is_replaced_with_an_event(cold, cfg_) -> None:  # type: ignore[no-untyped-def]
    _, _, _, last, pipeline = cold
    good = merged(None, pipeline.estimator.learned(), cfg_, "drive-1.mcap")
    r = good.r0["RL"]
    wrong = good.model_copy(update={"r0": good.r0 | {"RL": StoredRadius(radius_m=r.radius_m + 0.004, se_m=r.se_m)}})
    sink, rows, _, _, run = drive(cfg_, calibration=wrong)
    replaced = [e for e in sink.events if e.source == "calibration" and e.event == "replaced"]
    assert len(replaced) == 1 and "r0 RL" in replaced[0].detail
    assert rows[0]["r0_source_RL"] == "stored" and rows[-1]["r0_source_RL"] in ("calibrating", "calibrated")
    assert rows[-1]["r0_RL_m"] == pytest.approx(last.wheels["RL"].r0_m, abs=0.0005)
    assert "RL" in run.estimator.learned().r0


def test_a_calibration_of_another_vehicle_is_neither_used_nor_written(cold, cfg_, tmp_path) -> None:  # type: ignore[no-untyped-def]
    path = tmp_path / "calibration.toml"
    save_calibration(path, merged(None, cold[4].estimator.learned(), cfg_, "drive-1.mcap"))
    before = path.read_bytes()
    other = cfg_.with_overrides(vehicle={"name": "another car"})
    run = for_run(path, other)
    assert run.start is None and run.save_to is None and "another car" in run.note
    assert run.finish(cold[4].estimator.learned(), other, "x.mcap") == ""
    assert path.read_bytes() == before


# ---- the contract on the command line -------------------------------------------------------------------------------

@pytest.fixture(scope="module")
def logs(tmp_path_factory: pytest.TempPathFactory, cfg_: Config) -> tuple[Path, Path, Path]:
    """Two drives of the same car, host clock off UTC, as the files `slipdaq import` reads; and the config."""
    d = tmp_path_factory.mktemp("day")
    (d / "wpt.dbc").write_text((ROOT / "config" / "wpt.dbc").read_text())
    (d / "slipdaq.toml").write_text(cfg_.source_text)
    for name, seed in (("first", 7), ("second", 9)):
        settings = SimSettings(gps_latency_s=0.085, gps_noise_mps=0.03, can_jitter_s=0.0005, host_clock_offset_s=3.0,
                               seed=seed)
        events = generate(cfg_, "cycle", "paved", settings, 20.0, r0_offset_m=R0_OFFSET_M)
        write_drive_logs(events, d / f"{name}.log", d / f"{name}.nmea")
    return d / "first", d / "second", d / "slipdaq.toml"


def _import(drive_: Path, cfg: Path, out: Path, *flags: str) -> None:
    assert main(["import", "--can", f"{drive_}.log", "--nmea", f"{drive_}.nmea", "--config", str(cfg), "-o", str(out),
                 *flags]) == 0


def _estimates(path: Path) -> list[bytes]:
    return [data for _t, _ts, data in _raw_estimates(path)]


def _raw_estimates(path: Path):  # type: ignore[no-untyped-def]
    from slipdaq.logformat.reader import iter_messages

    return [(t, enc, data) for t, enc, _ns, data in iter_messages(path, (TOPIC_ESTIMATE,))]


def test_cli_calibration_persists_shows_resets_and_replays_exactly(logs, tmp_path, capsys) -> None:  # type: ignore[no-untyped-def]
    first, second, cfg = logs
    cal = tmp_path / "cal.toml"
    _import(first, cfg, tmp_path / "first.mcap", "--calibration", str(cal))
    assert cal.is_file() and "calibration saved" in capsys.readouterr().out
    assert read_metadata(tmp_path / "first.mcap")["calibration_toml"] == ""  # it started cold
    _import(second, cfg, tmp_path / "second.mcap", "--calibration", str(cal))
    meta = read_metadata(tmp_path / "second.mcap")
    assert "[latency]" in meta["calibration_toml"]  # the calibration it started from, kept in the log
    rows = list(iter_estimates(tmp_path / "second.mcap"))
    assert rows[0]["latency_source"] == "stored" and rows[0]["r0_source_FL"] == "stored"
    # replay starts from the calibration stored in the log, wherever the calibration file is now: the same estimates
    cal.unlink()
    (tmp_path / "elsewhere").mkdir()
    assert main(["replay", str(tmp_path / "second.mcap"), "-o", str(tmp_path / "elsewhere" / "re.mcap")]) == 0
    assert _estimates(tmp_path / "elsewhere" / "re.mcap") == _estimates(tmp_path / "second.mcap")
    saved = tmp_path / "elsewhere" / "calibration.toml"  # the default file: in the output's directory
    assert saved.is_file()
    capsys.readouterr()
    assert main(["calibration", "show", str(saved)]) == 0
    shown = capsys.readouterr().out
    assert "GPS latency" in shown and "r0 FL" in shown and "Cx FL" in shown
    assert main(["calibration", "reset", str(saved), "--wheel", "FL"]) == 0
    after = load_calibration(saved)
    assert after is not None and "FL" not in after.r0 and "FL" not in after.cx and "FR" in after.r0
    assert after.latency is not None
    assert main(["calibration", "reset", str(saved)]) == 0
    emptied = load_calibration(saved)
    assert emptied is not None and emptied.empty
    # a replay saves into the file that is there, and not over another vehicle's
    other = tmp_path / "other"
    other.mkdir()
    theirs = Calibration.model_validate({"vehicle": {"name": "another car"}, "r0": {"FL": {"radius_m": 0.31, "se_m": 0.0}}})
    save_calibration(other / "calibration.toml", theirs)
    before = (other / "calibration.toml").read_bytes()
    assert main(["replay", str(tmp_path / "second.mcap"), "-o", str(other / "re.mcap")]) == 0
    assert (other / "calibration.toml").read_bytes() == before and "another car" in capsys.readouterr().out
    # --no-calibration: starts cold, writes nothing
    _import(first, cfg, tmp_path / "cold" / "x.mcap", "--no-calibration")
    assert not (tmp_path / "cold" / "calibration.toml").exists()
    assert main(["calibration", "show", str(tmp_path / "cold" / "calibration.toml")]) == 2


def test_cli_bad_calibration_file_is_one_clear_error(tmp_path, logs, capsys) -> None:  # type: ignore[no-untyped-def]
    first, _, cfg = logs
    bad = tmp_path / "calibration.toml"
    bad.write_text("format = 1\n[r0.FL]\nradius_m = -3\nse_m = 0.0001\n")
    code = main(["import", "--can", f"{first}.log", "--nmea", f"{first}.nmea", "--config", str(cfg),
                 "-o", str(tmp_path / "x.mcap"), "--calibration", str(bad)])
    err = capsys.readouterr().err
    assert code == 2 and "r0.FL.radius_m" in err and str(bad) in err
    assert not (tmp_path / "x.mcap").exists()


# ---- 3. disturbed windows -------------------------------------------------------------------------------------------

def test_a_reader_stall_gives_disturbed_windows_not_wild_slip(cfg_) -> None:  # type: ignore[no-untyped-def]
    settings = SimSettings(gps_latency_s=0.085, gps_noise_mps=0.03, can_jitter_s=0.0005, seed=7, can_stall=(14.0, 2.0))
    sink, rows, truth, _, pipeline = drive(cfg_, settings)
    disturbed = [r for r in rows if r["quality"] == "disturbed"]
    t_stall = settings.start_utc_s + 14.0
    assert disturbed and all(t_stall - 0.5 < r["time_s"] < t_stall + 2.5 for r in disturbed)
    assert any(abs(r["time_s"] - (t_stall + 1.0)) < 0.3 for r in disturbed), "the windows inside the stall"
    assert all(r[f"slip_{w}"] is None for r in disturbed for w in WHEELS)
    errors = slip_errors(rows, truth)
    assert abs(errors).max() * 100 < 2.0
    # the stall does not make the wheels' latency estimate take over from UTC (or move it)
    assert pipeline.estimator.latency.source == "utc"
    status = pipeline.estimator.status()
    assert status["gps_latency_wheels_s"] == pytest.approx(0.085, abs=0.005)


def test_a_gps_gap_inside_a_window_is_disturbed(cfg_) -> None:  # type: ignore[no-untyped-def]
    settings = SimSettings(gps_latency_s=0.085, gps_noise_mps=0.03, can_jitter_s=0.0005, seed=7)
    events = list(generate(cfg_, "cycle", "paved", settings, 20.0, r0_offset_m=R0_OFFSET_M))
    t0, t1 = settings.start_utc_s + 12.0, settings.start_utc_s + 12.45  # four epochs lost
    records = [e.record for e in events if e.record is not None
               and not (type(e.record).__name__ == "NmeaLine" and t0 < e.record.timestamp_s < t1)]
    sink = CollectingSink()
    Pipeline(cfg_, [sink]).run(records)
    near = [e for e in sink.estimates if abs(e.time_s - (t0 + 0.2)) < 0.25]
    assert near and all(e.quality == "disturbed" for e in near)
    assert sum(e.quality == "disturbed" for e in sink.estimates) < 12


# ---- 4. two-pass post-processing ------------------------------------------------------------------------------------

def test_two_pass_is_as_good_at_the_first_acceleration_as_at_the_last(cold, cfg_) -> None:  # type: ignore[no-untyped-def]
    _, live_rows, truth, _, _ = cold
    events = list(generate(cfg_, "cycle", "paved", OFF_UTC, 30.0, r0_offset_m=R0_OFFSET_M))
    records = [e.record for e in events if e.record is not None]
    first = first_pass(cfg_, records, None, "drive.mcap")
    assert first.calibration.latency is not None
    assert first.calibration.latency.latency_s == pytest.approx(0.085, abs=0.003)
    sink, rows, _, _, _ = drive(cfg_, calibration=first.calibration, frozen=True, gps_speeds=first.gps_speeds)
    assert len(rows) == len(live_rows)
    assert all(r["latency_source"] == "stored" and r["quality"] == "ok" for r in rows
               if r["source"] == "gps" and r["speed_mps"] > 1.0)
    start = rows[0]["time_s"]
    early = [r for r in rows if r["time_s"] - start < 6.0]
    early_live = [r for r in live_rows if r["time_s"] - start < 6.0]
    assert sum(r["slip_FL"] is not None for r in early) > sum(r["slip_FL"] is not None for r in early_live) + 5
    assert slip_error(early, truth, min_speed_mps=1.0).rms_points < 0.3  # slip where the live run had none
    assert slip_error(rows, truth).rms_points < slip_error(live_rows, truth).rms_points
    raw_speeds = [r.speed_mps for r in sink.fixes]
    assert len(first.gps_speeds) == len(raw_speeds) and first.gps_speeds != raw_speeds  # one smoothed speed per fix
    assert not sink.events


def test_cli_two_pass_replay_and_report_default(logs, tmp_path, capsys) -> None:  # type: ignore[no-untyped-def]
    first, _, cfg = logs
    raw = tmp_path / "raw.mcap"
    _import(first, cfg, raw, "--no-calibration")
    assert main(["replay", str(raw), "-o", str(tmp_path / "plain.mcap"), "--no-calibration"]) == 0
    assert _estimates(tmp_path / "plain.mcap") == _estimates(raw)  # without --two-pass: bit for bit the import's
    assert main(["replay", str(raw), "-o", str(tmp_path / "two.mcap"), "--no-calibration", "--two-pass"]) == 0
    meta = read_metadata(tmp_path / "two.mcap")
    assert meta["two_pass"] == "true" and "[latency]" in meta["calibration_toml"]
    rows = list(iter_estimates(tmp_path / "two.mcap"))
    assert {r["latency_source"] for r in rows} == {"stored"}
    assert sum(r["slip_FL"] is not None for r in rows) > sum(r["slip_FL"] is not None for r in iter_estimates(raw))
    capsys.readouterr()
    assert main(["report", str(raw), "-o", str(tmp_path / "rep")]) == 0
    assert "(two-pass)" in capsys.readouterr().out
    assert main(["report", str(raw), "-o", str(tmp_path / "rep-live"), "--live"]) == 0
    assert "(logged)" in capsys.readouterr().out
    with open(tmp_path / "rep" / "summary.csv") as f, open(tmp_path / "rep-live" / "summary.csv") as g:
        assert list(csv.reader(f)) != list(csv.reader(g))
