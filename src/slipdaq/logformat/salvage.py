"""Reading MCAP logs record by record: logs that were never finished, and logs with damage inside.

A live log is a complete MCAP file after every commit (logformat.durable), so a daemon killed with SIGKILL leaves a
file every MCAP reader opens. Killed in the middle of a commit, or after a power loss, its tail may be torn: a record
cut short, zeros, garbage. A flash card may also flip bits anywhere in it. scan() reads such a file record by
record (logformat.damage: each record parsed and checked, each chunk against its CRC) from its start to its data
end, and goes past damage: a chunk that fails is skipped (its extent is in its header), bytes that are no record
are skipped up to the next record that parses (resynchronisation). Damage that nothing valid follows is a torn tail:
reading stops there. What was skipped is in ScanResult.damaged, with what the file says it held (its message
index, or the summary of a finished file).

The readers (logformat.reader) scan strictly: a torn tail ends the data (the file was not finished); damage before
valid data that lost something raises DamageError naming it, once the whole file is scanned (what was read is
yielded first); `slipdaq recover` scans with skip_damage and writes everything else.
"""

from __future__ import annotations

import contextlib
import os
import struct
import zlib
from collections.abc import Collection, Iterator, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, BinaryIO

from mcap.opcode import Opcode
from mcap.reader import make_reader
from mcap.records import Channel, Chunk, DataEnd, Footer, Message, MessageIndex, Metadata, Schema

from slipdaq.logformat.damage import (
    MAGIC,
    BadRecord,
    Damage,
    FileBytes,
    chunk_at,
    chunk_records,
    damaged_chunk_indexes,
    definitions,
    index_records,
    kind_of,
    parse_record,
    range_text,
    resync,
    time_text,
)
from slipdaq.logformat.errors import LogError

_FOOTER_BYTES = 9 + 8 + 8 + 4


class DamageError(LogError):
    """A log with damage before data that is whole: reading it through would skip what the damage held."""


@dataclass
class ScanResult:
    """How far a scan got, and what it could not read."""

    path: Path
    size_bytes: int = 0
    read_bytes: int = 0
    """The end of the last whole, valid record read (the file's size once its footer is read)."""
    finished: bool = False
    """The file ends with a footer (a provisional one counts: the daemon's file after a commit)."""
    has_summary: bool = False
    """The footer points to a summary section: the file was closed properly."""
    messages: int = 0
    stopped_because: str = ""
    """Why reading stopped before the end of the file ('' when it read to the footer)."""
    last_log_time_ns: int | None = None
    damaged: list[Damage] = field(default_factory=list)
    """The byte ranges that could not be read, in file order (a torn tail last)."""
    orphans: int = 0
    """Messages on channels whose definition was in a damaged range (and not in the summary): not read."""
    topics: dict[str, int] = field(default_factory=dict)
    """Messages in the data read, by topic (those of topics a scan passes over included)."""
    expected: dict[str, int] | None = None
    """Messages by topic as the file's statistics count them (a finished file with a sound summary)."""
    summary_damaged: str = ""
    """What is wrong with the summary section of a finished file (its data was read without it)."""

    @property
    def complete(self) -> bool:
        return self.finished and not self.stopped_because and not self.damaged and not self.orphans

    @property
    def lossy(self) -> bool:
        """Messages (or records that may have held some) could not be read."""
        return bool(self.orphans) or any(d.loses_data for d in self.damaged)

    @property
    def torn_at(self) -> int | None:
        tail = [d for d in self.damaged if d.tail]
        return tail[0].start if tail else (self.read_bytes if self.stopped_because else None)


Item = tuple[str, Any]
"""('schema', Schema) | ('channel', Channel) | ('metadata', Metadata) | ('message', (Channel, Message))"""

_UNREAD = object()


class _Scan:
    def __init__(self, path: Path, buf: FileBytes, res: ScanResult, skip: bool, topics: Collection[str] | None) -> None:
        self.path, self.buf, self.size, self.res, self.skip = path, buf, buf.size, res, skip
        self.topics = topics
        """The topics whose messages are read (None: all); the others are counted and passed over."""
        self.schemas: dict[int, Schema] = {}
        self.channels: dict[int, Channel] = {}
        self._summary: Any = _UNREAD
        self.waiting: list[Damage] = []
        """Damage whose first message after it is still to come."""
        self.owner: Damage | None = None
        """The damage the message index records being read may belong to."""
        self.prev_times: dict[int, list[int]] = {}
        """The log times of the last whole chunk's messages, by channel (its own message index records match)."""
        self.last_ns: int | None = None
        self.no_magic = False

    def summary(self) -> Any:
        """The summary of a finished file (mcap's reader) when it checks out against its CRC, else None."""
        if self._summary is _UNREAD:
            self._summary = None
            if self.size >= 2 * len(MAGIC) and self.buf[self.size - len(MAGIC):] == MAGIC:
                with contextlib.suppress(Exception), open(self.path, "rb") as f:
                    summary = make_reader(f).get_summary()
                    self._summary = summary if summary_intact(f) else None
        return self._summary

    def known(self, channel_id: int) -> bool:
        return channel_id in self.channels or channel_id in definitions(self.summary())[1]

    def topic_of(self, channel_id: int) -> str | None:
        """A channel's topic as the records read so far define it (None: not yet, or lost in damage)."""
        c = self.channels.get(channel_id)
        return c.topic if c is not None else None

    def topic(self, channel_id: int) -> str:
        c = self.channels.get(channel_id) or definitions(self.summary())[1].get(channel_id)
        return c.topic if c is not None else f"(channel {channel_id})"

    def run(self) -> Iterator[Item]:
        res, buf, size = self.res, self.buf, self.size
        pos: int | None = len(MAGIC)
        if buf[:len(MAGIC)] != MAGIC:
            pos = resync(buf, 0, size, self.known)
            if pos is None:
                raise LogError(f"{self.path}: not an MCAP file (no MCAP magic at the start)")
            res.damaged.append(Damage(0, pos, "no MCAP magic at the start", holds_messages=pos > 8 and None))
            self.no_magic = True  # no other MCAP tool opens it: a strict scan names the damage and recover
        res.read_bytes = pos or 0
        while pos is not None:
            if pos >= size:
                res.stopped_because = f"the file ends at byte {pos} without a footer: not finished"
                break
            try:
                record, end = parse_record(buf, pos, size, index_entries=self.owner is not None)
                items = self.decode(record, pos, end)
            except BadRecord as e:
                reread = self.reread(e)
                if reread is None:
                    pos = self.bad(e)
                    continue
                record, end, items = reread
            res.read_bytes = end
            if isinstance(record, DataEnd):
                self.data_end(end)
                break
            if isinstance(record, Footer):  # a footer without a data end before it
                res.finished, res.has_summary = True, record.summary_start != 0
                break
            yield from items
            pos = end
        self.settle()
        if not self.skip and (self.no_magic or res.orphans or any(d.loses_data and not d.tail for d in res.damaged)):
            raise DamageError(reader_error(self.path, res))

    def decode(self, record: Any, pos: int, end: int) -> list[Item]:
        if isinstance(record, MessageIndex):
            self.index(record)
            return []
        self.owner = None
        if isinstance(record, Chunk):
            return self.chunk_items(chunk_records(record, pos, end, self.topics, self.topic_of))
        if isinstance(record, Message) and not self.known(record.channel_id):
            raise BadRecord(pos, f"a message on channel {record.channel_id}, which the file does not define",
                            Opcode.MESSAGE, end)
        if isinstance(record, (Schema, Channel, Message)):
            return self.item(record)
        if isinstance(record, Metadata):
            return [("metadata", record)]
        return []  # header, indexes, statistics, attachments: not needed to read the data

    def chunk_items(self, records: list[Any]) -> list[Item]:
        items: list[Item] = []
        times: dict[int, list[int]] = {}
        counts: dict[int, int] = {}
        first = last = top = -1
        for r in records:
            if type(r) is tuple:  # chunk_read's (channel id, log time) of a message passed over
                channel_id, t = r
                times.setdefault(channel_id, []).append(t)
            elif isinstance(r, Message):
                channel_id, t = r.channel_id, r.log_time
                times.setdefault(channel_id, []).append(t)
                got = self.message_items(r)
                if got is None:
                    continue  # an orphan: not counted
                items.extend(got)
            else:
                items.extend(self.item(r))
                continue
            counts[channel_id] = counts.get(channel_id, 0) + 1
            if first < 0:
                first = t
            last = t
            top = max(top, t)
        if counts:
            self.note(counts, first, last, top)
        self.prev_times = times
        return items

    def reread(self, e: BadRecord) -> tuple[Chunk, int, list[Item]] | None:
        """A chunk whose record header is damaged (opcode, length) but whose content checks out: read through the
        summary's chunk index at its offset, or its header's own length. Listed as damage that lost nothing."""
        ends = [e.pos + c.chunk_length for c in getattr(self.summary(), "chunk_indexes", None) or []
                if c.chunk_start_offset == e.pos and e.pos + c.chunk_length != e.end]
        if e.chunk is None and len(head := self.buf[e.pos:e.pos + 9]) == 9:  # else the header's extent was tried
            ends.append(e.pos + 9 + struct.unpack("<BQ", head)[1])
        for end in ends:
            if e.pos + 9 < end <= self.size and (found := chunk_at(self.buf, e.pos, end)) is not None:
                self.owner = None
                self.res.damaged.append(Damage(e.pos, e.pos + 9, f"{' '.join(e.why.split())}: the chunk it starts "
                                               "was read all the same (its extent from the "
                                               f"{'header' if e.chunk is None and end == ends[-1] else 'summary'}, its "
                                               "CRC checks out)",
                                               e.opcode, holds_messages=False))
                return found[0], end, self.chunk_items(found[1])
        return None

    def item(self, r: Any) -> list[Item]:
        if isinstance(r, Schema):
            self.schemas[r.id] = r
            return [("schema", r)]
        if isinstance(r, Channel):
            self.channels[r.id] = r
            return [("channel", r)]
        if not isinstance(r, Message):
            return []
        out = self.message_items(r)
        if out is None:
            return []
        self.note({r.channel_id: 1}, r.log_time, r.log_time, r.log_time)
        return out

    def message_items(self, r: Message) -> list[Item] | None:
        """A message's item (unless its topic is passed over), after its channel's and schema's where only the
        summary defines them; None for an orphan (counted in res.orphans)."""
        out: list[Item] = []
        channel = self.channels.get(r.channel_id)
        if channel is None:  # its definition was in a damaged range: the summary's, when there is one
            schemas, channels = definitions(self.summary())
            channel = channels.get(r.channel_id)
            if channel is None:
                self.res.orphans += 1
                return None
            schema = schemas.get(channel.schema_id)
            if schema is not None and schema.id not in self.schemas:
                out.extend(self.item(schema))
            out.extend(self.item(channel))
        if self.topics is None or channel.topic in self.topics:
            out.append(("message", (channel, r)))
        return out

    def index(self, record: MessageIndex) -> None:
        """A message index record after damage: what the damaged chunk held (unless it is the last whole chunk's)."""
        d = self.owner
        if d is None or self.prev_times.get(record.channel_id) == [t for t, _ in record.records]:
            return
        d.count(record, self.topic(record.channel_id), "message index")

    def bad(self, e: BadRecord) -> int | None:
        """Damage at e.pos: where reading goes on (None: nothing valid follows, the file is torn there)."""
        next_ok = e.end is not None and e.end < self.size and _parses(self.buf, e.end, self.size)
        nxt = e.end if next_ok else resync(self.buf, e.pos + 1, self.size, self.known)
        why = " ".join(e.why.split())
        d = Damage(e.pos, self.size if nxt is None else nxt, why, e.opcode, tail=nxt is None,
                   holds_messages=kind_of(e, next_ok), before_ns=self.last_ns)
        if e.chunk is not None:
            d.header_times = (e.chunk.message_start_time, e.chunk.message_end_time)
        elif e.opcode == Opcode.CHUNK and len(head := self.buf[e.pos + 9:e.pos + 25]) == 16:
            d.header_times = struct.unpack("<QQ", head)  # a chunk cut short: its header's first fields
        self.res.damaged.append(d)
        self.waiting.append(d)
        self.owner = d
        if d.tail:
            self.res.stopped_because = f"at byte {e.pos}: {why}; nothing valid follows: torn from there"
        return nxt

    def note(self, counts: dict[int, int], first_ns: int, last_ns: int, top_ns: int) -> None:
        """Messages read or passed over, by channel, in a run of the file (a chunk): the first's, the last's and the
        latest log time."""
        res = self.res
        for channel_id, n in counts.items():
            topic = self.channels[channel_id].topic
            res.topics[topic] = res.topics.get(topic, 0) + n
            res.messages += n
        res.last_log_time_ns = last_ns
        for d in self.waiting:
            d.after_ns = first_ns
        self.waiting.clear()
        self.last_ns = top_ns if self.last_ns is None else max(self.last_ns, top_ns)

    def data_end(self, end: int) -> None:
        """After the data: the summary and footer of a finished file, or a live file's provisional footer."""
        res, buf, size = self.res, self.buf, self.size
        at = size - len(MAGIC) - _FOOTER_BYTES
        if at >= end and buf[size - len(MAGIC):] == MAGIC:
            try:
                footer, footer_end = parse_record(buf, at, size)
            except BadRecord:
                footer, footer_end = None, 0
            if isinstance(footer, Footer) and footer_end == size - len(MAGIC):
                res.finished, res.has_summary, res.read_bytes = True, footer.summary_start != 0, size
                if res.has_summary:
                    res.summary_damaged = _summary_problem(buf, footer, at, end)
                return
        res.stopped_because = (f"the data ends at byte {end}, but no footer ends the file after it: cut or damaged "
                               "after its data")

    def settle(self) -> None:
        """What each damaged range held and when, from the summary where the scan did not learn it."""
        res = self.res
        summary = self.summary() if res.has_summary or any(d.loses_data for d in res.damaged) else None
        if summary is not None and summary.statistics is not None and (self.skip or res.damaged):
            expected: dict[str, int] = {}
            for cid, n in summary.statistics.channel_message_counts.items():
                expected[self.topic(cid)] = expected.get(self.topic(cid), 0) + n
            res.expected = expected
        for d in res.damaged:
            chunk_times = None
            if summary is not None and summary.chunk_indexes:
                chunks = damaged_chunk_indexes(summary, d)
                if not chunks and d.holds_messages is None:
                    d.holds_messages = False
                if chunks and d.holds_messages is not False:  # False: known to have lost nothing
                    d.holds_messages = True
                    chunk_times = (min(c.message_start_time for c in chunks), max(c.message_end_time for c in chunks))
                    _count_from_summary(d, chunks, self)
            d.settle_times(chunk_times)


def _parses(buf: FileBytes, at: int, size: int) -> bool:
    try:
        parse_record(buf, at, size)
    except BadRecord:
        return False
    return True


def _count_from_summary(d: Damage, chunks: list[Any], scan: _Scan) -> None:
    """The lost messages by topic from the message index records the summary's chunk indexes point to (when every
    one of them reads: a range over several chunks is then counted whole)."""
    offsets = [off for c in chunks for off in c.message_index_offsets.values()]
    records = index_records(scan.buf, scan.size, offsets)
    if len(records) != len(offsets) or (d.counted_by and len(chunks) == 1):
        return
    d.lost.clear()
    d.index_times = None
    for r in records:
        d.count(r, scan.topic(r.channel_id), "message index (through the summary's chunk index)")


def _summary_problem(buf: FileBytes, footer: Footer, footer_at: int, data_end: int) -> str:
    start = footer.summary_start
    if not data_end <= start <= footer_at:
        return f"its footer points to byte {start}, outside the summary section (bytes {data_end}-{footer_at})"
    if footer.summary_crc and zlib.crc32(buf[start:footer_at + 9 + 16]) != footer.summary_crc:
        return f"its summary (bytes {start}-{footer_at}: indexes, statistics) fails its CRC check"
    return ""


def summary_intact(f: BinaryIO) -> bool:
    """The summary section of an open MCAP file matches its footer's CRC (True when the footer gives none)."""
    f.seek(0, os.SEEK_END)
    size = f.tell()
    at = size - len(MAGIC) - _FOOTER_BYTES
    if at < len(MAGIC):
        return False
    f.seek(at)
    opcode, _length, start, _offsets, crc = struct.unpack("<BQQQI", f.read(_FOOTER_BYTES))
    if not crc:
        return True
    if not len(MAGIC) <= start <= at:
        return False
    f.seek(start)
    return zlib.crc32(f.read(at + 9 + 16 - start)) == crc


def reader_error(path: str | Path, res: ScanResult) -> str:
    """One line: where a log is damaged (and torn), and the command that writes everything else."""
    inner = [d for d in res.damaged if not d.tail]
    parts = [f"{range_text(d)}, {time_text(d)}" for d in [d for d in inner if d.loses_data] or inner]
    text = f"damaged at {'; '.join(parts)}" if parts else "damaged"
    if res.orphans:
        text += f"; {res.orphans} messages on channels whose definition is lost"
    if res.stopped_because:
        text += f"; and not finished: torn at byte {res.torn_at} ({res.stopped_because})"
    return (f"{path}: {text}; `slipdaq recover {path} -o FIXED.mcap` writes everything else to a finished copy and "
            "lists what is lost")


def scan(path: str | Path, result: ScanResult | None = None, *, skip_damage: bool = False,
         topics: Collection[str] | None = None) -> Iterator[Item]:
    """The records of an MCAP file in file order, up to its data end (or a torn tail); with topics, only the
    messages of those topics (the others are counted in `result` as read, but not made into records).

    Damage that valid records follow is skipped and listed in result.damaged; unless skip_damage, DamageError once
    the rest of the file is scanned, where the damage lost something (a chunk, a message, a metadata record, or
    what it held is unknown), and where the file has no MCAP magic. Fills `result` (when given) as it
    goes. Raises LogError when the file cannot be opened or does not start like MCAP (with skip_damage: when no MCAP
    record is found in it)."""
    p = Path(path)
    res = result if result is not None else ScanResult(p)
    res.path = p
    try:
        fd = os.open(p, os.O_RDONLY)
    except OSError as e:
        raise LogError(f"{p}: cannot read: {e.strerror}") from None
    try:
        res.size_bytes = os.fstat(fd).st_size
        yield from _Scan(p, FileBytes(fd, res.size_bytes), res, skip_damage, topics).run()
    finally:
        os.close(fd)


def survey(path: str | Path) -> ScanResult:
    """The whole file scanned past its damage (for the message of a reader that failed)."""
    res = ScanResult(Path(path))
    for _ in scan(path, res, skip_damage=True):
        pass
    return res


def scan_messages(
    path: str | Path, topics: Sequence[str] | None = None, result: ScanResult | None = None
) -> Iterator[tuple[Channel, Message]]:
    for kind, item in scan(path, result, topics=topics):
        if kind == "message":
            channel: Channel
            message: Message
            channel, message = item
            if topics is None or channel.topic in topics:
                yield channel, message


def scan_metadata(path: str | Path, *, skip_damage: bool = False) -> list[Metadata]:
    """The metadata records (they come before the first chunk in slipdaq's logs)."""
    out = []
    for kind, item in scan(path, skip_damage=skip_damage):
        if kind == "metadata":
            out.append(item)
        elif kind == "message":
            break
    return out
