"""Reading MCAP logs that were never finished, record by record.

A live log is a complete MCAP file after every commit (logformat.durable), so a daemon killed with SIGKILL leaves a
file every MCAP reader opens. Killed in the middle of a commit, or after a power loss, its tail may be torn: a record
cut short, zeros, garbage. scan() reads such a file record by record, as far as the records are whole and their
chunks check out (CRC, decompression), and stops at the first one that does not: everything before it is kept, which
is everything up to the last complete chunk.
"""

from __future__ import annotations

import io
import struct
from collections.abc import Iterator, Sequence
from dataclasses import dataclass, field
from pathlib import Path

from mcap.data_stream import ReadDataStream
from mcap.opcode import Opcode
from mcap.records import Channel, Chunk, DataEnd, Footer, Header, Message, Metadata, Schema
from mcap.stream_reader import breakup_chunk

from slipdaq.logformat.errors import LogError

MAGIC = b"\x89MCAP0\r\n"
_KNOWN = {int(o) for o in Opcode}
_MAX_RECORD = 1 << 31
"""A record longer than this (2 GiB) is garbage, not data: slipdaq's chunks are about a megabyte."""


@dataclass
class ScanResult:
    """How far a scan got."""

    path: Path
    size_bytes: int = 0
    read_bytes: int = 0
    """Bytes of whole, valid records from the start of the file (the rest was not used)."""
    finished: bool = False
    """The file ends with a footer (a provisional one counts: the daemon's file after a commit)."""
    has_summary: bool = False
    """The footer points to a summary section: the file was closed properly."""
    messages: int = 0
    stopped_because: str = ""
    """Why reading stopped before the end of the file ('' when it read to the footer)."""
    last_log_time_ns: int | None = None

    @property
    def complete(self) -> bool:
        return self.finished and not self.stopped_because


@dataclass
class _State:
    schemas: dict[int, Schema] = field(default_factory=dict)
    channels: dict[int, Channel] = field(default_factory=dict)


Item = tuple[str, object]
"""('schema', Schema) | ('channel', Channel) | ('metadata', Metadata) | ('message', (Channel, Message))"""


def scan(path: str | Path, result: ScanResult | None = None) -> Iterator[Item]:
    """The records of an MCAP file in file order, up to the first one that is not whole and valid.

    Fills `result` (when given) as it goes. Raises LogError only when the file does not even start like MCAP."""
    p = Path(path)
    res = result if result is not None else ScanResult(p)
    res.path = p
    try:
        f = open(p, "rb")
    except OSError as e:
        raise LogError(f"{p}: cannot read: {e.strerror}") from None
    with f:
        f.seek(0, io.SEEK_END)
        res.size_bytes = size = f.tell()
        f.seek(0)
        if f.read(len(MAGIC)) != MAGIC:
            raise LogError(f"{p}: not an MCAP file (no MCAP magic at the start)")
        pos = len(MAGIC)
        res.read_bytes = pos
        state = _State()
        while True:
            head = f.read(9)
            if len(head) < 9:
                res.stopped_because = (f"the file ends at byte {pos} without a footer: not finished" if not head
                                       else f"the file ends inside a record at byte {pos}")
                return
            opcode, length = struct.unpack("<BQ", head)
            if opcode not in _KNOWN or length > _MAX_RECORD:
                res.stopped_because = f"no valid record at byte {pos} (opcode {opcode:#04x}): torn or overwritten"
                return
            if pos + 9 + length > size:
                res.stopped_because = (f"record at byte {pos} ({Opcode(opcode).name}, {length} bytes) is cut short "
                                       f"by the end of the file ({size} bytes)")
                return
            body = f.read(length)
            try:
                items = list(_decode(opcode, body, state))
            except Exception as e:  # corrupt content: CRC, zstd, field lengths
                res.stopped_because = f"record at byte {pos} ({Opcode(opcode).name}) does not decode: {e}"
                return
            pos += 9 + length
            res.read_bytes = pos
            for kind, item in items:
                if kind == "message":
                    res.messages += 1
                    res.last_log_time_ns = item[1].log_time  # type: ignore[index]  # a 'message' item is (Channel, Message)
                elif kind == "footer":
                    res.finished = True
                    res.has_summary = item.summary_start != 0  # type: ignore[attr-defined]  # a Footer, by its opcode
                    res.read_bytes = size if f.read(len(MAGIC)) == MAGIC else pos
                    return
                if kind != "footer":
                    yield kind, item


def _decode(opcode: int, body: bytes, state: _State) -> Iterator[Item]:
    stream = ReadDataStream(io.BytesIO(body))
    if opcode == Opcode.HEADER:
        Header.read(stream)
    elif opcode == Opcode.SCHEMA:
        yield from _record(Schema.read(stream), state)
    elif opcode == Opcode.CHANNEL:
        yield from _record(Channel.read(stream), state)
    elif opcode == Opcode.MESSAGE:
        yield from _record(Message.read(stream, len(body)), state)
    elif opcode == Opcode.CHUNK:
        records = breakup_chunk(Chunk.read(stream), validate_crc=True)
        out: list[Item] = []
        for r in records:  # the whole chunk or nothing
            out.extend(_record(r, state))
        yield from out
    elif opcode == Opcode.METADATA:
        yield "metadata", Metadata.read(stream)
    elif opcode == Opcode.DATA_END:
        DataEnd.read(stream)
    elif opcode == Opcode.FOOTER:
        yield "footer", Footer.read(stream)
    # indexes, statistics, summary offsets, attachments: not needed to read the data


def _record(r: object, state: _State) -> Iterator[Item]:
    if isinstance(r, Schema):
        state.schemas[r.id] = r
        yield "schema", r
    elif isinstance(r, Channel):
        state.channels[r.id] = r
        yield "channel", r
    elif isinstance(r, Message):
        channel = state.channels.get(r.channel_id)
        if channel is None:
            raise ValueError(f"message on unknown channel {r.channel_id}")
        yield "message", (channel, r)


def scan_messages(
    path: str | Path, topics: Sequence[str] | None = None, result: ScanResult | None = None
) -> Iterator[tuple[Channel, Message]]:
    for kind, item in scan(path, result):
        if kind == "message":
            channel: Channel
            message: Message
            channel, message = item  # type: ignore[misc]  # a 'message' item is (Channel, Message)
            if topics is None or channel.topic in topics:
                yield channel, message


def scan_metadata(path: str | Path) -> list[Metadata]:
    """The metadata records (they come before the first chunk in slipdaq's logs)."""
    out = []
    for kind, item in scan(path):
        if kind == "metadata":
            out.append(item)
        elif kind == "message":
            break
    return out  # type: ignore[return-value]  # only 'metadata' items are kept
