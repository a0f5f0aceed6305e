"""The batched log format: /can/raw and /wpt/count in CDR batches, read back by us and by mcap-ros2-support, and
logs of the old per-frame format still read and replayed."""

from __future__ import annotations

import json
import sys
from pathlib import Path

import numpy as np
from mcap.reader import make_reader
from mcap_ros2.decoder import DecoderFactory

from slipdaq.cli import main
from slipdaq.config import load_config
from slipdaq.logformat.cdr import decode_can_batch, decode_wheel_batch
from slipdaq.logformat.reader import iter_raw_batches, iter_raw_records, iter_topic
from slipdaq.logformat.topics import MAX_BATCH_FRAMES, MAX_BATCH_SPAN_S, TOPIC_CAN, TOPIC_ESTIMATE, TOPIC_NMEA, TOPIC_WPT
from support.paths import CONFIG, ROOT
from support.reliability_support import sim_records

sys.path.insert(0, str(ROOT / "tools"))
from legacy_log import write_old_format_log  # noqa: E402  (tools/: the old format's writer, shared with benchmarks)
from slipdaq.pipeline import Pipeline
from slipdaq.records import CanFrame, CanFrameBatch, NmeaLine
from slipdaq.sinks import CollectingSink
from slipdaq.sinks.mcap_log import McapLogSink


def _odd_frames() -> list:
    """CAN FD payloads, short ones, error and extended frames between WPT traffic, and NMEA lines."""
    rec = sim_records(3.0, wpt_rate_hz=200.0)
    out: list = []
    for k, r in enumerate(rec):
        out.append(r)
        if k % 97 == 0:
            out.append(CanFrame(r.timestamp_s, 0x18DAF110, bytes(range(k % 65)), is_extended_id=True))
        if k % 131 == 0:
            out.append(CanFrame(r.timestamp_s, 0x20000004, bytes(8), is_extended_id=True, is_error_frame=True))
        if k % 151 == 0:
            out.append(CanFrame(r.timestamp_s, 0x7DF, b""))
    return out


def _write(path: Path, records: list, batched: bool) -> Pipeline:
    cfg = load_config(CONFIG)
    sink = McapLogSink(path, cfg, mode="live")
    p = Pipeline(cfg, [sink])
    run: list = []
    for r in records:
        if batched and isinstance(r, CanFrame):
            run.append(r)
            continue
        if run:
            p.process_can_batch(run)
            run = []
        p.process(r)
    if run:
        p.process_can_batch(run)
    p.finish()
    sink.close()
    return p


def test_every_frame_and_line_comes_back_in_order(tmp_path: Path) -> None:
    records = _odd_frames()
    for batched in (False, True):
        path = tmp_path / f"b{batched}.mcap"
        _write(path, records, batched)
        assert list(iter_raw_records(path)) == records
        n = 0
        with open(path, "rb") as f:
            for _, channel, m in make_reader(f).iter_messages(topics=[TOPIC_CAN, TOPIC_NMEA], log_time_order=False):
                if channel.topic == TOPIC_CAN:
                    first, b = decode_can_batch(m.data)
                    assert first == n and 0 < len(b) <= MAX_BATCH_FRAMES
                    assert float(b.timestamp_s[-1] - b.timestamp_s[0]) <= MAX_BATCH_SPAN_S + 0.01
                    n += len(b)
                else:
                    assert json.loads(m.data)["can_index"] == n  # the frames before it, exactly
        assert n == sum(isinstance(r, CanFrame) for r in records)


def test_cdr_batches_read_by_mcap_ros2_support(tmp_path: Path) -> None:
    path = tmp_path / "log.mcap"
    _write(path, _odd_frames(), True)
    checked = {TOPIC_CAN: 0, TOPIC_WPT: 0}
    with open(path, "rb") as f:
        reader = make_reader(f, decoder_factories=[DecoderFactory()])
        for _schema, channel, m, ros in reader.iter_decoded_messages(topics=list(checked), log_time_order=False):
            checked[channel.topic] += 1
            if channel.topic == TOPIC_CAN:
                first, b = decode_can_batch(m.data)
                assert ros.first_index == first
                assert list(ros.timestamp_s) == b.timestamp_s.tolist() and list(ros.id) == b.arbitration_id.tolist()
                assert list(ros.flags) == b.flags.tolist() and list(ros.dlc) == b.dlc.tolist()
                assert bytes(ros.data) == b"".join(b.payload(i) for i in range(len(b)))
            else:
                first, s = decode_wheel_batch(m.data)
                assert ros.first_index == first
                for field in ("timestamp_s", "wheel", "revolutions", "count", "raw", "seq", "lost_frames", "flags"):
                    assert list(getattr(ros, field)) == getattr(s, field).tolist(), field
    assert checked[TOPIC_CAN] > 10 and checked[TOPIC_WPT] > 10


def test_old_per_frame_log_replays_to_the_same_estimates(tmp_path: Path, capsys) -> None:  # type: ignore[no-untyped-def]
    records = [r for r in sim_records(6.0, wpt_rate_hz=200.0) if isinstance(r, (CanFrame, NmeaLine))]
    old = tmp_path / "old.mcap"
    write_old_format_log(old, load_config(CONFIG), records)
    assert list(iter_raw_records(old)) == records
    items = list(iter_raw_batches(old))
    assert any(isinstance(i, CanFrameBatch) and len(i) > 1 for i in items)
    # what the pipeline made of the records one by one, when they were recorded
    collect = CollectingSink()
    p = Pipeline(load_config(CONFIG), [collect])
    for r in records:
        p.process(r)
    assert main(["replay", str(old), "-o", str(tmp_path / "new.mcap")]) == 0
    new = tmp_path / "new.mcap"
    got = [d for _, _, d in iter_topic(new, (TOPIC_ESTIMATE,))]
    assert len(got) > 30 and got == [json.loads(json.dumps(e.as_row())) for e in collect.estimates]
    assert list(iter_raw_records(new)) == records  # and the replay's log is in the new format, every frame kept
    with open(new, "rb") as f:
        summary = make_reader(f).get_summary()
    assert summary is not None
    assert {c.topic: c.message_encoding for c in summary.channels.values()}[TOPIC_CAN] == "cdr"


def test_batch_columns_round_trip() -> None:
    frames = [CanFrame(1.5, 0x310, bytes(range(8))), CanFrame(1.6, 0x1FFFFFFF, b"\x01", True),
              CanFrame(1.7, 0, bytes(64)), CanFrame(1.8, 5, b"", False, True)]
    b = CanFrameBatch.from_frames(frames)
    assert list(b.frames()) == frames and b.data.shape == (4, 64)
    from slipdaq.logformat.cdr import encode_can_batch
    first, back = decode_can_batch(encode_can_batch(7, b))
    assert first == 7 and list(back.frames()) == frames
    assert np.array_equal(back.dlc, [8, 1, 64, 0])


def test_status_sink_counts_batches_as_records() -> None:
    from slipdaq.sinks.status import StatusSink

    records = _odd_frames()
    one, many = StatusSink(), StatusSink()
    p1, p2 = Pipeline(load_config(CONFIG), [one]), Pipeline(load_config(CONFIG), [many])
    for r in records:
        p1.process(r)
    run: list = []
    for r in records + [None]:
        if isinstance(r, CanFrame):
            run.append(r)
            continue
        p2.process_can_batch(run)
        run = []
        if r is not None:
            p2.process(r)
    assert (many.can_frames, many.nmea_lines, many.wheel_frames, many.can_errors) == \
        (one.can_frames, one.nmea_lines, one.wheel_frames, one.can_errors)
    assert one.can_errors


def test_idle_live_sink_waits_for_the_next_flush_period(tmp_path: Path) -> None:
    """With nothing to write for longer than a flush period, the flush timer is armed a flush period ahead (it used
    to re-arm itself with no delay, spinning on the event loop)."""
    import asyncio

    mono = [1000.0]

    async def run() -> float:
        sink = McapLogSink(tmp_path / "idle.mcap", load_config(CONFIG), mode="live", flush_every_s=10.0,
                           monotonic=lambda: mono[0])
        mono[0] += 30.0  # the sink's clock: 30 s without a record
        sink._tick()  # what the timer does when it fires
        assert sink._timer is not None
        ahead = sink._timer.when() - asyncio.get_running_loop().time()
        sink.close()
        return ahead

    assert asyncio.run(run()) > 5.0  # about one flush period (10 s), not 0
