"""/can/raw keeps every field python-can gives a frame: remote (with the DLC it asks for), CAN FD, bit rate switch,
error state indicator, direction, DLC, payloads up to 64 bytes and the channel, through import, replay, recover,
tools/replay/replay_bus.py and the live CAN source. The input is python-can's own test logs (tests/data/python-can)
and candump and CSV logs python-can's writers make of them; what python-can's LogReader reads from each file is the
reference. The logs are read back with mcap's reader and mcap-ros2-support's decoder, by the bit numbers and
field names docs/log.md states, not with slipdaq's reader."""

from __future__ import annotations

import asyncio
import contextlib
import importlib.util
import io
import json
import time
from pathlib import Path

import can
import pytest
from mcap.reader import make_reader
from mcap_ros2.decoder import DecoderFactory

from slipdaq.cli import main
from slipdaq.config import load_config
from slipdaq.logformat.reader import iter_raw_records
from slipdaq.pipeline import Pipeline
from slipdaq.records import CanFrame, CanFrameBatch
from slipdaq.sources.can_bus import CanBusSource
from support.paths import CONFIG, DATA, ROOT
from support.reliability_support import nmea

PYCAN = DATA / "python-can"
FILES = sorted(p.name for p in PYCAN.iterdir() if p.suffix in (".asc", ".blf", ".trc"))
FIELDS = ("timestamp", "arbitration_id", "is_extended_id", "is_error_frame", "is_remote_frame", "is_fd",
          "bitrate_switch", "error_state_indicator", "is_rx", "dlc", "data", "channel")


def message_fields(m: can.Message) -> dict:
    """A python-can Message as the fields compared (the channel as its str, as a slipdaq log names it)."""
    d = {k: getattr(m, k) for k in FIELDS}
    d["data"] = bytes(m.data)
    d["channel"] = None if m.channel is None else str(m.channel)
    return d


def read_can_raw(path: Path) -> list[dict]:
    """Every frame of a slipdaq log's /can/raw, decoded by mcap-ros2-support from the log's own schema, with the
    meaning docs/log.md gives each field: flags bit 0 extended, 1 error, 2 remote, 3 CAN FD, 4 bit rate switch, 5 error
    state indicator, 6 transmitted, 7 DLC other than the 8-byte payload's; `channel` indexes the can_channels list of
    the log's last `slipdaq` metadata record; payloads back to back (none for a remote frame)."""
    with open(path, "rb") as f:
        reader = make_reader(f, decoder_factories=[DecoderFactory()])
        metas = [m.metadata for m in reader.iter_metadata() if m.name == "slipdaq"]
        names = json.loads(metas[-1]["can_channels"])
        out = []
        for _s, channel, _m, msg in reader.iter_decoded_messages(topics=["/can/raw"], log_time_order=False):
            assert channel.message_encoding == "cdr"
            data = bytes(msg.data)
            pos = 0
            for t, ident, flags, dlc, ch in zip(msg.timestamp_s, msg.id, msg.flags, msg.dlc, msg.channel):
                n = 0 if flags & 4 else 8 if flags & 128 else dlc
                out.append({"timestamp": t, "arbitration_id": ident, "is_extended_id": bool(flags & 1),
                            "is_error_frame": bool(flags & 2), "is_remote_frame": bool(flags & 4),
                            "is_fd": bool(flags & 8), "bitrate_switch": bool(flags & 16),
                            "error_state_indicator": bool(flags & 32), "is_rx": not flags & 64, "dlc": dlc,
                            "data": data[pos:pos + n], "channel": names[ch]})
                pos += n
            assert pos == len(data)
    return out


def nmea_log(path: Path, t: float) -> Path:
    """One RMC at time t of the CAN log's clock (import needs an NMEA log)."""
    path.write_text(f"({t:.6f}) {nmea('GPRMC,120000.00,A,4807.038,N,01131.000,E,10.0,90.0,230394,,,A')}\n")
    return path


def import_log(can_log: Path, out: Path) -> Path:
    first = next(iter(can.LogReader(str(can_log))))
    with contextlib.redirect_stdout(io.StringIO()):
        rc = main(["import", "--can", str(can_log), "--nmea", str(nmea_log(out.with_suffix(".nmea"), first.timestamp)),
                   "--config", str(CONFIG), "-o", str(out)])
    assert rc == 0
    return out


def written_by_python_can(tmp_path: Path, suffix: str) -> Path:
    """python-can's writer for `suffix` (candump -L .log, .csv) over every message of the test logs: the file that
    python-can's reader then reads back as it reads it."""
    path = tmp_path / f"all{suffix}"
    with can.Logger(str(path)) as writer:
        for name in FILES:
            for m in can.LogReader(str(PYCAN / name)):
                writer.on_message_received(m)
    return path


@pytest.mark.parametrize("name", FILES + ["candump.log", "python-can.csv"])
def test_import_keeps_every_field_python_can_gives(tmp_path: Path, name: str) -> None:
    if name == "candump.log":
        src = written_by_python_can(tmp_path, ".log")
    elif name == "python-can.csv":
        src = written_by_python_can(tmp_path, ".csv")
    else:
        src = PYCAN / name
    expected = [message_fields(m) for m in can.LogReader(str(src))]
    assert expected
    got = read_can_raw(import_log(src, tmp_path / "imported.mcap"))
    assert got == expected


def test_replay_and_recover_keep_every_field(tmp_path: Path) -> None:
    src = PYCAN / "logfile.asc"  # five channels, remote, CAN FD, bit rate switch, transmitted and error frames
    imported = import_log(src, tmp_path / "imported.mcap")
    expected = [message_fields(m) for m in can.LogReader(str(src))]
    assert {k for m in can.LogReader(str(src)) for k in ("is_remote_frame", "is_fd", "bitrate_switch",
                                                        "is_error_frame") if getattr(m, k)} | \
        {"tx" for m in can.LogReader(str(src)) if not m.is_rx} == \
        {"is_remote_frame", "is_fd", "bitrate_switch", "is_error_frame", "tx"}
    with contextlib.redirect_stdout(io.StringIO()):
        assert main(["replay", str(imported), "-o", str(tmp_path / "replayed.mcap")]) == 0
        assert main(["recover", str(imported), "-o", str(tmp_path / "recovered.mcap")]) == 0
        assert main(["replay", str(tmp_path / "replayed.mcap"), "-o", str(tmp_path / "twice.mcap")]) == 0
    for name in ("replayed", "recovered", "twice"):
        assert read_can_raw(tmp_path / f"{name}.mcap") == expected, name


def _load_replay_bus():  # type: ignore[no-untyped-def]
    spec = importlib.util.spec_from_file_location("replay_bus", ROOT / "tools" / "replay" / "replay_bus.py")
    assert spec is not None and spec.loader is not None
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


@pytest.mark.parametrize("name", ["logfile.asc", "test_CanFdMessage64.blf", "test_CanRemoteMessage.asc",
                                  "test_CanMessage_V2_1.trc"])
def test_replay_bus_sends_every_frame_as_it_was(tmp_path: Path, name: str) -> None:
    """tools/replay/replay_bus.py puts an imported log on python-can's virtual bus, each logged channel on a bus of
    its own (`--channel LOGGED=CH`): every frame arrives on its channel's bus with the fields python-can read from
    the file. The direction (is_rx) is the receiver's own view on any bus (python-can's virtual bus sets it, as
    SocketCAN does), so it is checked on the messages replay_bus sends."""
    src = PYCAN / name
    originals = list(can.LogReader(str(src)))
    imported = import_log(src, tmp_path / "imported.mcap")
    prefix = f"rb-{time.monotonic_ns()}-"
    names = sorted({str(m.channel) for m in originals})
    receivers = {n: can.Bus(interface="virtual", channel=prefix + n) for n in names}
    try:
        with contextlib.redirect_stdout(io.StringIO()) as out:
            rc = _load_replay_bus().main([str(imported), "--interface", "virtual", "--speed", "1000"]
                                         + [a for n in names for a in ("--channel", f"{n}={prefix}{n}")])
        assert rc == 0 and f"sent {len(originals)} CAN frames" in out.getvalue()
        for n, bus in receivers.items():
            got = []
            while (m := bus.recv(timeout=0)) is not None:
                got.append(m)
            want = [m for m in originals if str(m.channel) == n]
            assert [m.channel for m in got] == [prefix + n] * len(want)
            skip = ("timestamp", "is_rx", "channel")
            assert [{k: v for k, v in message_fields(m).items() if k not in skip} for m in got] == \
                [{k: v for k, v in message_fields(m).items() if k not in skip} for m in want]
    finally:
        for bus in receivers.values():
            bus.shutdown()
    from slipdaq.sources.can_bus import to_message  # what replay_bus sends for each logged frame

    sent = [to_message(f) for f in iter_raw_records(imported) if isinstance(f, CanFrame)]
    assert [(m.is_rx, m.channel) for m in sent] == [(m.is_rx, str(m.channel)) for m in originals]


def test_the_live_can_source_keeps_every_field() -> None:
    """CanBusSource on python-can's virtual bus (the thread reader): a frame at a time and many at once (each a
    CanFrameBatch) both keep remote, DLC, CAN FD, bit rate switch, error state indicator and payloads; the channel is
    the bus's."""
    originals = [m for name in FILES for m in can.LogReader(str(PYCAN / name))]
    channel = f"live-{time.monotonic_ns()}"
    got: list[CanFrame] = []
    batches: list[int] = []

    def take(frames: CanFrameBatch) -> None:
        batches.append(len(frames))
        got.extend(frames.frames())

    async def run() -> None:
        with can.Bus(interface="virtual", channel=channel) as rx, can.Bus(interface="virtual", channel=channel) as tx:
            src = CanBusSource(rx)
            task = asyncio.create_task(src.run(got.append, take))
            await asyncio.sleep(0.1)
            for m in originals[:5]:
                tx.send(m)
                await asyncio.sleep(0.05)
            for m in originals[5:]:
                tx.send(m)
            t_end = time.monotonic() + 5.0
            while len(got) < len(originals) and time.monotonic() < t_end:
                await asyncio.sleep(0.02)
            task.cancel()
            with contextlib.suppress(asyncio.CancelledError):
                await task

    asyncio.run(run())
    from slipdaq.sources.can_bus import to_message

    assert min(batches) == 1 and max(batches) > 1
    skip = ("timestamp", "is_rx", "channel")
    assert [{k: v for k, v in message_fields(to_message(f)).items() if k not in skip} for f in got] == \
        [{k: v for k, v in message_fields(m).items() if k not in skip} for m in originals]
    assert {f.channel for f in got} == {channel}


def test_a_remote_frame_with_a_wheel_s_id_is_not_wheel_data() -> None:
    """A remote frame asking for WPT_FL (8 bytes) carries no count: it is an unknown frame, not a zero count, frame
    by frame and in a batch alike."""
    cfg = load_config(CONFIG)
    frames = [CanFrame(0.01 * k, 0x310, (1000 * k).to_bytes(4, "little") + bytes([0, 0, 0, k])) for k in range(1, 60)]
    frames.insert(30, CanFrame(0.305, 0x310, b"", is_remote_frame=True, dlc=8))
    one, many = Pipeline(cfg, []), Pipeline(cfg, [])
    for f in frames:
        one.process(f)
    many.process_can_batch(CanFrameBatch.from_frames(frames))
    for p in (one, many):
        d = p.diagnostics()
        assert (d.wpt_frames["FL"], d.unknown_frames, d.bad_frames, d.lost_frames["FL"]) == (59, 1, 0, 0)


OLD = DATA / "slipdaq-42c5f78"


def test_logs_written_before_still_read(tmp_path: Path) -> None:
    """A log that slipdaq 42c5f78 imported from logfile.asc (its /can/raw schema has no channel; remote frames were
    zero-length data frames then): read, replayed and recovered as it was, every frame on the one unnamed channel."""
    old = OLD / "logfile-asc-import.mcap"
    src = [m for m in can.LogReader(str(PYCAN / "logfile.asc"))]
    then = [(m.timestamp, m.arbitration_id, m.is_extended_id, m.is_error_frame, bytes(m.data)) for m in src]
    frames = [r for r in iter_raw_records(old) if isinstance(r, CanFrame)]
    assert [(f.timestamp_s, f.arbitration_id, f.is_extended_id, f.is_error_frame, f.data) for f in frames] == then
    assert all(f.channel is None and f.flags & ~3 == 0 for f in frames)
    with contextlib.redirect_stdout(io.StringIO()):
        assert main(["replay", str(old), "-o", str(tmp_path / "replayed.mcap")]) == 0
        assert main(["recover", str(old), "-o", str(tmp_path / "recovered.mcap")]) == 0
    replayed = read_can_raw(tmp_path / "replayed.mcap")  # the new format: channel 0 of can_channels [null]
    assert [(d["timestamp"], d["arbitration_id"], d["is_extended_id"], d["is_error_frame"], d["data"])
            for d in replayed] == then
    assert {d["channel"] for d in replayed} == {None}
    assert [r for r in iter_raw_records(tmp_path / "recovered.mcap") if isinstance(r, CanFrame)] == frames


def test_a_channel_that_appears_in_a_later_segment_is_named_after_recover(tmp_path: Path) -> None:
    """A live run cut into segments (rotation) whose bus shows a second channel only in its third second: each
    segment names every channel its frames use, and so does `slipdaq recover` of the segments joined."""
    from slipdaq.logformat.rotation import RotationPolicy, run_segments
    from slipdaq.sinks.mcap_log import McapLogSink
    from support.reliability_support import sim_records

    records = sim_records(5.0)
    t0 = records[0].timestamp_s
    records = [CanFrame(r.timestamp_s, r.arbitration_id, r.data, channel="can1" if r.timestamp_s - t0 > 3.0 and
                        k % 3 == 0 else "can0") if isinstance(r, CanFrame) else r for k, r in enumerate(records)]
    clock = [1000.0]
    path = tmp_path / "run.mcap"
    sink = McapLogSink(path, load_config(CONFIG), "live", flush_every_s=0.5, monotonic=lambda: clock[0], fsync=False,
                       rotation=RotationPolicy(max_s=1.5), can_channels=["can0"])
    p = Pipeline(load_config(CONFIG), [sink])
    for r in records:
        clock[0] = 1000.0 + r.timestamp_s - t0
        p.process(r)
    p.finish()
    sink.close()
    segments = run_segments(path)
    assert len(segments) >= 3
    channels = [(r.timestamp_s, r.channel) for r in records if isinstance(r, CanFrame)]
    assert [(d["timestamp"], d["channel"]) for s in segments for d in read_can_raw(s)] == channels
    with contextlib.redirect_stdout(io.StringIO()):
        assert main(["recover", *map(str, segments), "-o", str(tmp_path / "joined.mcap")]) == 0
    assert [(d["timestamp"], d["channel"]) for d in read_can_raw(tmp_path / "joined.mcap")] == channels
