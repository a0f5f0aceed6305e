"""A GPS receiver's byte stream -> raw records: UBX frames, RTCM 3 frames and NMEA lines (the one framing rule, live
and import).

A UBX frame starts with the sync bytes 0xB5 0x62, then class, id, a 16-bit little-endian payload length, the payload
and a two-byte Fletcher checksum; a frame whose checksum fails, or whose declared length exceeds MAX_FRAME_BYTES, is
noise: its first byte is dropped (counted in bad_frames) and framing goes on at the next byte.

An RTCM 3 frame starts with 0xD3, six zero bits and a 10-bit length, then the message and a CRC-24Q (RTCM 10403.3,
section 4): kept as a record when its CRC holds, else its first byte goes on as text.

Everything else is text, cut into lines at LF and also before every `$` or `!` (the NMEA start delimiters), before
0xD3 and before the UBX sync bytes wherever they appear. So a sentence that follows binary bytes (UBX, RTCM) without a line end in
between starts a line of its own and is kept. A line longer than MAX_LINE_BYTES yields its first MAX_LINE_BYTES bytes
once (counted in overlong_lines) and the rest of it, up to the next LF, start delimiter or sync, is dropped.

The records do not depend on how the bytes were split into reads, and at most MAX_FRAME_BYTES bytes are held between
calls. The text of a line is its bytes as latin-1 (lossless), without the line end (CR LF or LF). A record takes the
time of the read that brought its last byte (a line's LF), even when it is known to be complete only later (a line
ended by the next `$`, or held behind bytes that looked like the start of a UBX frame).
"""

from __future__ import annotations

import re
from collections import deque

from slipdaq.decode.ubx import SYNC, ubx_checksum
from slipdaq.records import NmeaLine, RtcmFrame, UbxFrame

MAX_LINE_BYTES = 256
"""NMEA allows 82 characters; longer lines are cut here and counted as overlong."""
MAX_FRAME_BYTES = 8 + 8192
"""The largest UBX frame kept (NAV-PVT is 100 bytes, NAV-SIG of a ZED-F9 up to 1.3 kB, RXM-RAWX with 255
measurements 8 kB); a longer declared length is noise."""

_DELIMITER = re.compile(rb"\n|[$!\xd3]|\xb5b")
"""What ends a line: its line end, or the start of the next record (an NMEA start delimiter, an RTCM 3 preamble, the
UBX sync bytes)."""
_LF, _B5, _D3 = 0x0A, 0xB5, 0xD3


def _crc24q_table() -> list[int]:
    table = []
    for i in range(256):
        c = i << 16
        for _ in range(8):
            c = (c << 1) ^ 0x1864CFB if c & 0x800000 else c << 1
        table.append(c & 0xFFFFFF)
    return table


_CRC24Q = _crc24q_table()


def crc24q(data: bytes) -> bytes:
    """The CRC-24Q of RTCM 3 (polynomial 0x1864CFB, initial value 0), as its three bytes, most significant first."""
    crc = 0
    for b in data:
        crc = ((crc << 8) & 0xFFFFFF) ^ _CRC24Q[((crc >> 16) ^ b) & 0xFF]
    return crc.to_bytes(3, "big")


def arrival_s(reads: deque[tuple[int, float]], end: int) -> float:
    """The time of the read that brought the byte before offset `end`: reads are (end offset, time) of each read held,
    in order (the framers' one rule: a record takes the time of the read that brought its last byte)."""
    for stop, t in reads:
        if stop >= end:
            return t
    return reads[-1][1]


class GpsFramer:
    """Splits a receiver's byte stream into UbxFrame, RtcmFrame and NmeaLine records (see the module docstring)."""

    def __init__(self) -> None:
        self._buf = bytearray()
        self._reads: deque[tuple[int, float]] = deque()  # (end offset in _buf, time) of each read still held
        self._skipping = False  # inside the dropped tail of an overlong line
        self.bad_frames = 0
        self.overlong_lines = 0

    @property
    def pending_bytes(self) -> int:
        """Bytes held for a record whose end has not come yet."""
        return len(self._buf)

    def feed(self, data: bytes, timestamp_s: float) -> list[NmeaLine | UbxFrame | RtcmFrame]:
        """The records completed by these bytes, which arrived at timestamp_s."""
        if data:
            self._buf += data
            self._reads.append((len(self._buf), timestamp_s))
        return self._frame(final=False)

    def flush(self) -> list[NmeaLine | UbxFrame | RtcmFrame]:
        """The end of the stream: what is held becomes records (a frame cut short is noise, a line without end a line)."""
        return self._frame(final=True)

    def _arrival(self, end: int) -> float:
        return arrival_s(self._reads, end)

    def _frame(self, final: bool) -> list[NmeaLine | UbxFrame | RtcmFrame]:
        out: list[NmeaLine | UbxFrame | RtcmFrame] = []
        buf = self._buf
        n = len(buf)
        pos = 0
        while pos < n:
            first = buf[pos]
            if first == _B5:
                if pos + 1 == n and not final:
                    break  # maybe the sync bytes
                if buf[pos + 1 : pos + 2] == SYNC[1:]:
                    self._skipping = False
                    length = 8 + int.from_bytes(buf[pos + 4 : pos + 6], "little") if n - pos >= 6 else None
                    if (length is None or n - pos < length <= MAX_FRAME_BYTES) and not final:
                        break
                    frame = bytes(buf[pos : pos + length]) if length is not None else b""
                    if length is not None and length <= MAX_FRAME_BYTES and len(frame) == length \
                            and ubx_checksum(frame[2:-2]) == frame[-2:]:
                        out.append(UbxFrame(self._arrival(pos + length), frame))
                        pos += length
                    else:  # noise: the next byte goes on as text
                        self.bad_frames += 1
                        pos += 1
                    continue
            if first == _D3:
                if n - pos < 3 and not final:
                    break  # maybe a frame
                if n - pos >= 3 and buf[pos + 1] & 0xFC == 0:
                    length = 6 + ((buf[pos + 1] & 0x03) << 8 | buf[pos + 2])
                    if n - pos < length and not final:
                        break
                    frame = bytes(buf[pos : pos + length])
                    if len(frame) == length and crc24q(frame[:-3]) == frame[-3:]:
                        self._skipping = False
                        out.append(RtcmFrame(self._arrival(pos + length), frame))
                        pos += length
                        continue
            if first == _LF:
                self._skipping = False
                pos += 1
                continue
            if first in b"$!":
                self._skipping = False
            limit = pos + MAX_LINE_BYTES + 2  # a delimiter further on makes the line overlong anyway
            m = _DELIMITER.search(buf, pos + 1, limit)
            if m is not None:
                end = m.start()
                after = end + 1 if buf[end] == _LF else end
            elif limit < n:  # no end among its first MAX_LINE_BYTES + 1 bytes: overlong, cut now
                self._cut(out, pos)
                pos += MAX_LINE_BYTES + 1
                continue
            elif final:
                end = after = n
            else:  # its end has not come yet
                known = n - pos - (buf[n - 1] == _B5)
                if known > MAX_LINE_BYTES:
                    self._cut(out, pos)
                    pos += known
                    continue
                break
            if end - pos > MAX_LINE_BYTES:
                self._cut(out, pos)
            elif not self._skipping:
                self._emit(out, pos, end, after)
            self._skipping = False
            pos = after
        del buf[:pos]
        reads = self._reads
        while reads and reads[0][0] <= pos:
            reads.popleft()
        for i, (stop, t) in enumerate(reads):
            reads[i] = (stop - pos, t)
        return out

    def _cut(self, out: list[NmeaLine | UbxFrame | RtcmFrame], pos: int) -> None:
        """An overlong line: its first MAX_LINE_BYTES bytes once, then the rest is skipped."""
        if not self._skipping:
            self.overlong_lines += 1
            self._emit(out, pos, pos + MAX_LINE_BYTES, pos + MAX_LINE_BYTES)
        self._skipping = True

    def _emit(self, out: list[NmeaLine | UbxFrame | RtcmFrame], start: int, end: int, last: int) -> None:
        """The line buf[start:end]; it arrived with the byte before `last` (its LF, or its own last byte)."""
        text = bytes(self._buf[start:end]).rstrip(b"\r").decode("latin-1")
        if text:
            out.append(NmeaLine(self._arrival(last), text))
