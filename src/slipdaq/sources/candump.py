"""candump -L logs (.log) read as batches of frames: the frames python-can's CanutilsLogReader gives, without a
Message per line.

A line in the form a logger writes (`(SECONDS) CHANNEL ID#DATA [R|T]`: a named channel, a 3- or 8-digit ID, up to
8 data bytes) is parsed many lines at once by one regular expression into numpy columns; any other line (CAN FD,
remote and error frames, numeric channels, odd spacing, damage) is handed to python-can's reader, so every line
means what python-can makes of it and a line python-can cannot read raises what it raises there.
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
_PLAIN = re.compile(rb"^\((\d+\.\d+)\) ([A-Za-z][A-Za-z0-9_]*) ([0-9A-Fa-f]{3}|[0-9A-Fa-f]{8})#((?:[0-9A-Fa-f]{2}){0,8})"
                    rb"(?: ([RTrt]))?\n", re.M)
_CHANNEL = re.compile(r"[A-Za-z][A-Za-z0-9_]*")
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
    batch = _columns_batch(text)
    if batch is not None:
        return batch
    lines = _PLAIN.findall(text)
    if len(lines) == text.count(b"\n") and text.endswith(b"\n"):
        batch = _plain_batch(lines)
        if batch is not None:
            return batch
    return _mixed_batch(text, encoding, frames_before)


def _columns_batch(text: bytes) -> CanFrameBatch | None:
    """Lines all in the form _PLAIN matches, read as numpy rows, the lines of one length at a time, each length's
    layout (where each field is) taken from its first line; None when a line is not in that form, lines of one
    length are laid out differently, there are many lengths or an error frame (the regular expression reads them)."""
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
    t = np.empty(n, dtype=np.float64)
    ident = np.empty(n, dtype=np.uint32)
    flags = np.empty(n, dtype=np.uint8)
    dlc = np.empty(n, dtype=np.uint8)
    payload = np.zeros((n, 8), dtype=np.uint8)
    channel = np.empty(n, dtype=np.uint16)
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
            return None
        t[which], ident[which], flags[which], data, its_names, codes = got
        dlc[which] = data.shape[1]
        payload[which, : data.shape[1]] = data
        for name in its_names:
            if name not in names:
                names.append(name)
        channel[which] = np.array([names.index(name) for name in its_names], dtype=np.uint16)[codes]
    if ((ident & np.uint32(_ERROR_ID)) == _ERROR_ID).any():
        return None
    if len(names) > 1:  # the names in order of appearance
        order = np.argsort([int(np.argmax(channel == i)) for i in range(len(names))])
        lut = np.zeros(len(names), dtype=np.uint16)
        lut[order] = np.arange(len(names), dtype=np.uint16)
        channel, names = lut[channel], [names[i] for i in order.tolist()]
    return CanFrameBatch(t, ident & np.uint32(0x1FFFFFFF), flags, dlc, payload, channel, tuple(names))


def _rows(rows: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, list[str], np.ndarray] | None:
    """Lines of one length as rows of bytes (newline included): (stamps, raw IDs, flags, payloads, channel names,
    each row's index in them) when every row is laid out as the first, in the form _PLAIN matches; else None."""
    m = _PLAIN.fullmatch(rows[0].tobytes())
    if m is None:
        return None
    stamp, chan, ident, data, direction = m.span(1), m.span(2), m.span(3), m.span(4), m.span(5)
    dot = m.start(1) + m[1].index(b".")
    fixed = np.ones(rows.shape[1], dtype=bool)  # the columns every row has as the first: all but the fields'
    for a, b in (stamp, chan, ident, data, direction):
        fixed[a:b] = False  # an absent direction: (-1, -1), no column
    fixed[dot] = True
    cols = np.flatnonzero(fixed)
    if not (rows[:, cols] == rows[0, cols]).all():
        return None
    digits = np.r_[stamp[0] : dot, dot + 1 : stamp[1]]
    d = rows[:, digits] - np.uint8(48)
    hex_id, hex_data = _HEX[rows[:, ident[0] : ident[1]]], _HEX[rows[:, data[0] : data[1]]]
    if not ((d < 10).all() and (hex_id < 16).all() and (hex_data < 16).all()) or len(digits) > 18:
        return None
    scale = np.int64(10) ** np.arange(len(digits) - 1, -1, -1, dtype=np.int64)
    whole = d.astype(np.int64) @ scale  # the stamp's digits as one integer (18 digits fit in 63 bits)
    if whole.max() >= 2**53:
        return None
    t = whole / float(10 ** (stamp[1] - dot - 1))  # both exact doubles: the quotient rounds as float() of the text
    value = np.zeros(len(rows), dtype=np.uint32)
    for j in range(hex_id.shape[1]):
        value = value * np.uint32(16) + hex_id[:, j]
    flags = np.full(len(rows), FLAG_EXTENDED if ident[1] - ident[0] > 3 else 0, dtype=np.uint8)
    if direction[0] >= 0:
        letter = rows[:, direction[0]] | np.uint8(0x20)  # lower case
        tx = letter == ord("t")
        if not (tx | (letter == ord("r"))).all():
            return None
        flags |= tx.astype(np.uint8) * np.uint8(FLAG_TX)
    names, codes = [m[2].decode()], np.zeros(len(rows), dtype=np.intp)
    channels = rows[:, chan[0] : chan[1]]
    if not (channels == channels[0]).all():
        unique, codes = np.unique(channels, axis=0, return_inverse=True)
        names = [row.tobytes().decode("latin-1") for row in unique]
        if not all(_CHANNEL.fullmatch(name) for name in names):
            return None
    return t, value, flags, hex_data[:, 0::2] * np.uint8(16) + hex_data[:, 1::2], names, codes.reshape(-1)


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
