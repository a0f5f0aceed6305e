"""A replay's log written in a process of its own (offline.log_process): the same bytes as the log written in the run's
process, for frames one by one, a log's batches, a second pass and a real capture; an input read again that differs
and an error where the log is written each end the run with their error and leave no process behind (a run that
stops: test_summary_process.py)."""

from __future__ import annotations

import dataclasses
import io
from pathlib import Path
from typing import Any

import pytest

from slipdaq.cli import main
from slipdaq.config import Config, load_config
from slipdaq.logformat.reader import config_from_log, iter_raw_batches, raw_record_count
from slipdaq.offline.log_process import LogProcessError
from slipdaq.offline.run import first_pass, process_to_log
from slipdaq.offline.summaries import MIN_RAW_RECORDS
from slipdaq.records import CanFrame, NmeaLine
from slipdaq.sim.emit import SimSettings, generate
from support.forks import FORKS, children
from support.paths import CONFIG, DATA, ROOT
from support.sim_logs import FIXED_META

RAV4 = DATA / "rav4-comma2k19"


@pytest.fixture(scope="module")
def drive() -> tuple[Config, list[Any]]:
    """30 s of the cycle, as single CAN frames and NMEA lines: about 120,000 frames and a few maneuvers."""
    cfg = load_config(CONFIG)
    records = [e.record for e in generate(cfg, "cycle", "paved", SimSettings(seed=5), duration_s=30.0)
               if e.record is not None]
    assert len(records) >= MIN_RAW_RECORDS
    return cfg, records


def _both_ways(cfg: Config, records: Any, tmp_path: Path, name: str, **options: Any) -> bytes:
    """The log written here and in a process of its own; the bytes, checked equal."""
    here = tmp_path / f"{name}-here.mcap"
    apart = tmp_path / f"{name}-apart.mcap"
    p_here = process_to_log(cfg, records(), here, "replay", metadata=FIXED_META, stream=io.StringIO(), **options)
    before = len(FORKS)
    p_apart = process_to_log(cfg, records(), apart, "replay", metadata=FIXED_META, stream=io.StringIO(),
                             reread=records, **options)
    assert len(FORKS) - before == 2  # the log's process and the summaries'
    assert p_apart.estimates == p_here.estimates > 0
    assert apart.read_bytes() == here.read_bytes()
    assert children() == []
    return here.read_bytes()


def test_frames_one_by_one_the_same_bytes(drive: tuple[Config, list[Any]], tmp_path: Path) -> None:
    cfg, records = drive
    _both_ways(cfg, lambda: iter(records), tmp_path, "frames", total=len(records))


def test_a_logs_replay_and_its_second_pass_the_same_bytes(drive: tuple[Config, list[Any]], tmp_path: Path) -> None:
    """A log's CAN batches (as iter_raw_batches reads them), the first replay and a second pass (its calibration
    held, the smoothed speeds)."""
    cfg, records = drive
    log = tmp_path / "recorded.mcap"
    process_to_log(cfg, iter(records), log, "import", metadata=FIXED_META, stream=io.StringIO(), total=len(records))
    again = lambda: iter_raw_batches(log)  # noqa: E731
    _both_ways(cfg, again, tmp_path, "replay", total=len(records))
    first = first_pass(cfg, again(), None, str(log), total=len(records), stream=io.StringIO())
    _both_ways(cfg, again, tmp_path, "second", total=len(records), **first.second_pass())


def test_a_real_captures_replay_the_same_bytes(tmp_path: Path) -> None:
    """The RAV4's ABS wheel speeds (four wheels to a frame; the run's first segment a frame with no wheel sample)."""
    log = tmp_path / "rav4.mcap"
    assert main(["import", "--can", str(RAV4 / "rav4_bus0.candump.log"), "--nmea", str(RAV4 / "rav4_ublox.nmea"),
                 "--config", str(ROOT / "config" / "examples" / "rav4-comma2k19.toml"), "-o", str(log),
                 "--no-calibration"]) == 0
    _both_ways(config_from_log(log), lambda: iter_raw_batches(log), tmp_path, "rav4", total=raw_record_count(log))


def _line_missing(records: list[Any]) -> list[Any]:
    k = next(i for i, r in enumerate(records) if isinstance(r, NmeaLine) and i > len(records) // 3)
    return records[:k] + records[k + 1:]


def _frame_moved(records: list[Any]) -> list[Any]:
    k = next(i for i, r in enumerate(records) if isinstance(r, CanFrame) and i > len(records) // 3
             and isinstance(records[i - 1], NmeaLine))  # the first frame of a run: its time is checked
    return records[:k] + [dataclasses.replace(records[k], timestamp_s=records[k].timestamp_s + 1e-6)] + records[k + 1:]


def _cut_after_a_line(records: list[Any]) -> list[Any]:
    return records[: next(i for i, r in enumerate(records) if isinstance(r, NmeaLine) and i > 2 * len(records) // 3)]


@pytest.mark.parametrize(("change", "error"), [
    (_line_missing, "another record than the run's"),
    (_frame_moved, "other CAN frames than the run's"),
    (_cut_after_a_line, "read to the input's end before the run did"),
])
def test_an_input_read_again_that_differs_fails_the_run(drive: tuple[Config, list[Any]], tmp_path: Path,
                                                        change: Any, error: str) -> None:
    """The log's process checks each run of frames' first time and each raw record's time: a line missing, a frame
    moved by a microsecond and the input cut short are each an error."""
    cfg, records = drive
    other = change(records)
    with pytest.raises(LogProcessError, match=error) as raised:
        process_to_log(cfg, iter(records), tmp_path / "out.mcap", "replay", stream=io.StringIO(),
                       total=len(records), reread=lambda: iter(other))
    assert "in the log's process" in "".join(raised.value.__notes__)
    assert children() == []


def test_an_error_where_the_log_is_written_is_the_runs(drive: tuple[Config, list[Any]], tmp_path: Path) -> None:
    """The log cannot be made (its path is a directory): the same error as when it is written in the run's process."""
    cfg, records = drive
    out = tmp_path / "a-directory.mcap"
    out.mkdir()
    with pytest.raises(IsADirectoryError):
        process_to_log(cfg, iter(records), out, "replay", stream=io.StringIO(), total=len(records))
    with pytest.raises(IsADirectoryError) as raised:
        process_to_log(cfg, iter(records), out, "replay", stream=io.StringIO(), total=len(records),
                       reread=lambda: iter(records))
    assert "in the log's process" in "".join(raised.value.__notes__)
    assert children() == []
