"""A chunk's records, with the messages of topics not read passed over: each such message only as its channel and
log time (what a scan counts), not as an mcap.records.Message.

mcap's breakup_chunk makes a Message of every record; a slipdaq log holds about three derived messages for each raw
one, and a replay reads only the raw ones: making the others took more time than reading the raw ones
(docs/performance.md, "Reading the log"). The records' layout is MCAP's (spec v0: a record is an opcode byte and a
uint64 length; a message's body starts with channel id u16, sequence u32, log time u64 and publish time u64); the
chunk is decompressed and checked by mcap's get_chunk_data_stream, schema and channel records are read with mcap's
own record classes. A record that runs past the chunk's end is an error here (breakup_chunk returns its message cut
short). tests/logformat/test_chunk_read.py holds it to breakup_chunk, chunk by chunk.
"""

from __future__ import annotations

import io
import struct
from collections.abc import Callable, Collection
from typing import Any

from mcap.data_stream import ReadDataStream
from mcap.exceptions import McapError
from mcap.opcode import Opcode
from mcap.records import Channel, Chunk, Message, Schema
from mcap.stream_reader import get_chunk_data_stream

_HEAD = struct.Struct("<BQ")
_MESSAGE_HEAD = struct.Struct("<HIQQ")
"""A message record's fixed fields: channel id, sequence, log time, publish time."""


def chunk_messages(
    chunk: Chunk, topics: Collection[str] | None = None, topic_of: Callable[[int], str | None] = lambda _: None
) -> list[Schema | Channel | Message | tuple[int, int]]:
    """The chunk's schema, channel and message records in order; with topics, a message whose channel's topic
    (defined earlier in the chunk, else topic_of(channel id)) is not in them as its (channel id, log time), and a
    channel topic_of does not know (None): its messages as Message. Raises CRCValidationError on a chunk that fails
    its CRC, McapError on records that do not fit it."""
    stream, size = get_chunk_data_stream(chunk, validate_crc=True)
    data = stream.read(size)
    out: list[Schema | Channel | Message | tuple[int, int]] = []
    read: dict[int, bool] = {}
    """By channel id: its messages are made into Message records (a channel defined in the chunk: by its topic)."""
    head, message_head = _HEAD.unpack_from, _MESSAGE_HEAD.unpack_from
    pos = 0
    while pos < size:
        if pos + 9 > size:
            raise McapError(f"a record header cut short at byte {pos} of the chunk")
        opcode, length = head(data, pos)
        start, end = pos + 9, pos + 9 + length
        if end > size:
            raise McapError(f"a record of {length} bytes at byte {pos} runs past the chunk's end ({size})")
        if opcode == Opcode.MESSAGE:
            if length < _MESSAGE_HEAD.size:
                raise McapError(f"a message record of {length} bytes at byte {pos} of the chunk")
            channel_id, sequence, log_time, publish_time = message_head(data, start)
            keep = read.get(channel_id)
            if keep is None:
                topic = topic_of(channel_id)
                keep = read[channel_id] = topics is None or topic is None or topic in topics
            if not keep:
                out.append((channel_id, log_time))
            else:
                out.append(Message(channel_id=channel_id, sequence=sequence, log_time=log_time,
                                   publish_time=publish_time, data=data[start + _MESSAGE_HEAD.size:end]))
        elif opcode in (Opcode.CHANNEL, Opcode.SCHEMA):
            record: Any = (Channel if opcode == Opcode.CHANNEL else Schema).read(
                ReadDataStream(io.BytesIO(data[start:end])))
            if isinstance(record, Channel):
                read[record.id] = topics is None or record.topic in topics
            out.append(record)
        pos = end
    return out
