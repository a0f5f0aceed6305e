"""The log's MCAP writer: the file mcap.Writer writes (zstd chunks, message indexes, the summary with statistics,
chunk and metadata indexes, summary offsets), byte for byte (tested against it), with what the log does per message
made cheap: a message is appended to its chunk with one struct.pack, a chunk's message indexes are packed whole, and a
chunk filled by messages is compressed on a worker thread (zstd releases the GIL) while the next one fills. That chunk
is written in its place, before any later record, and flush() and finish() wait for it; the stream gets whole
records in each write() as from mcap.Writer (logformat.durable relies on it)."""

from __future__ import annotations

import struct
import zlib
from collections import defaultdict
from concurrent.futures import Future, ThreadPoolExecutor
from types import TracebackType
from typing import Any

import zstandard
from mcap.data_stream import RecordBuilder
from mcap.opcode import Opcode
from mcap.records import (
    Channel,
    Chunk,
    ChunkIndex,
    DataEnd,
    Footer,
    Header,
    Metadata,
    MetadataIndex,
    Schema,
    Statistics,
    SummaryOffset,
)

MAGIC = b"\x89MCAP0\r\n"
_MESSAGE = struct.Struct("<BQHIQQ")
"""A Message record's opcode, length, channel id, sequence, log time and publish time; its data follows."""
_MESSAGE_INDEX = struct.Struct("<BQHI")


def _compress(data: bytes) -> tuple[bytes, int]:
    """The chunk's records compressed as mcap.Writer does (zstd at its default level, 3), and their CRC-32 (both
    release the GIL)."""
    return zstandard.compress(data), zlib.crc32(data)


class _Finished:
    """A chunk closed and being compressed: what its Chunk, MessageIndex and ChunkIndex records need."""

    __slots__ = ("compressed", "end_ns", "indexes", "size", "start_ns")

    def __init__(self, data: bytes, start_ns: int, end_ns: int, indexes: dict[int, list[int]],
                 pool: ThreadPoolExecutor | None) -> None:
        self.compressed: Future[tuple[bytes, int]] | tuple[bytes, int] = \
            pool.submit(_compress, data) if pool is not None else _compress(data)
        self.size = len(data)
        self.start_ns, self.end_ns, self.indexes = start_ns, end_ns, indexes


class McapWriter:
    """Writes an MCAP file to a binary stream (write, tell, flush): start, register_schema, register_channel,
    add_metadata, add_message, flush (the chunk in progress closed and written), finish (the summary and footer)."""

    def __init__(self, stream: Any, chunk_size: int = 1024 * 1024) -> None:
        self._stream = stream
        self._chunk_size = chunk_size
        self._records = RecordBuilder()
        self._chunk = bytearray()
        self._chunk_messages = 0
        self._chunk_start = self._chunk_end = 0
        self._indexes: dict[int, list[int]] = {}
        """Per channel (in the order of its first message in the chunk): log time, offset, log time, offset, ..."""
        self._finished: _Finished | None = None
        self._pool: ThreadPoolExecutor | None = None
        self._schemas: dict[int, Schema] = {}
        self._channels: dict[int, Channel] = {}
        self._chunk_indexes = bytearray()
        """The summary's ChunkIndex records, serialized as each chunk is written (about 210 bytes a chunk with 13
        channels, a seventh of a ChunkIndex object's 1.4 kB: a day's log has thousands of chunks)."""
        self._metadata_indexes: list[MetadataIndex] = []
        self._stats = Statistics(attachment_count=0, channel_count=0, channel_message_counts=defaultdict(int),
                                 chunk_count=0, message_count=0, metadata_count=0, message_start_time=0,
                                 message_end_time=0, schema_count=0)

    # ---- records outside chunks ----
    def _flush_records(self) -> None:
        """The records built so far to the stream, after the chunk being compressed."""
        if self._finished is not None:
            self._write_finished()
        data = self._records.end()
        if data:
            self._stream.write(data)

    def start(self, profile: str = "", library: str = "") -> None:
        self._stream.write(MAGIC)
        Header(profile, library).write(self._records)
        self._flush_records()

    def add_metadata(self, name: str, data: dict[str, str]) -> None:
        self._flush_records()
        offset = self._stream.tell()
        self._stats.metadata_count += 1
        Metadata(name=name, metadata=data).write(self._records)
        self._metadata_indexes.append(MetadataIndex(offset=offset, length=self._records.count, name=name))
        self._flush_records()

    # ---- into the chunk ----
    def _add_to_chunk(self, record: Schema | Channel) -> None:
        b = RecordBuilder()
        record.write(b)
        self._chunk += b.end()
        if len(self._chunk) > self._chunk_size:
            self._close_chunk(compress_on_thread=True)

    def register_schema(self, name: str, encoding: str, data: bytes) -> int:
        schema_id = len(self._schemas) + 1
        self._schemas[schema_id] = schema = Schema(id=schema_id, data=data, encoding=encoding, name=name)
        self._stats.schema_count += 1
        self._add_to_chunk(schema)
        return schema_id

    def register_channel(self, topic: str, message_encoding: str, schema_id: int) -> int:
        channel_id = len(self._channels) + 1
        self._channels[channel_id] = channel = Channel(id=channel_id, topic=topic, message_encoding=message_encoding,
                                                       schema_id=schema_id, metadata={})
        self._stats.channel_count += 1
        self._add_to_chunk(channel)
        return channel_id

    def add_message(self, channel_id: int, log_time: int, data: bytes, publish_time: int, sequence: int = 0) -> None:
        stats = self._stats
        if stats.message_count == 0 or log_time < stats.message_start_time:
            stats.message_start_time = log_time
        if log_time > stats.message_end_time:
            stats.message_end_time = log_time
        stats.channel_message_counts[channel_id] += 1
        stats.message_count += 1
        if self._chunk_messages == 0 or log_time < self._chunk_start:
            self._chunk_start = log_time
        if log_time > self._chunk_end:
            self._chunk_end = log_time
        self._chunk_messages += 1
        chunk = self._chunk
        index = self._indexes.get(channel_id)
        if index is None:
            index = self._indexes[channel_id] = []
        index += (log_time, len(chunk))
        chunk += _MESSAGE.pack(Opcode.MESSAGE, 22 + len(data), channel_id, sequence, log_time, publish_time)
        chunk += data
        if len(chunk) > self._chunk_size:
            self._close_chunk(compress_on_thread=True)

    # ---- chunks ----
    def _close_chunk(self, compress_on_thread: bool = False) -> None:
        """The chunk in progress (if it has messages) compressed, on the worker thread when asked (written by the
        next record written, or by flush or finish), else at once."""
        if not self._chunk_messages:
            return
        if self._finished is not None:
            self._write_finished()
        if compress_on_thread and self._pool is None:
            self._pool = ThreadPoolExecutor(max_workers=1, thread_name_prefix="mcap-zstd")
        self._stats.chunk_count += 1
        self._finished = _Finished(bytes(self._chunk), self._chunk_start, self._chunk_end, self._indexes,
                                   self._pool if compress_on_thread else None)
        self._chunk = bytearray()
        self._chunk_messages = 0
        self._chunk_start = self._chunk_end = 0
        self._indexes = {}
        if not compress_on_thread:
            self._write_finished()

    def _write_finished(self) -> None:
        """The closed chunk's Chunk record, then its MessageIndex records, as mcap.Writer writes them."""
        done, self._finished = self._finished, None
        assert done is not None
        compressed, crc = done.compressed if isinstance(done.compressed, tuple) else done.compressed.result()
        chunk = Chunk(compression="zstd", data=compressed, message_start_time=done.start_ns,
                      message_end_time=done.end_ns, uncompressed_crc=crc, uncompressed_size=done.size)
        self._flush_records()
        chunk_offset = self._stream.tell()
        chunk.write(self._records)
        index = ChunkIndex(message_start_time=done.start_ns, message_end_time=done.end_ns,
                           chunk_start_offset=chunk_offset, chunk_length=self._records.count,
                           message_index_offsets={}, message_index_length=0, compression="zstd",
                           compressed_size=len(compressed), uncompressed_size=done.size)
        self._flush_records()
        index_offset = self._stream.tell()
        parts = []
        length = 0
        for channel_id, entries in done.indexes.items():
            index.message_index_offsets[channel_id] = index_offset + length
            n = len(entries)
            part = _MESSAGE_INDEX.pack(Opcode.MESSAGE_INDEX, 6 + 8 * n, channel_id, 8 * n) + \
                struct.pack(f"<{n}Q", *entries)
            parts.append(part)
            length += len(part)
        index.message_index_length = length
        if parts:
            self._stream.write(b"".join(parts))
        rb = RecordBuilder()
        index.write(rb)
        self._chunk_indexes += rb.end()

    def flush(self) -> None:
        """The chunk in progress closed and everything written to the stream, which is then flushed."""
        self._close_chunk()
        self._flush_records()
        self._stream.flush()

    def close_pool(self) -> None:
        """Stop the worker thread (finish does; a writer given up without finish should)."""
        if self._pool is not None:
            self._pool.shutdown(wait=True)
            self._pool = None

    def __enter__(self) -> McapWriter:
        return self

    def __exit__(self, kind: type[BaseException] | None, error: BaseException | None,
                 tb: TracebackType | None) -> None:
        """The file finished when the block ends normally; on an error only the worker thread stopped (the stream
        then holds what was written: `slipdaq recover` reads it)."""
        if kind is None:
            self.finish()
        else:
            self.close_pool()

    # ---- the end ----
    def finish(self) -> None:
        """DataEnd, the summary and the footer (the stream is left open)."""
        self._close_chunk()
        if self._finished is not None:
            self._write_finished()
        self.close_pool()
        DataEnd(0).write(self._records)
        self._flush_records()
        start = self._stream.tell()
        b = RecordBuilder()
        offsets: list[SummaryOffset] = []

        def group(opcode: Opcode, records: list[Any] | bytearray) -> None:
            first = b.count
            if isinstance(records, bytearray):  # already serialized
                b.write(records)
            for r in records if isinstance(records, list) else ():
                r.write(b)
            offsets.append(SummaryOffset(group_opcode=opcode, group_start=start + first, group_length=b.count - first))

        group(Opcode.SCHEMA, list(self._schemas.values()))
        group(Opcode.CHANNEL, list(self._channels.values()))
        group(Opcode.STATISTICS, [self._stats])
        group(Opcode.CHUNK_INDEX, self._chunk_indexes)
        group(Opcode.ATTACHMENT_INDEX, [])
        group(Opcode.METADATA_INDEX, self._metadata_indexes)
        offset_start = start + b.count
        for o in offsets:
            o.write(b)
        summary = b.end()
        crc = zlib.crc32(struct.pack("<BQQQ", Opcode.FOOTER, 20, start if summary else 0, offset_start),
                         zlib.crc32(summary))
        self._stream.write(summary)
        Footer(summary_start=start if summary else 0, summary_offset_start=offset_start,
               summary_crc=crc).write(self._records)
        self._flush_records()
        self._stream.write(MAGIC)
