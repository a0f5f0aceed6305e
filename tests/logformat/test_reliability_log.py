"""Reliability of the MCAP log: a chunk closed at least every second even when records stop; SIGINT and
SIGTERM finish the file; after SIGKILL (or a torn tail after a power loss) the file is read up to its last complete
chunk by the standard MCAP reader, `slipdaq replay`/`export`, and `slipdaq recover`; disk full gives a clear message
while estimating goes on; rotation by size or duration loses no message at a boundary."""

from __future__ import annotations

import asyncio
import csv
import json
import os
import shutil
import signal
import time
from pathlib import Path

import pytest
from mcap.reader import make_reader

from slipdaq.cli import main
from slipdaq.config import load_config
from slipdaq.logformat.cdr import decode_can_batch
from slipdaq.logformat.durable import TRAILER
from slipdaq.logformat.reader import is_finished, iter_estimates, iter_raw_records, iter_topic, read_metadata
from slipdaq.logformat.rotation import RotationPolicy, run_segments
from slipdaq.logformat.salvage import ScanResult, scan
from slipdaq.logformat.topics import TOPIC_EVENTS
from slipdaq.offline.recover import recover
from slipdaq.pipeline import Pipeline
from slipdaq.records import CanFrame, NmeaLine
from slipdaq.sinks import CollectingSink
from slipdaq.sinks.mcap_log import McapLogSink
from slipdaq.sinks.status import SourceStatus, StatusSink, status_line
from support.paths import CONFIG
from support.reliability_support import DaemonProcess, fill, gps_lines, sim_records, small_tmpfs


class FakeMonotonic:
    def __init__(self) -> None:
        self.t = 1000.0

    def __call__(self) -> float:
        return self.t


def _write_live_log(path: Path, records, commit_every_s: float = 1.0, **sink_kw):  # type: ignore[no-untyped-def]
    """Records through a pipeline into a live-mode sink whose monotonic clock follows record time (commits every
    commit_every_s of records); returns (sink, estimates as dicts)."""
    cfg = load_config(CONFIG)
    mono = FakeMonotonic()
    sink_kw = {"can_channels": [None]} | sink_kw  # as a live run: its bus's channel known from the start
    sink = McapLogSink(path, cfg, mode="live", flush_every_s=commit_every_s, monotonic=mono, fsync=False, **sink_kw)
    collect = CollectingSink()
    p = Pipeline(cfg, [sink, collect])
    t0 = records[0].timestamp_s
    for r in records:
        mono.t = 1000.0 + r.timestamp_s - t0
        p.process(r)
    p.finish()
    return sink, [e.as_row() for e in collect.estimates], mono


def _same_json(rows):  # type: ignore[no-untyped-def]
    return [json.loads(json.dumps(r)) for r in rows]


# ---- a chunk every second, whatever the records do ----

def test_chunk_closed_every_second_even_when_records_stop(tmp_path: Path) -> None:
    """Records for 1.6 s, then none: what was written is on disk, readable, within 1 s (a timer on the loop), and
    every chunk of the finished file spans at most 1 s."""
    cfg = load_config(CONFIG)
    path = tmp_path / "live.mcap"

    async def run() -> tuple[int, int]:
        sink = McapLogSink(path, cfg, mode="live", flush_every_s=1.0)
        n = 0
        t_end = time.monotonic() + 1.6
        while time.monotonic() < t_end:
            for _ in range(4):
                sink.on_raw(CanFrame(time.time(), 0x123, bytes(8)))
                n += 1
            await asyncio.sleep(0.01)
        await asyncio.sleep(1.15)  # no record at all now
        copy = tmp_path / "copy.mcap"
        shutil.copy(path, copy)  # what a SIGKILL now would leave
        with open(copy, "rb") as f:  # the standard reader; /can/raw holds batches of frames
            seen = sum(len(decode_can_batch(m.data)[1]) for _, _, m in make_reader(f).iter_messages(
                log_time_order=False))
        sink.close()
        return n, seen

    n, seen = asyncio.run(run())
    assert seen == n
    with open(path, "rb") as f:
        summary = make_reader(f).get_summary()
    assert summary is not None and len(summary.chunk_indexes) >= 2
    for ci in summary.chunk_indexes:
        assert (ci.message_end_time - ci.message_start_time) / 1e9 <= 1.05


def test_file_is_complete_mcap_after_every_commit(tmp_path: Path) -> None:
    """The live file ends with a provisional footer after each commit: the standard reader reads it (no summary)."""
    records = sim_records(4.0)
    path = tmp_path / "live.mcap"
    cfg = load_config(CONFIG)
    mono = FakeMonotonic()
    sink = McapLogSink(path, cfg, mode="live", flush_every_s=1.0, monotonic=mono, fsync=False)
    p = Pipeline(cfg, [sink])
    t0 = records[0].timestamp_s
    checked = 0
    for r in records:
        mono.t = 1000.0 + r.timestamp_s - t0
        commits = sink.log.commits
        p.process(r)
        if sink.log.commits != commits:
            data = path.read_bytes()
            assert data.endswith(TRAILER)
            with open(path, "rb") as f:
                reader = make_reader(f)
                assert reader.get_summary() is None
                n = sum(1 for _ in reader.iter_messages(log_time_order=False))
            assert n == sink.log.messages - sink.log.unflushed
            checked += 1
    sink.close()
    assert checked >= 3 and is_finished(path)


# ---- signals ----

def test_sigterm_finishes_the_log_and_the_daemon_opens_no_network_port(tmp_path: Path) -> None:
    """`slipdaq run` as a process: no TCP/UDP/raw socket of its own (checked in /proc), SIGTERM -> exit 0, a finished
    log (summary) with every line written."""
    d = DaemonProcess(tmp_path)
    try:
        d.start()
        assert d.proc is not None
        inodes = set()
        for fd in os.listdir(f"/proc/{d.proc.pid}/fd"):
            try:
                target = os.readlink(f"/proc/{d.proc.pid}/fd/{fd}")
            except OSError:  # closed while we looked
                continue
            if target.startswith("socket:["):
                inodes.add(target[8:-1])
        for table in ("tcp", "tcp6", "udp", "udp6", "raw", "raw6", "udplite", "udplite6"):
            p = Path(f"/proc/{d.proc.pid}/net/{table}")
            if p.exists():
                for line in p.read_text().splitlines()[1:]:
                    assert line.split()[9] not in inodes, f"the daemon has an open {table} socket: {line}"
        d.write_lines(gps_lines(1.0), 60.0)
        time.sleep(0.3)
        out, err = d.signal(signal.SIGTERM)
    finally:
        d.close()
    assert d.proc.returncode == 0, err
    assert "Traceback" not in err and "log written" in out
    (log,) = d.logs()
    assert is_finished(log)
    assert [r.line for r in iter_raw_records(log) if isinstance(r, NmeaLine)] == [line for _, line in d.written]


def test_sigkill_log_readable_losing_at_most_a_second(tmp_path: Path, capsys) -> None:  # type: ignore[no-untyped-def]
    """SIGKILL mid-run: the standard MCAP reader reads the file; it has every line written up to about a second
    before the kill; replay and export work on it as it is; recover writes a finished copy that replays the same."""
    d = DaemonProcess(tmp_path)
    lines = gps_lines(2.5)
    try:
        d.start()
        d.write_lines(lines, 60.0)  # 2.5 s of 20 Hz epochs
        killed_at = time.time()
        d.signal(signal.SIGKILL)
    finally:
        d.close()
    assert d.proc is not None and d.proc.returncode == -signal.SIGKILL
    (log,) = d.logs()
    assert not is_finished(log)
    with open(log, "rb") as f:  # the standard reader, as is
        reader = make_reader(f)
        got = [json.loads(m.data)["line"] for _, c, m in reader.iter_messages(log_time_order=False)
               if c.topic == "/nmea/raw"]
    written = [line for _, line in d.written]
    assert got == written[: len(got)]  # a prefix: nothing reordered, nothing invented
    lost = [t for t, _ in d.written[len(got):]]
    assert not lost or killed_at - lost[0] <= 1.0 + 0.5, f"lost {killed_at - lost[0]:.2f} s of data"
    assert len(got) > 0.5 * len(written)
    # replay and export on the file as it is (a note says it was not finished)
    capsys.readouterr()
    assert main(["replay", str(log), "-o", str(tmp_path / "replayed.mcap")]) == 0
    assert "not finished" in capsys.readouterr().err
    assert main(["export", str(log), "--csv", str(tmp_path / "est.csv")]) == 0
    with open(tmp_path / "est.csv") as f:
        assert len(list(csv.reader(f))) - 1 == len(list(iter_estimates(log)))
    # recover: a finished copy, with the same raw records
    fixed = tmp_path / "fixed.mcap"
    assert main(["recover", str(log), "-o", str(fixed)]) == 0
    assert "not finished" in capsys.readouterr().out
    assert is_finished(fixed)
    assert [r.line for r in iter_raw_records(fixed) if isinstance(r, NmeaLine)] == got
    assert json.loads(read_metadata(fixed)["recovered_from"]) == [log.name]


# ---- torn files: killed inside a write, or a power loss ----

@pytest.fixture(scope="module")
def finished_log(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, list, list]:
    path = tmp_path_factory.mktemp("torn") / "run.mcap"
    records = sim_records(5.0)
    sink, estimates, _ = _write_live_log(path, records, commit_every_s=0.5)
    sink.close()
    return path, records, estimates


def _raw_prefix_ok(got: list, records: list) -> None:
    assert got == records[: len(got)]


@pytest.mark.parametrize("tail", ["cut", "zeros", "garbage"])
def test_torn_tail_reads_up_to_last_complete_chunk(finished_log, tmp_path: Path, tail: str) -> None:  # type: ignore[no-untyped-def]
    """Cut anywhere (killed inside a write), or with zeros or garbage after the cut (power loss): reading stops at
    the last whole chunk, never raises; recover makes a finished file of exactly that; the further the cut, the more
    is kept."""
    path, records, _ = finished_log
    data = path.read_bytes()
    rng = __import__("random").Random(tail)
    cuts = sorted(rng.sample(range(100, len(data) - 1), 25))
    kept = []
    for cut in cuts:
        torn = tmp_path / f"t{cut}.mcap"
        extra = b"" if tail == "cut" else bytes(4096) if tail == "zeros" else rng.randbytes(4096)
        torn.write_bytes(data[:cut] + extra)
        res = ScanResult(torn)
        got = list(iter_raw_records(torn, res))
        _raw_prefix_ok(got, records)
        assert res.stopped_because and not res.has_summary
        kept.append(len(got))
        if cut == cuts[-1]:
            fixed = tmp_path / "fixed.mcap"
            rep = recover([torn], fixed)
            assert is_finished(fixed) and list(iter_raw_records(fixed)) == got
            assert rep.inputs[0].read_bytes <= cut or tail != "cut"  # zeros may complete an index record
    assert kept == sorted(kept) and kept[-1] > 0.8 * len(records)


def test_not_an_mcap_file_is_one_clear_error(tmp_path: Path, capsys) -> None:  # type: ignore[no-untyped-def]
    bad = tmp_path / "bad.mcap"
    bad.write_bytes(b"hello, this is not MCAP")
    for argv in (["replay", str(bad), "-o", str(tmp_path / "o.mcap")], ["export", str(bad), "--csv", "x.csv"],
                 ["recover", str(bad), "-o", str(tmp_path / "r.mcap")]):
        assert main(argv) == 1
        err = capsys.readouterr().err
        assert str(bad) in err and err.count("\n") == 1 and "Traceback" not in err


# ---- disk full ----

def test_disk_full_clear_message_estimating_goes_on_and_logging_resumes(tmp_path: Path, caplog) -> None:  # type: ignore[no-untyped-def]
    """A log on a small tmpfs filled up: no exception reaches the pipeline, the error names the disk being full
    (log, live view), estimates go on, the file is readable up to its last commit, and once space is free the log
    goes on in a new segment (an event says how long and how many messages were dropped)."""
    records = sim_records(8.0, wpt_rate_hz=400.0)
    cfg = load_config(CONFIG)
    with small_tmpfs(tmp_path / "mnt", "1M") as mnt:
        filler = fill(mnt, 30_000)  # about 1 s of this log (CAN frames in batches)
        mono = FakeMonotonic()
        seen: list = []
        sink = McapLogSink(mnt / "run.mcap", cfg, mode="live", flush_every_s=1.0, monotonic=mono, fsync=False,
                           on_event=seen.append)
        collect = CollectingSink()
        status = StatusSink(SourceStatus(log_status=sink.log_status, log_path=lambda: str(sink.path)))
        p = Pipeline(cfg, [sink, collect, status])
        t0 = records[0].timestamp_s
        estimates_at_failure = None
        freed = False
        for r in records:
            mono.t = 1000.0 + r.timestamp_s - t0
            p.process(r)  # never raises
            if sink.error and estimates_at_failure is None:
                estimates_at_failure = len(collect.estimates)
                line = status_line(status, __import__("slipdaq.sinks.status", fromlist=["_Rates"])._Rates())
                assert "disk full" in line and "estimating goes on" in line
            if sink.error and not freed and r.timestamp_s - t0 > 4.5:
                filler.unlink()
                freed = True
        p.finish()
        sink.close()
        assert estimates_at_failure is not None, "the disk never filled"
        assert len(collect.estimates) > estimates_at_failure + 20  # estimating went on
        assert any("log write failed: disk full" in r.getMessage() for r in caplog.records)
        assert [e.event for e in seen] == ["write_failed", "resumed"]
        assert sink.error is None and sink.dropped_messages > 0
        first, second = run_segments(mnt / "run.mcap")
        assert not is_finished(first) and is_finished(second)
        res = ScanResult(first)
        part1 = list(iter_raw_records(first, res))
        assert res.finished and not res.stopped_because  # readable to its end: the last commit
        part2 = list(iter_raw_records(second))
        i = records.index(part2[0])
        assert part1 == records[: len(part1)] and part2 == records[i: i + len(part2)]
        events = [d for _, _, d in iter_topic(second, (TOPIC_EVENTS,))]
        assert events and events[0]["event"] == "resumed" and events[0]["counters"]["dropped_messages"] > 0


def test_log_dir_not_writable_is_one_clear_error(tmp_path: Path, capsys) -> None:  # type: ignore[no-untyped-def]
    (tmp_path / "logs").write_text("a file where the log dir should be")
    cfg_path = tmp_path / "c.toml"
    cfg_path.write_text(CONFIG.read_text().replace('interface = "socketcan"', 'interface = "virtual"'))
    (tmp_path / "wpt.dbc").write_text((CONFIG.parent / "wpt.dbc").read_text())
    assert main(["run", "--config", str(cfg_path), "--log-dir", str(tmp_path / "logs"), "--duration", "1"]) == 1
    err = capsys.readouterr().err
    assert "logs" in err and err.count("\n") == 1


# ---- rotation ----

def test_slipdaq_run_rotates_by_the_config(tmp_path: Path) -> None:
    """`slipdaq run` with log.rotate_duration_s = 10: after 10 s it goes on in NAME_002.mcap, says so at exit, and the
    segments hold every NMEA line written, once each, in order."""
    d = DaemonProcess(tmp_path)
    try:
        d.start("rotate_duration_s = 10\n")
        d.write_lines(gps_lines(12.0, rate_hz=10.0), 30.0)  # 360 lines (10 Hz x 3 sentences) in ~12 s
        out, err = d.signal(signal.SIGTERM)
    finally:
        d.close()
    assert d.proc is not None and d.proc.returncode == 0, err
    segments = d.logs()
    assert len(segments) == 2 and segments == run_segments(segments[0])
    assert f"log segments: {segments[0]} {segments[1]}" in out
    lines = [r.line for seg in segments for r in iter_raw_records(seg) if isinstance(r, NmeaLine)]
    assert lines == [line for _, line in d.written]
    assert all(is_finished(seg) for seg in segments) and read_metadata(segments[1])["segment"] == "2"


@pytest.mark.parametrize("policy", [RotationPolicy(max_bytes=25_000), RotationPolicy(max_s=1.5)],
                         ids=["size", "duration"])
def test_rotation_loses_no_message_at_a_boundary(tmp_path: Path, policy: RotationPolicy) -> None:
    """Segments by size or by duration: each a finished slipdaq log; their raw records, in order, are exactly the
    records; their estimates are the live ones; joined by `slipdaq recover`, the run replays to the same estimates."""
    records = sim_records(8.0)
    path = tmp_path / "run.mcap"
    sink, estimates, _ = _write_live_log(path, records, rotation=policy)
    sink.close()
    segments = run_segments(path)
    assert len(segments) >= 3 and segments == sink.segments
    raw, est = [], []
    for n, seg in enumerate(segments, 1):
        assert is_finished(seg)
        meta = read_metadata(seg)
        assert meta["segment"] == str(n) and meta["first_segment"] == path.name
        raw += list(iter_raw_records(seg))
        est += list(iter_estimates(seg))
    assert raw == records
    assert est == _same_json(estimates)
    if policy.max_bytes:  # cut within a second of it: the limit, a second of data and a file's fixed part at most
        McapLogSink(tmp_path / "empty.mcap", load_config(CONFIG), "live").close()
        fixed = (tmp_path / "empty.mcap").stat().st_size  # header, schemas, metadata, summary
        assert all(s.stat().st_size < 2 * policy.max_bytes + fixed for s in segments[:-1])
    joined = tmp_path / "joined.mcap"
    assert main(["recover", *map(str, segments), "-o", str(joined)]) == 0
    assert list(iter_raw_records(joined)) == records
    again = tmp_path / "again.mcap"
    assert main(["replay", str(joined), "-o", str(again)]) == 0
    assert list(iter_estimates(again)) == est


def test_recover_refuses_logs_of_different_runs(tmp_path: Path, capsys) -> None:  # type: ignore[no-untyped-def]
    a, b = tmp_path / "a.mcap", tmp_path / "b.mcap"
    cfg = load_config(CONFIG)
    McapLogSink(a, cfg, "live").close()
    McapLogSink(b, cfg.with_overrides(vehicle={"mass_kg": 1500.0}), "live").close()
    assert main(["recover", str(a), str(b), "-o", str(tmp_path / "j.mcap")]) == 1
    assert "another config" in capsys.readouterr().err




def test_scan_of_a_finished_file_reads_everything(finished_log) -> None:  # type: ignore[no-untyped-def]
    path, records, _ = finished_log
    res = ScanResult(path)
    items = list(scan(path, res))
    kinds = [k for k, _ in items]
    assert res.finished and res.has_summary and not res.stopped_because and res.read_bytes == res.size_bytes
    frames = sum(len(decode_can_batch(m.data)[1]) for k, (c, m) in ((k, i) for k, i in items if k == "message")
                 if c.topic == "/can/raw")
    assert kinds.count("metadata") == 1 and frames == sum(isinstance(r, CanFrame) for r in records)
    assert res.messages > sum(not isinstance(r, CanFrame) for r in records)
