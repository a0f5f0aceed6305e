"""A chunk read with the messages of other topics passed over (logformat.chunk_read) against mcap's breakup_chunk,
chunk by chunk, on logs slipdaq wrote (two older revisions' and this one's) and on files mcap's own Writer wrote;
and a scan that reads some topics (salvage.scan's topics) against a scan of everything, on sound and damaged logs."""

from __future__ import annotations

import zlib
from collections.abc import Callable, Collection
from pathlib import Path
from typing import Any

import pytest
import zstandard
from mcap.exceptions import McapError
from mcap.opcode import Opcode
from mcap.reader import make_reader
from mcap.records import Channel, Chunk, Message
from mcap.stream_reader import CRCValidationError, StreamReader, breakup_chunk
from mcap.writer import CompressionType, Writer

from slipdaq.logformat.chunk_read import chunk_messages
from slipdaq.logformat.damage import BadRecord, chunk_records
from slipdaq.logformat.salvage import ScanResult, scan
from slipdaq.logformat.topics import RAW_TOPICS, TOPIC_ESTIMATE
from support.paths import DATA
from support.sim_logs import chunked_log

OLDER_LOGS = [DATA / "slipdaq-6641212" / "drive-fast-rows.mcap", DATA / "slipdaq-42c5f78" / "logfile-asc-import.mcap"]


@pytest.fixture(scope="module")
def log(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """This tree's log of a 20 s drive in chunks of 32 kB (a dozen or more)."""
    return chunked_log(tmp_path_factory.mktemp("chunk-read"), 20.0, 32768, seed=3)


def mcap_written(path: Path, compression: CompressionType) -> Path:
    """A file from mcap's own Writer: three channels on two schemas, small chunks (channels defined in them)."""
    with open(path, "wb") as f:
        w = Writer(f, chunk_size=2048, compression=compression)
        w.start(profile="", library="test")
        schema = w.register_schema("s", "jsonschema", b"{}")
        ids = [w.register_channel(t, "json", schema) for t in ("/a", "/b")]
        ids.append(w.register_channel("/c", "raw", w.register_schema("r", "", b"")))
        for k in range(600):
            w.add_message(ids[k % 3], log_time=1_000 * k, data=b'{"k": %d}' % k + b"x" * (k % 37),
                          publish_time=1_000 * k + 1, sequence=k)
        w.finish()
    return path


def file_chunks(path: Path) -> list[Chunk]:
    with open(path, "rb") as f:
        return [r for r in StreamReader(f, emit_chunks=True).records if isinstance(r, Chunk)]


def summary_topics(path: Path) -> dict[int, str]:
    with open(path, "rb") as f:
        summary = make_reader(f).get_summary()
    assert summary is not None
    return {c.id: c.topic for c in summary.channels.values()}


def by_the_library(chunk: Chunk, topics: Collection[str], topic_of: Callable[[int], str | None]) -> list[Any]:
    """breakup_chunk's records, a message of a topic not read as its (channel id, log time)."""
    out: list[Any] = []
    local: dict[int, str] = {}
    for r in breakup_chunk(chunk, validate_crc=True):
        if isinstance(r, Channel):
            local[r.id] = r.topic
        if isinstance(r, Message):
            topic = local.get(r.channel_id) or topic_of(r.channel_id)
            if topic is not None and topic not in topics:
                out.append((r.channel_id, r.log_time))
                continue
        out.append(r)
    return out


def logs(log: Path, tmp_path: Path) -> list[Path]:
    return [log, *OLDER_LOGS, mcap_written(tmp_path / "zstd.mcap", CompressionType.ZSTD),
            mcap_written(tmp_path / "none.mcap", CompressionType.NONE)]


@pytest.mark.parametrize("topics", [RAW_TOPICS, (TOPIC_ESTIMATE, "/b"), (), None], ids=["raw", "some", "none", "all"])
def test_every_chunk_reads_as_breakup_chunk_reads_it(log: Path, tmp_path: Path, topics: tuple[str, ...] | None) -> None:
    passed = read = 0
    for path in logs(log, tmp_path):
        known = summary_topics(path)
        wanted = tuple(known.values()) if topics is None else topics
        chunks = file_chunks(path)
        assert chunks, path
        for topic_of in (known.get, lambda _: None):  # the channels known before the chunk, or none of them
            for chunk in chunks:
                got = chunk_messages(chunk, wanted, topic_of)
                assert got == by_the_library(chunk, wanted, topic_of)
                passed += sum(isinstance(r, tuple) for r in got)
                read += sum(isinstance(r, Message) for r in got)
    assert read > 0  # with topics=(): the messages of channels not known before their chunk
    assert passed == 0 if topics is None else passed > 0


def rebuilt(chunk: Chunk, content: bytes, *, crc: int | None = None) -> Chunk:
    """The chunk with other records' bytes, compressed as it was."""
    data = zstandard.compress(content) if chunk.compression == "zstd" else content
    return Chunk(message_start_time=chunk.message_start_time, message_end_time=chunk.message_end_time,
                 uncompressed_size=len(content), uncompressed_crc=zlib.crc32(content) if crc is None else crc,
                 compression=chunk.compression, data=data)


def test_a_chunk_whose_records_do_not_fit_it_is_damaged(log: Path) -> None:
    """A record past the chunk's end, a header cut short, a message shorter than its fixed fields: an error (a
    chunk that does not decode), and a chunk that fails its CRC: the library's error."""
    chunk = file_chunks(log)[0]
    content = zstandard.decompress(chunk.data, chunk.uncompressed_size)
    assert content[0] in (Opcode.SCHEMA, Opcode.CHANNEL, Opcode.MESSAGE)
    topic_of = summary_topics(log).get
    assert chunk_messages(rebuilt(chunk, content), RAW_TOPICS, topic_of) == chunk_messages(chunk, RAW_TOPICS, topic_of)
    for bad in (content[:-3],  # the last record cut short
                content + b"\x05\x01\x00",  # a record header cut short
                content + bytes([Opcode.MESSAGE]) + (10).to_bytes(8, "little") + b"\x00" * 10):  # a message too short
        damaged = rebuilt(chunk, bad)
        for topics in (RAW_TOPICS, None):
            with pytest.raises(McapError):
                chunk_messages(damaged, topics, topic_of)
            with pytest.raises(BadRecord, match="does not decode"):
                chunk_records(damaged, 0, 1, topics, topic_of)
    wrong_crc = rebuilt(chunk, content, crc=zlib.crc32(content) ^ 1)
    for read in (lambda c: breakup_chunk(c, validate_crc=True), lambda c: chunk_messages(c, RAW_TOPICS, topic_of)):
        with pytest.raises(CRCValidationError):
            read(wrong_crc)
    with pytest.raises(BadRecord, match="fails its CRC check"):
        chunk_records(wrong_crc, 0, 1, RAW_TOPICS, topic_of)


def damaged_copies(log: Path, tmp_path: Path) -> list[Path]:
    """The log with a chunk's middle bytes flipped, cut in its last third, and with both; and with its first chunk
    flipped (the channels it defines then come from the summary)."""
    data = log.read_bytes()
    with open(log, "rb") as f:
        summary = make_reader(f).get_summary()
    assert summary is not None and len(summary.chunk_indexes) >= 6
    indexes = sorted(summary.chunk_indexes, key=lambda c: c.chunk_start_offset)

    def flipped(index: Any) -> bytearray:
        copy = bytearray(data)
        mid = index.chunk_start_offset + index.chunk_length // 2
        for off in range(mid, mid + 4):
            copy[off] ^= 0xFF
        return copy

    third = flipped(indexes[2])
    out = []
    for name, content in (("flipped", bytes(third)), ("cut", data[:len(data) * 2 // 3]),
                          ("both", bytes(third[:len(data) * 2 // 3])), ("first", bytes(flipped(indexes[0])))):
        (tmp_path / f"{name}.mcap").write_bytes(content)
        out.append(tmp_path / f"{name}.mcap")
    return out


def test_a_scan_of_some_topics_reads_what_a_scan_of_all_reads(log: Path, tmp_path: Path) -> None:
    """Their messages, every other record, and the same ScanResult (messages counted, by topic, the damage found,
    where it stopped) on the log, its damaged copies and the older logs."""
    for path in [log, *damaged_copies(log, tmp_path), *OLDER_LOGS]:
        for topics in (RAW_TOPICS, (TOPIC_ESTIMATE,), ()):
            whole, some = ScanResult(path), ScanResult(path)
            everything = [(k, i) for k, i in scan(path, whole, skip_damage=True)
                          if k != "message" or i[0].topic in topics]
            assert list(scan(path, some, skip_damage=True, topics=topics)) == everything
            assert some == whole
            assert whole.messages > 0
    damaged = ScanResult(tmp_path / "both.mcap")
    list(scan(tmp_path / "both.mcap", damaged, skip_damage=True, topics=RAW_TOPICS))
    assert damaged.damaged and damaged.stopped_because, "the copy holds damage and a tear"
    first = ScanResult(tmp_path / "first.mcap")
    kinds = [k for k, _ in scan(tmp_path / "first.mcap", first, skip_damage=True, topics=(TOPIC_ESTIMATE,))]
    assert first.damaged and "channel" in kinds, "channels defined by the summary only, after the damage"

