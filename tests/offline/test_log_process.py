"""A replay's log written in a process of its own (offline.log_process): the same bytes as the log written in the run's
process, for frames one by one, a log's raw messages, a second pass, a real capture, an old log's frames one message
each, and a two-pass replay whose log's process reads the log itself; records decoded otherwise in the process and an
error where the log is written each end the run with their error and leave no process behind (a run that stops:
test_summary_process.py)."""

from __future__ import annotations

import dataclasses
import io
import os
from pathlib import Path
from typing import Any

import pytest

from slipdaq.cli import main
from slipdaq.config import Config, load_config
from slipdaq.logformat.json_codec import can_frame_to_dict, dumps
from slipdaq.logformat.reader import config_from_log, iter_raw_batches, iter_raw_messages, raw_batches, raw_record_count
from slipdaq.logformat.salvage import ScanResult
from slipdaq.logformat.topics import TOPIC_CAN, TOPIC_NMEA
from slipdaq.offline import first_pass_feed, log_process, run
from slipdaq.offline.log_process import LogProcessError
from slipdaq.offline.run import first_pass, process_to_log, replay_two_pass
from slipdaq.offline.summaries import MIN_RAW_RECORDS
from slipdaq.records import CanFrame, NmeaLine
from slipdaq.sim.emit import SimSettings, generate
from support.forks import FORKS, children, failing_in_a_child, made_here
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


def _both_ways(cfg: Config, pieces: Any, decode: Any, tmp_path: Path, name: str, **options: Any) -> bytes:
    """The log written here and in a process of its own (sent the pieces: decode(pieces()) the records); the bytes,
    checked equal."""
    here = tmp_path / f"{name}-here.mcap"
    apart = tmp_path / f"{name}-apart.mcap"
    p_here = process_to_log(cfg, decode(pieces()), here, "replay", metadata=FIXED_META, stream=io.StringIO(),
                            **options)
    before = len(FORKS)
    p_apart = process_to_log(cfg, pieces(), apart, "replay", metadata=FIXED_META, stream=io.StringIO(),
                             decode=decode, **options)
    assert len(FORKS) - before == 2  # the log's process and the summaries'
    assert p_apart.estimates == p_here.estimates > 0
    assert apart.read_bytes() == here.read_bytes()
    assert children() == []
    return here.read_bytes()


def _records(pieces: Any) -> Any:
    return pieces


def test_frames_one_by_one_the_same_bytes(drive: tuple[Config, list[Any]], tmp_path: Path) -> None:
    """Records sent as they are (pickled): single frames, batched as the run batches them."""
    cfg, records = drive
    _both_ways(cfg, lambda: iter(records), _records, tmp_path, "frames", total=len(records))


def test_a_logs_replay_and_its_second_pass_the_same_bytes(drive: tuple[Config, list[Any]], tmp_path: Path) -> None:
    """A log's raw messages (as a replay reads them), the first replay and a second pass (its calibration held, the
    smoothed speeds)."""
    cfg, records = drive
    log = tmp_path / "recorded.mcap"
    process_to_log(cfg, iter(records), log, "import", metadata=FIXED_META, stream=io.StringIO(), total=len(records))
    messages = lambda: iter_raw_messages(log)  # noqa: E731
    _both_ways(cfg, messages, raw_batches, tmp_path, "replay", total=len(records))
    first = first_pass(cfg, iter_raw_batches(log), None, str(log), total=len(records), stream=io.StringIO())
    _both_ways(cfg, messages, raw_batches, tmp_path, "second", total=len(records), **first.second_pass())


def test_a_real_captures_replay_the_same_bytes(tmp_path: Path) -> None:
    """The RAV4's ABS wheel speeds (four wheels to a frame; the run's first segment a frame with no wheel sample)."""
    log = tmp_path / "rav4.mcap"
    assert main(["import", "--can", str(RAV4 / "rav4_bus0.candump.log"), "--nmea", str(RAV4 / "rav4_ublox.nmea"),
                 "--config", str(ROOT / "config" / "examples" / "rav4-comma2k19.toml"), "-o", str(log),
                 "--no-calibration"]) == 0
    _both_ways(config_from_log(log), lambda: iter_raw_messages(log), raw_batches, tmp_path, "rav4",
               total=raw_record_count(log))


def test_an_old_logs_frames_one_message_each_the_same_bytes(drive: tuple[Config, list[Any]], tmp_path: Path) -> None:
    """A log from before the batches (a JSON message per CAN frame): the process joins its frames into the same
    batches as the run (the message that ends a batch, read to end it, is sent with it; the record it makes, with
    nothing)."""
    cfg, records = drive
    messages = [((None,), TOPIC_CAN, "json", dumps(can_frame_to_dict(r))) if isinstance(r, CanFrame)
                else ((None,), TOPIC_NMEA, "json", dumps({"timestamp_s": r.timestamp_s, "line": r.line}))
                for r in records]
    _both_ways(cfg, lambda: iter(messages), raw_batches, tmp_path, "old", total=len(records))


def _two_pass_both_ways(log: Path, tmp_path: Path, total: int, monkeypatch: pytest.MonkeyPatch,
                        fed: bool = True) -> None:
    """replay_two_pass, its log's process forked before the first pass and reading the log itself: the bytes of the
    second pass written here. fed: the run's process decodes no wheel frame and reads no message of the log (the log's
    process feeds it: first_pass_feed); else (a log too long to feed whole) the first pass is fed by a process of its
    own and the second pass reads and decodes the log here."""
    cfg = config_from_log(log)
    here, apart = tmp_path / f"{log.stem}-two-pass-here.mcap", tmp_path / f"{log.stem}-two-pass-apart.mcap"
    first = first_pass(cfg, iter_raw_batches(log), None, str(log), total=total, stream=io.StringIO())
    before = len(FORKS)
    with made_here(monkeypatch) as here_calls:
        scanned = ScanResult(log)
        p_apart, first_apart = replay_two_pass(cfg, log, apart, None, metadata=FIXED_META, total=total,
                                               scanned=scanned)
    assert (here_calls["decode_batch"] == 0) is fed
    assert here_calls["messages"] == (0 if fed else 1)  # the second pass's read
    assert scanned.has_summary and scanned.messages > 0  # the scan made where the log is read
    assert len(FORKS) - before == (2 if fed else 3)  # the log's process and the summaries' (and the first pass's feed)
    assert first_apart.gps_speeds == first.gps_speeds
    p_here = process_to_log(cfg, iter_raw_batches(log), here, "replay", metadata=FIXED_META, stream=io.StringIO(),
                            total=total, **first_apart.second_pass())  # its calibration's time learned the same
    assert p_apart.estimates == p_here.estimates > 0
    assert apart.read_bytes() == here.read_bytes()
    assert children() == []


def test_a_two_pass_replay_whose_process_reads_the_log_itself_the_same_bytes(
        drive: tuple[Config, list[Any]], tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """The simulated drive, read ahead whole and fed to the first pass, and then a piece ahead only (a log too long
    to feed: the rest decoded as the run's calls ask for it), and the RAV4's capture (its first segment a frame with
    no wheel sample)."""
    cfg, records = drive
    log = tmp_path / "recorded.mcap"
    process_to_log(cfg, iter(records), log, "import", metadata=FIXED_META, stream=io.StringIO(), total=len(records))
    _two_pass_both_ways(log, tmp_path, len(records), monkeypatch)
    monkeypatch.setattr(log_process, "AHEAD_FRAMES", 1)
    monkeypatch.setattr(first_pass_feed, "FEED_BYTES", 0)  # a log too long to feed
    _two_pass_both_ways(log, tmp_path, len(records), monkeypatch, fed=False)
    monkeypatch.undo()
    rav4 = tmp_path / "rav4.mcap"
    assert main(["import", "--can", str(RAV4 / "rav4_bus0.candump.log"), "--nmea", str(RAV4 / "rav4_ublox.nmea"),
                 "--config", str(ROOT / "config" / "examples" / "rav4-comma2k19.toml"), "-o", str(rav4),
                 "--no-calibration"]) == 0
    _two_pass_both_ways(rav4, tmp_path, raw_record_count(rav4), monkeypatch)


PARENT = os.getpid()


def _in_the_process_only(change: Any) -> Any:
    """A decode that changes the records in the log's process only (the run's records as they are)."""
    def decode(pieces: Any) -> Any:
        return change(pieces) if os.getpid() != PARENT else pieces
    return decode


def _line_moved(records: Any) -> Any:
    lines = 0
    for r in records:
        if isinstance(r, NmeaLine):
            lines += 1
            if lines == 100:
                r = dataclasses.replace(r, timestamp_s=r.timestamp_s + 1e-6)
        yield r


def _frame_moved(records: Any) -> Any:
    frames, before = 0, None
    for r in records:
        if isinstance(r, CanFrame) and isinstance(before, NmeaLine):
            frames += 1
            if frames == 100:  # the first frame of a run: its time is checked
                r = dataclasses.replace(r, timestamp_s=r.timestamp_s + 1e-6)
        before = r
        yield r


def _cut_after_a_line(records: Any) -> Any:
    lines = 0
    for r in records:
        yield r
        lines += isinstance(r, NmeaLine)
        if lines == 100:
            return


@pytest.mark.parametrize(("change", "error"), [
    (_line_moved, "another record than the run's"),
    (_frame_moved, "other CAN frames than the run's"),
    (_cut_after_a_line, "decoded fewer items of the input than the run read"),
])
def test_records_decoded_otherwise_in_the_process_fail_the_run(drive: tuple[Config, list[Any]], tmp_path: Path,
                                                               change: Any, error: str) -> None:
    """The log's process checks each run of frames' first time and each raw record's time against the run's calls:
    a line or a frame moved by a microsecond and the input ending early there are each an error."""
    cfg, records = drive
    with pytest.raises(LogProcessError, match=error) as raised:
        process_to_log(cfg, iter(records), tmp_path / "out.mcap", "replay", stream=io.StringIO(),
                       total=len(records), decode=_in_the_process_only(change))
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
                       decode=_records)
    assert "in the log's process" in "".join(raised.value.__notes__)
    assert children() == []


def test_a_feed_brings_the_scan_a_torn_log_is_not_fed_and_a_failing_feed_is_the_runs_error(
        drive: tuple[Config, list[Any]], tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """A log fed to the first pass: the scan the run gets is the one made where the log is read, the same as reading it
    here. A log cut short (killed while writing: its size unknown without its summary) is not fed: the run reads it,
    and its scan says where it stopped. The log's process failing while it feeds the first pass: the run ends with its
    error, and leaves no process behind."""
    cfg, records = drive
    log = tmp_path / "recorded.mcap"
    process_to_log(cfg, iter(records), log, "import", metadata=FIXED_META, stream=io.StringIO(), total=len(records))
    torn = tmp_path / "torn.mcap"
    torn.write_bytes(log.read_bytes()[: int(log.stat().st_size * 0.8)])
    assert first_pass_feed.fed_whole(log) and not first_pass_feed.fed_whole(torn)
    for path, feed_bytes in ((log, first_pass_feed.FEED_BYTES), (log, 0), (torn, first_pass_feed.FEED_BYTES)):
        monkeypatch.setattr(first_pass_feed, "FEED_BYTES", feed_bytes)  # 0: too long to feed whole, its own feed
        here = ScanResult(path)
        assert sum(1 for _ in iter_raw_messages(path, here)) > 100
        assert here.has_summary is (path == log) and bool(here.stopped_because) is (path == torn)
        scanned = ScanResult(path)
        replay_two_pass(cfg, path, tmp_path / f"out-{path.stem}.mcap", None, metadata=FIXED_META, total=len(records),
                        scanned=scanned)
        assert scanned == here
    monkeypatch.undo()

    monkeypatch.setattr(run, "log_decoder", lambda _: failing_in_a_child(raw_batches, 500))
    with pytest.raises(ValueError, match="cannot be decoded") as raised:
        replay_two_pass(cfg, log, tmp_path / "failed.mcap", None, metadata=FIXED_META, total=len(records))
    assert "in the log's process" in "".join(raised.value.__notes__)
    assert children() == []
    monkeypatch.setattr(first_pass_feed, "FEED_BYTES", 0)  # the first pass's own feed failing
    with pytest.raises(ValueError, match="cannot be decoded") as raised:
        replay_two_pass(cfg, log, tmp_path / "failed.mcap", None, metadata=FIXED_META, total=len(records))
    assert "in the feed's process" in "".join(raised.value.__notes__)
    assert children() == []
