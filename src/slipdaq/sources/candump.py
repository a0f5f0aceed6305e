"""candump -L logs (.log) read as batches of frames: the frames python-can's CanutilsLogReader gives, without a
Message per line.

Lines in the form a logger writes (`(SECONDS) CHANNEL ID#DATA [R|T]`: a named or numbered channel, a 3- or 8-digit
ID, up to 8 data bytes) are read as a table of bytes, those of one length at a time (numpy); a run of lines that do
not fit goes through a regular expression, and any line that is not in that form (CAN FD, remote and error frames,
odd spacing, damage) through python-can's reader, so every line means what python-can makes of it and a line
python-can cannot read raises what it raises there.
"""

from __future__ import annotations

import binascii
import io
import locale
import re
from collections.abc import Iterator
from pathlib import Path

import numpy as np

from slipdaq.records import FLAG_EXTENDED, FLAG_TX, CanFrameBatch

CHUNK_BYTES = 1 << 20
"""Text read and parsed at once (cut after its last whole line)."""
_PLAIN = re.compile(rb"^\((\d+\.\d+)\) ([A-Za-z][A-Za-z0-9_]*|0|[1-9][0-9]*) ([0-9A-Fa-f]{3}|[0-9A-Fa-f]{8})#"
                    rb"((?:[0-9A-Fa-f]{2}){0,8})"
                    rb"(?: ([RTrt]))?\r?\n", re.M)
_CHANNEL = re.compile(r"[A-Za-z][A-Za-z0-9_]*|0|[1-9][0-9]*")
"""A channel _PLAIN takes: a name, or a number python-can's int() gives back as written."""
_TEMPLATE_ROWS = 16
"""A length's layout is that of the first of its first lines in the form _PLAIN matches."""
_MAX_LAYOUTS = 16
"""More line lengths than this in a chunk: it is read by the regular expression."""
_HEX = np.full(256, 255, dtype=np.uint8)
_HEX[np.frombuffer(b"0123456789abcdefABCDEF", dtype=np.uint8)] = [*range(16), *range(10, 16)]
_ERROR_ID = 0x20000080
"""CAN_ERR_FLAG | CAN_ERR_BUSERROR: an ID with both bits is an error frame (python-can's rule)."""


class CandumpError(Exception):
    """A line python-can cannot read: its exception, and how many frames the file gave before it."""

    def __init__(self, error: Exception, frames_before: int) -> None:
        super().__init__(str(error))
        self.error = error
        self.frames_before = frames_before


def iter_candump(path: str | Path) -> Iterator[CanFrameBatch]:
    """The frames of a candump -L log in file order, a batch per chunk of text (none for a chunk without frames).
    Raises CandumpError for a line python-can's reader cannot read (UnicodeDecodeError for bytes that are not text
    in the encoding python-can opens it with)."""
    encoding = locale.getpreferredencoding(False)
    frames = 0
    rest = b""
    with open(path, "rb") as f:
        while True:
            block = f.read(CHUNK_BYTES)
            text = rest + block
            if block:
                cut = text.rfind(b"\n") + 1
                text, rest = text[:cut], text[cut:]
                if not text:
                    continue
            elif not text:
                return
            if not text.isascii():
                text.decode(encoding)  # python-can reads the file as text: bytes that are not text fail the same way
            batch = parse_chunk(text, encoding, frames)
            frames += len(batch)
            if len(batch):
                yield batch
            if not block:
                return


def parse_chunk(text: bytes, encoding: str = "utf-8", frames_before: int = 0) -> CanFrameBatch:
    """The frames of whole lines of a candump -L log (the last may lack its newline)."""
    got = _table(text)
    if got is None:
        return _regex_batch(text, encoding, frames_before)
    batch, ok, starts, ends = got
    if ok.all():
        return batch
    parts: list[CanFrameBatch] = []  # runs of rows read as a table, and of other lines, in file order
    frames = frames_before
    cuts = [0, *(np.flatnonzero(np.diff(ok.view(np.int8))) + 1).tolist(), len(ok)]
    for i, j in zip(cuts[:-1], cuts[1:]):
        part = batch.slice(i, j) if ok[i] else _regex_batch(text[starts[i] : ends[j - 1] + 1], encoding, frames)
        parts.append(part)
        frames += len(part)
    parts = [p for p in parts if len(p)] or parts[:1]
    return parts[0] if len(parts) == 1 else CanFrameBatch.concat(parts)


def _regex_batch(text: bytes, encoding: str, frames_before: int) -> CanFrameBatch:
    """The lines by the regular expression (and python-can for the others)."""
    lines = _PLAIN.findall(text)
    if len(lines) == text.count(b"\n") and text.endswith(b"\n"):
        batch = _plain_batch(lines)
        if batch is not None:
            return batch
    return _mixed_batch(text, encoding, frames_before)


def _table(text: bytes) -> tuple[CanFrameBatch, np.ndarray, np.ndarray, np.ndarray] | None:
    """The lines read as numpy rows, those of one length at a time, each length's layout (where each field is) taken
    from its first line in the form _PLAIN matches: (the frames, per line whether it was read so: in that layout,
    not an error frame, line starts, line ends); the others' rows hold nothing. None when the text does not end with
    a newline or has many lengths."""
    buf = np.frombuffer(text, dtype=np.uint8)
    ends = np.flatnonzero(buf == 10)
    n = len(ends)
    if n == 0 or ends[-1] != len(buf) - 1:
        return None
    starts = np.zeros(n, dtype=np.int64)
    starts[1:] = ends[:-1] + 1
    widths = ends - starts
    lengths = np.unique(widths)
    if len(lengths) > _MAX_LAYOUTS:
        return None
    t = np.zeros(n, dtype=np.float64)
    ident = np.zeros(n, dtype=np.uint32)
    flags = np.zeros(n, dtype=np.uint8)
    dlc = np.zeros(n, dtype=np.uint8)
    payload = np.zeros((n, 8), dtype=np.uint8)
    channel = np.zeros(n, dtype=np.uint16)
    ok = np.zeros(n, dtype=bool)
    names: list[str] = []
    for width in lengths.tolist():
        if len(lengths) == 1:
            which: slice | np.ndarray = slice(None)
            rows = buf.reshape(n, width + 1)
        else:
            which = np.flatnonzero(widths == width)
            rows = buf[starts[which, None] + np.arange(width + 1)]
        got = _rows(rows)
        if got is None:
            continue
        t[which], ident[which], flags[which], data, its_names, codes, ok[which] = got
        dlc[which] = data.shape[1]
        payload[which, : data.shape[1]] = data
        for name in its_names:
            if name not in names:
                names.append(name)
        channel[which] = np.array([names.index(name) for name in its_names], dtype=np.uint16)[codes]
    ok &= (ident & np.uint32(_ERROR_ID)) != _ERROR_ID
    if len(names) > 1:  # the names in order of appearance
        first = [int(np.argmax(ok & (channel == i))) if (ok & (channel == i)).any() else n for i in range(len(names))]
        order = np.argsort(first, kind="stable")
        lut = np.zeros(len(names), dtype=np.uint16)
        lut[order] = np.arange(len(names), dtype=np.uint16)
        channel, names = lut[channel], [names[i] for i in order.tolist()]
    batch = CanFrameBatch(t, ident & np.uint32(0x1FFFFFFF), flags, dlc, payload, channel, tuple(names) or (None,))
    return batch, ok, starts, ends


_Rows = tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, list[str], np.ndarray, np.ndarray]


def _rows(rows: np.ndarray) -> _Rows | None:
    """Lines of one length as rows of bytes (newline included), laid out as the first of them _PLAIN matches, or,
    when fewer than half are, as the first of the others: (stamps, raw IDs, flags, payloads, channel names, each
    row's index in them, whether the row is laid out so); None when no row near the start matches."""
    first = _first_plain(rows)
    got = None if first is None else _laid_out_as(rows, first)
    if got is not None and got[-1].sum() * 2 < len(rows):
        second = _first_plain(rows[~got[-1]])
        other = None if second is None else _laid_out_as(rows, second)
        if other is not None and other[-1].sum() > got[-1].sum():
            return other
    return got


def _first_plain(rows: np.ndarray) -> re.Match[bytes] | None:
    return next(filter(None, (_PLAIN.fullmatch(row.tobytes()) for row in rows[:_TEMPLATE_ROWS])), None)


def _laid_out_as(rows: np.ndarray, m: re.Match[bytes]) -> _Rows | None:
    """_rows with the layout of the line m matched."""
    template = np.frombuffer(m.string, dtype=np.uint8)
    stamp, chan, ident, data, direction = m.span(1), m.span(2), m.span(3), m.span(4), m.span(5)
    dot = m.start(1) + m[1].index(b".")
    fixed = np.ones(rows.shape[1], dtype=bool)  # the columns every row has as the template: all but the fields'
    for a, b in (stamp, chan, ident, data, direction):
        fixed[a:b] = False  # an absent direction: (-1, -1), no column
    fixed[dot] = True
    cols = np.flatnonzero(fixed)
    digits = np.r_[stamp[0] : dot, dot + 1 : stamp[1]]
    if len(digits) > 18:
        return None
    d = rows[:, digits] - np.uint8(48)
    hex_id, hex_data = _HEX[rows[:, ident[0] : ident[1]]], _HEX[rows[:, data[0] : data[1]]]
    ok = (rows[:, cols] == template[cols]).all(axis=1) & (d < 10).all(axis=1) & (hex_id < 16).all(axis=1) & (
        hex_data < 16).all(axis=1)
    scale = np.int64(10) ** np.arange(len(digits) - 1, -1, -1, dtype=np.int64)
    whole = d.astype(np.int64) @ scale  # the stamp's digits as one integer (18 digits fit in 63 bits)
    ok &= whole < 2**53
    t = whole / float(10 ** (stamp[1] - dot - 1))  # both exact doubles: the quotient rounds as float() of the text
    value = np.zeros(len(rows), dtype=np.uint32)
    for j in range(hex_id.shape[1]):
        value = value * np.uint32(16) + hex_id[:, j]
    flags = np.full(len(rows), FLAG_EXTENDED if ident[1] - ident[0] > 3 else 0, dtype=np.uint8)
    if direction[0] >= 0:
        letter = rows[:, direction[0]] | np.uint8(0x20)  # lower case
        tx = letter == ord("t")
        ok &= tx | (letter == ord("r"))
        flags |= tx.astype(np.uint8) * np.uint8(FLAG_TX)
    names, codes = [m[2].decode()], np.zeros(len(rows), dtype=np.intp)
    channels = rows[:, chan[0] : chan[1]]
    if not (channels == channels[0]).all():
        unique, codes = np.unique(channels, axis=0, return_inverse=True)
        codes = codes.reshape(-1)
        valid = np.array([_CHANNEL.fullmatch(row.tobytes().decode("latin-1")) is not None for row in unique])
        ok &= valid[codes]
        keep = np.flatnonzero(valid)
        lut = np.zeros(len(unique), dtype=np.intp)
        lut[keep] = np.arange(len(keep))
        codes = lut[codes]
        names = [unique[i].tobytes().decode() for i in keep.tolist()] or [m[2].decode()]
    return t, value, flags, hex_data[:, 0::2] * np.uint8(16) + hex_data[:, 1::2], names, codes, ok


def _plain_batch(lines: list[tuple[bytes, bytes, bytes, bytes, bytes]]) -> CanFrameBatch | None:
    """Lines that matched _PLAIN as a batch; None when one of them is an error frame."""
    n = len(lines)
    if n == 0:
        return CanFrameBatch.from_columns([], [], [], [])
    stamps, channels, ids, data, direction = zip(*lines)
    t = np.fromiter(map(float, stamps), dtype=np.float64, count=n)
    ident = np.fromiter(map(int, ids, [16] * n), dtype=np.uint32, count=n)
    if ((ident & np.uint32(_ERROR_ID)) == _ERROR_ID).any():
        return None
    lengths = np.fromiter(map(len, data), dtype=np.uint8, count=n) >> 1
    flags = (np.fromiter(map(len, ids), dtype=np.uint8, count=n) > 3) * np.uint8(FLAG_EXTENDED)  # python-can's rule
    if direction.count(b"") + direction.count(b"R") + direction.count(b"r") != n:
        flags |= np.array([d in (b"T", b"t") for d in direction], dtype=np.uint8) * np.uint8(FLAG_TX)
    if bool((lengths == 8).all()):
        payload = np.frombuffer(binascii.unhexlify(b"".join(data)), dtype=np.uint8).reshape(n, 8)
    else:
        payload = np.frombuffer(binascii.unhexlify(b"".join(d.ljust(16, b"0") for d in data)),
                                dtype=np.uint8).reshape(n, 8)
    names: tuple[str, ...]
    if channels.count(channels[0]) == n:
        channel, names = np.zeros(n, dtype=np.uint16), (channels[0].decode(),)
    else:
        index: dict[bytes, int] = {}
        channel = np.fromiter((index.setdefault(c, len(index)) for c in channels), dtype=np.uint16, count=n)
        names = tuple(c.decode() for c in index)
    return CanFrameBatch(t, ident & np.uint32(0x1FFFFFFF), flags, lengths, payload, channel, names)


def _mixed_batch(text: bytes, encoding: str, frames_before: int) -> CanFrameBatch:
    """Lines of either kind: the plain ones as _plain_batch, the others through python-can's reader."""
    import can

    parts: list[CanFrameBatch] = []
    plain: list[tuple[bytes, bytes, bytes, bytes, bytes]] = []
    frames = frames_before

    def flush_plain() -> None:
        nonlocal frames
        if plain:
            batch = _plain_batch(plain)
            assert batch is not None  # error frames went to other()
            parts.append(batch)
            frames += len(plain)
            plain.clear()

    def other(lines: bytes) -> None:
        nonlocal frames
        flush_plain()
        msgs: list[can.Message] = []
        try:
            for msg in can.io.CanutilsLogReader(io.StringIO(lines.decode(encoding), newline=None)):
                msgs.append(msg)
        except Exception as e:
            raise CandumpError(e, frames + len(msgs)) from e
        if msgs:
            parts.append(CanFrameBatch.from_frames(msgs, [m.timestamp for m in msgs]))
            frames += len(msgs)

    end = 0
    for m in _PLAIN.finditer(text):
        if m.start() != end:
            other(text[end : m.start()])
        end = m.end()
        if int(m[3], 16) & _ERROR_ID == _ERROR_ID:
            other(m[0])
        else:
            plain.append((m[1], m[2], m[3], m[4], m[5] or b""))
    if end != len(text):
        other(text[end:])
    flush_plain()
    if not parts:
        return CanFrameBatch.from_columns([], [], [], [])
    return parts[0] if len(parts) == 1 else CanFrameBatch.concat(parts)
