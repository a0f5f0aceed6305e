"""Reading MCAP logs that were never finished, and rewriting them (or a rotated run's segments) as one finished file.

A live log is a complete MCAP file after every commit (sinks.durable), so a daemon killed with SIGKILL leaves a file
every MCAP reader opens. Killed in the middle of a commit, or after a power loss, its tail may be torn: a record cut
short, zeros, garbage. scan() reads such a file record by record, as far as the records are whole and their chunks
check out (CRC, decompression), and stops at the first one that does not: everything before it is kept, which is
everything up to the last complete chunk. recover() writes what scan() read into a new, finished file (summary,
indexes, statistics), joining several inputs (the segments of a rotated run) in order.
"""

from __future__ import annotations

import io
import json
import struct
from collections.abc import Iterator, Sequence
from dataclasses import dataclass, field
from pathlib import Path

from mcap.data_stream import ReadDataStream
from mcap.opcode import Opcode
from mcap.records import Channel, Chunk, DataEnd, Footer, Header, Message, Metadata, Schema
from mcap.stream_reader import breakup_chunk
from mcap.writer import CompressionType, Writer

from slipdaq.outputs import atomic_output
from slipdaq.sources.read_errors import InputError

MAGIC = b"\x89MCAP0\r\n"
_KNOWN = {int(o) for o in Opcode}
_MAX_RECORD = 1 << 31
"""A record longer than this (2 GiB) is garbage, not data: slipdaq's chunks are about a megabyte."""


class LogError(InputError):
    """A file that is not a readable slipdaq log (also slipdaq.sources.mcap_log.LogError)."""


class RecoverError(LogError):
    """The inputs cannot be recovered or joined (not MCAP, different runs)."""


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
                    res.last_log_time_ns = item[1].log_time  # type: ignore[index]
                elif kind == "footer":
                    res.finished = True
                    res.has_summary = item.summary_start != 0  # type: ignore[attr-defined]
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
            channel, message = item  # type: ignore[misc]
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
    return out  # type: ignore[return-value]


@dataclass
class RecoverReport:
    inputs: list[ScanResult]
    output: Path
    messages: int
    topics: dict[str, int]


def recover(inputs: Sequence[str | Path], output: str | Path, metadata_name: str = "slipdaq") -> RecoverReport:
    """Everything readable of `inputs` (in order) into one finished MCAP file `output`.

    Channels are matched by topic; the first input's metadata is kept (with `recovered_from` added to the slipdaq
    record), and a later input's longer list of CAN channels (can_channels) too. Inputs of different runs (a
    different config) are refused, and so is an output that is one of the inputs (OutputError); the output is in
    place only once it is complete (outputs.atomic_output)."""
    if not inputs:
        raise RecoverError("no input")
    out = Path(output)
    first_meta: dict[str, str] | None = None
    for p in inputs:  # check them all before writing anything
        metas = {m.name: m.metadata for m in scan_metadata(p)}
        meta = metas.get(metadata_name)
        if meta is None:
            raise RecoverError(f"{p}: no '{metadata_name}' metadata: not a slipdaq log (or torn before it)")
        if first_meta is None:
            first_meta = meta
        elif meta.get("config_toml") != first_meta.get("config_toml") or meta.get("dbc") != first_meta.get("dbc"):
            raise RecoverError(f"{p}: recorded with another config than {inputs[0]}: not segments of one run")
    results: list[ScanResult] = []
    topics: dict[str, int] = {}
    total = 0
    with atomic_output(output, inputs=inputs) as tmp, open(tmp, "wb") as f:
        writer = Writer(f, compression=CompressionType.ZSTD)
        writer.start(profile=metadata_name, library="slipdaq recover")
        schema_ids: dict[tuple[str, str, bytes], int] = {}
        channels: str | None = None  # the can_channels of the last slipdaq record written
        channel_ids: dict[tuple[str, str], int] = {}
        for n, p in enumerate(inputs):
            res = ScanResult(Path(p))
            local_schema: dict[int, int] = {}
            local_channel: dict[int, int] = {}
            for kind, item in scan(p, res):
                if kind == "schema":
                    s: Schema = item  # type: ignore[assignment]
                    key = (s.name, s.encoding, bytes(s.data))
                    if key not in schema_ids:
                        schema_ids[key] = writer.register_schema(s.name, s.encoding, s.data)
                    local_schema[s.id] = schema_ids[key]
                elif kind == "channel":
                    c: Channel = item  # type: ignore[assignment]
                    ckey = (c.topic, c.message_encoding)
                    if ckey not in channel_ids:
                        channel_ids[ckey] = writer.register_channel(
                            c.topic, c.message_encoding, local_schema.get(c.schema_id, 0), dict(c.metadata))
                    local_channel[c.id] = channel_ids[ckey]
                elif kind == "metadata":
                    m: Metadata = item  # type: ignore[assignment]
                    data = dict(m.metadata)
                    if m.name == metadata_name:
                        if n and data.get("can_channels") == channels:
                            continue
                        if n:  # a later segment's longer list of CAN channels: the first's record with it
                            data = dict(first_meta or {}) | {"can_channels": data.get("can_channels", "")}
                        channels = data.get("can_channels")
                        data["recovered_from"] = json.dumps([str(Path(i).name) for i in inputs])
                    elif n:
                        continue
                    writer.add_metadata(m.name, data)
                elif kind == "message":
                    channel: Channel
                    msg: Message
                    channel, msg = item  # type: ignore[misc]
                    writer.add_message(local_channel[channel.id], log_time=msg.log_time, data=msg.data,
                                       publish_time=msg.publish_time, sequence=msg.sequence)
                    topics[channel.topic] = topics.get(channel.topic, 0) + 1
                    total += 1
            results.append(res)
        writer.finish()
    return RecoverReport(results, out, total, topics)
