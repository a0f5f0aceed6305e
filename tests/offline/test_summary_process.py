"""The maneuvers' summaries in a second process (offline.summaries, Pipeline's hold_output): the log is the same bytes
as with the summaries computed at once, whatever each took; the process ends with the run, on an error and on
KeyboardInterrupt; a live run forks none."""

from __future__ import annotations

import io
import json
import multiprocessing
import os
import re
import time
from collections.abc import Iterator
from concurrent.futures import Executor, Future
from pathlib import Path
from typing import Any

import pytest

from slipdaq.config import Config, load_config
from slipdaq.maneuver import detector
from slipdaq.offline.run import process, process_to_log
from slipdaq.offline.summaries import MIN_RAW_RECORDS, SummaryProcess, SummaryProcessError, worth_a_process
from slipdaq.sim.emit import SimSettings, generate
from slipdaq.sinks import Sink
from slipdaq.sinks.mcap_log import McapLogSink
from support.forks import FORKS, children
from support.paths import CONFIG
from support.sim_logs import FIXED_META


@pytest.fixture(scope="module")
def drive() -> tuple[Config, list[Any]]:
    """40 s of the cycle: five maneuvers, the last decided by the log's end (Pipeline.finish)."""
    cfg = load_config(CONFIG)
    return cfg, [e.record for e in generate(cfg, "cycle", "paved", SimSettings(seed=3), duration_s=40.0)
                 if e.record is not None]


class _Maneuvers(Sink):
    def __init__(self) -> None:
        self.times: list[float] = []
        self.last_s = 0.0

    def on_maneuver(self, maneuver: Any, log_time_s: float) -> None:
        self.times.append(log_time_s)

    def on_diagnostics(self, diagnostics: dict[str, object], log_time_s: float) -> None:
        self.last_s = log_time_s


def _log(cfg: Config, records: list[Any], path: Path, summaries: Executor | None) -> _Maneuvers:
    seen = _Maneuvers()
    sink = McapLogSink(path, cfg, mode="replay", metadata=FIXED_META)
    try:
        process(cfg, records, [sink, seen], stream=io.StringIO(), summaries=summaries)
    finally:
        sink.close()
    return seen


def _same_log_both_ways(cfg: Config, records: list[Any], tmp_path: Path) -> _Maneuvers:
    at_once = _log(cfg, records, tmp_path / "at-once.mcap", None)
    with SummaryProcess() as summaries:
        beside = _log(cfg, records, tmp_path / "beside.mcap", summaries)
    assert summaries.process.exitcode == 0
    assert beside.times == at_once.times
    assert (tmp_path / "beside.mcap").read_bytes() == (tmp_path / "at-once.mcap").read_bytes()
    return at_once


def test_the_log_is_the_same_bytes_with_the_summaries_in_a_second_process(
        drive: tuple[Config, list[Any]], tmp_path: Path) -> None:
    cfg, records = drive
    seen = _same_log_both_ways(cfg, records, tmp_path)
    assert len(seen.times) == 5
    assert seen.times[-1] == seen.last_s  # decided at the log's end
    assert len(set(seen.times)) == 5


@pytest.mark.slow
def test_coasts_in_order_with_the_summaries_in_a_second_process(tmp_path: Path) -> None:
    """The coast-down drive: its coast records (made at once) wait behind any summary still out."""
    from slipdaq.config import packaged_config_path
    from slipdaq.sim.road_loads import RoadLoadTruth

    cfg = load_config(packaged_config_path()).with_overrides(vehicle={"rotating_mass_factor": 1.04})
    events = generate(cfg, "coast-down", "paved", SimSettings(seed=2, gps_latency_s=0.08, gps_noise_mps=0.03,
                                                               wpt_rate_hz=50.0), 141.0,
                      road_loads=RoadLoadTruth(f0_n=400.0, f2_n_per_mps2=1.0, rotating_mass_factor=1.04,
                                                              wind_mps=3.0))
    seen = _same_log_both_ways(cfg, [e.record for e in events if e.record is not None], tmp_path)
    assert len(seen.times) >= 2


class _Asked(Future[Any]):
    """Done only once its result is asked for: the job runs then."""

    def __init__(self, fn: Any, args: tuple[Any, ...]) -> None:
        super().__init__()
        self._job = fn, args

    def result(self, timeout: float | None = None) -> Any:
        if not self.done():
            try:
                self.set_result(self._job[0](*self._job[1]))
            except Exception as e:
                self.set_exception(e)
        return super().result(timeout)


class _Latest(Executor):
    """Every summary as late as it can come: never done until waited for (past HOLD_MAX_CALLS held calls, or at the
    log's end)."""

    def submit(self, fn: Any, /, *args: Any, **kwargs: Any) -> Future[Any]:
        return _Asked(fn, args)


@pytest.mark.parametrize("most_held", [None, 64])
def test_the_same_bytes_when_every_summary_comes_as_late_as_it_can(
        drive: tuple[Config, list[Any]], tmp_path: Path, monkeypatch: pytest.MonkeyPatch, most_held: int | None) -> None:
    """Held to the log's end (the drive's at most 2,375 calls), or waited for past 64 held calls."""
    from slipdaq import pipeline

    if most_held is not None:
        monkeypatch.setattr(pipeline, "HOLD_MAX_CALLS", most_held)
    cfg, records = drive
    at_once = _log(cfg, records, tmp_path / "at-once.mcap", None)
    latest = _log(cfg, records, tmp_path / "latest.mcap", _Latest())
    assert latest.times == at_once.times
    assert (tmp_path / "latest.mcap").read_bytes() == (tmp_path / "at-once.mcap").read_bytes()


def _raising_summary(*args: Any, **kwargs: Any) -> Any:
    raise ValueError("a summary that fails")


def test_a_summary_that_raises_fails_the_run_as_at_once(drive: tuple[Config, list[Any]], tmp_path: Path,
                                                          monkeypatch: pytest.MonkeyPatch) -> None:
    """The error a summary raises (here every summary's) ends the run as it does at once, and the process with it."""
    cfg, records = drive
    monkeypatch.setattr(detector, "summarize_maneuver", _raising_summary)
    with pytest.raises(ValueError, match="a summary that fails"):
        _log(cfg, records, tmp_path / "at-once.mcap", None)
    with pytest.raises(ValueError, match="a summary that fails") as raised:
        with SummaryProcess() as summaries:
            _log(cfg, records, tmp_path / "beside.mcap", summaries)
    assert "in the summary process" in "".join(raised.value.__notes__)
    assert not summaries.process.is_alive()


def _interrupted(records: list[Any], after: int, error: BaseException) -> Iterator[Any]:
    yield from records[:after]
    raise error


@pytest.mark.parametrize("error", [KeyboardInterrupt(), OSError("the log's disk is gone")])
@pytest.mark.parametrize("log_apart", [False, True])
def test_the_process_ends_when_the_run_stops(drive: tuple[Config, list[Any]], tmp_path: Path,
                                            error: BaseException, log_apart: bool) -> None:
    """A replay (a known total of records: the process is forked) stopped half way by ^C or an error: the summary
    process, and the log's where it is written apart (offline.log_process), are terminated and reaped before the
    error leaves process_to_log (no orphan)."""
    cfg, records = drive
    before = len(FORKS)
    with pytest.raises(type(error)):
        process_to_log(cfg, _interrupted(records, len(records) // 2, error), tmp_path / "out.mcap", "replay",
                       total=MIN_RAW_RECORDS, stream=io.StringIO(), decode=(lambda p: p) if log_apart else None)
    assert FORKS[before:] == [os.getpid()] * (2 if log_apart else 1)  # forked by this process
    assert not [p for p in multiprocessing.active_children() if p.name in ("slipdaq-summaries", "slipdaq-log")]
    assert children() == []


def test_jobs_come_back_in_order_and_a_dead_process_fails_what_is_out() -> None:
    with SummaryProcess() as summaries:
        got = [summaries.submit(pow, k, 2) for k in range(50)]
        assert [f.result() for f in got] == [k * k for k in range(50)]
    assert summaries.process.exitcode == 0
    summaries = SummaryProcess()
    try:
        out = summaries.submit(time.sleep, 60.0)
        summaries.process.kill()
        with pytest.raises(SummaryProcessError):
            out.result(timeout=30)
        summaries.process.join()
        with pytest.raises(SummaryProcessError):
            summaries.submit(pow, 2, 2).result(timeout=30)
    finally:
        summaries.terminate()


def test_short_logs_and_runs_without_a_total_summarize_at_once(drive: tuple[Config, list[Any]],
                                                              tmp_path: Path) -> None:
    cfg, records = drive
    assert not worth_a_process(None)
    assert not worth_a_process(MIN_RAW_RECORDS - 1)
    before = len(FORKS)
    process_to_log(cfg, records, tmp_path / "import.mcap", "import", stream=io.StringIO())
    process_to_log(cfg, records, tmp_path / "short.mcap", "replay", total=MIN_RAW_RECORDS - 1, stream=io.StringIO())
    assert FORKS[before:] == []


def test_a_live_run_forks_no_summary_process(tmp_path: Path) -> None:
    """The live daemon summarizes on its thread (its records later in the log): no second process."""
    from slipdaq.live.demo import run_demo

    before = len(FORKS)
    assert run_demo(3.0, "cycle", "paved", tmp_path, out=io.StringIO(), no_calibration=True) == 0
    assert FORKS[before:] == []


def _tree(root: Path) -> dict[str, bytes]:
    """Every file of a report by its path; summary.json and index.html without their time of generation."""
    files = {p.relative_to(root).as_posix(): p.read_bytes() for p in sorted(root.rglob("*")) if p.is_file()}
    js = json.loads(files["summary.json"])
    js.pop("generated_utc")
    files["summary.json"] = json.dumps(js).encode()
    files["index.html"] = re.sub(rb", \d{4}-\d\d-\d\dT\d\d:\d\d:\d\d\+00:00\. Tables", b". Tables", files["index.html"])
    return files


def test_the_report_is_the_same_with_its_summaries_beside_the_second_pass(
        drive: tuple[Config, list[Any]], tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """`slipdaq report` of a log's raw records two-pass: its maneuvers decided as the second pass makes the rows and
    summarized in the second process (DetectorFeed, what `slipdaq report` does), its passes fed by a process that
    reads the log (FedPasses), give the same report, file for file, as decided afterwards."""
    from slipdaq.offline import summaries
    from slipdaq.report.build import make_report, read_log

    cfg, records = drive
    log = tmp_path / "drive.mcap"
    process_to_log(cfg, records, log, "import", stream=io.StringIO())
    monkeypatch.setattr(summaries, "MIN_RAW_RECORDS", 10**9)  # every log short: no second process
    before = len(FORKS)
    after = make_report([log], tmp_path / "after", two_pass=True, summaries_beside=True)
    assert read_log(log, two_pass=True, maneuvers=True).maneuvers is None
    assert FORKS[before:] == []
    monkeypatch.setattr(summaries, "MIN_RAW_RECORDS", 1)
    beside = make_report([log], tmp_path / "beside", two_pass=True, summaries_beside=True)
    assert FORKS[before:] == [os.getpid()] * 2  # the feed's process (first_pass_feed.FedPasses) and the summaries'
    assert [len(x.logs[0].maneuvers) for x in (after, beside)] == [len(after.logs[0].maneuvers)] * 2
    assert len(after.logs[0].maneuvers) >= 8  # accelerate, cruise and brake
    assert _tree(tmp_path / "beside") == _tree(tmp_path / "after")
    before = len(FORKS)
    make_report([log], tmp_path / "default", two_pass=True)  # `slipdaq report`: summaries beside the pass
    assert FORKS[before:] == [os.getpid()] * 2
    assert _tree(tmp_path / "default") == _tree(tmp_path / "after")
