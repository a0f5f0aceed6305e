"""u-blox UBX: a byte stream that mixes UBX frames and NMEA lines -> raw records; UBX NAV-PVT -> GpsFix (pyubx2).

Framing: a UBX frame starts with 0xB5 0x62, then class, id, a 16-bit little-endian payload length, the payload and a
two-byte Fletcher checksum; anything else is text, cut into lines at LF (or before the next 0xB5 0x62). A frame
whose checksum fails is noise: one byte is skipped and the search goes on. Nothing held exceeds MAX_FRAME_BYTES.
NAV-PVT gives ground speed (gSpeed, mm/s) with its accuracy estimate (sAcc, mm/s), the fix's UTC time (when the
receiver marks date and time valid), position, and validity (gnssFixOK and a 2D/3D fix).
"""

from __future__ import annotations

import calendar
import datetime as dt

from slipdaq.decode.nmea import MAX_LINE_BYTES
from slipdaq.records import GpsFix, NmeaLine, UbxFrame

SYNC = b"\xb5\x62"
MAX_FRAME_BYTES = 8 + 1024
"""The largest UBX frame kept (NAV-PVT is 100 bytes); a longer declared length is noise."""


def ubx_checksum(body: bytes) -> bytes:
    """8-bit Fletcher over class, id, length and payload."""
    a = b = 0
    for byte in body:
        a = (a + byte) & 0xFF
        b = (b + a) & 0xFF
    return bytes((a, b))


class GpsFramer:
    """Splits a receiver's byte stream into UbxFrame and NmeaLine records (see the module docstring)."""

    def __init__(self) -> None:
        self._buf = bytearray()
        self.bad_frames = 0
        self.overlong_lines = 0

    @property
    def pending_bytes(self) -> int:
        return len(self._buf)

    def feed(self, data: bytes, timestamp_s: float) -> list[NmeaLine | UbxFrame]:
        self._buf += data
        out: list[NmeaLine | UbxFrame] = []
        buf = self._buf
        while buf:
            if buf[:2] == SYNC:
                if len(buf) < 6:
                    break
                length = 8 + int.from_bytes(buf[4:6], "little")
                if length > MAX_FRAME_BYTES:
                    self.bad_frames += 1
                    del buf[:1]
                    continue
                if len(buf) < length:
                    break
                frame = bytes(buf[:length])
                if ubx_checksum(frame[2:-2]) == frame[-2:]:
                    out.append(UbxFrame(timestamp_s, frame))
                    del buf[:length]
                else:
                    self.bad_frames += 1
                    del buf[:1]
                continue
            if buf[:1] == SYNC[:1] and len(buf) < 2:
                break  # maybe the start of a frame
            nl = buf.find(b"\n")
            sync = buf.find(SYNC, 1)
            ends = [i for i in (nl, sync) if i >= 0]
            if not ends:
                if len(buf) > MAX_LINE_BYTES:
                    self.overlong_lines += 1
                    del buf[:]
                break
            end = min(ends)
            line = bytes(buf[:end]).rstrip(b"\r")
            del buf[: end + 1 if end == nl else end]
            if len(line) > MAX_LINE_BYTES:
                self.overlong_lines += 1
                line = line[:MAX_LINE_BYTES]
            if line:
                out.append(NmeaLine(timestamp_s, line.decode("latin-1")))
        return out


class UbxDecoder:
    """UBX frames -> GpsFix from NAV-PVT; other messages are counted as unused. Never raises."""

    def __init__(self) -> None:
        self.frames = 0
        self.bad_frames = 0
        self.unused_frames = 0
        self.fixes = 0

    def decode(self, frame: UbxFrame) -> GpsFix | None:
        from pyubx2 import UBXReader  # imported with the first UBX frame (most logs have none)

        self.frames += 1
        try:
            msg = UBXReader.parse(frame.data)
            if getattr(msg, "identity", "") != "NAV-PVT":
                self.unused_frames += 1
                return None
            return self._nav_pvt(msg, frame.timestamp_s)
        except Exception:  # pyubx2 raises several types on malformed payloads
            self.bad_frames += 1
            return None

    def _nav_pvt(self, m, timestamp_s: float) -> GpsFix:  # type: ignore[no-untyped-def]
        utc = None
        if m.validDate and m.validTime:
            base = dt.datetime(m.year, m.month, m.day, m.hour, m.min, m.second)
            utc = calendar.timegm(base.timetuple()) + m.nano * 1e-9
        self.fixes += 1
        return GpsFix(
            timestamp_s=timestamp_s,
            speed_mps=m.gSpeed / 1000.0,
            fix_time_utc_s=utc,
            valid=bool(m.gnssFixOk) and m.fixType in (2, 3, 4),
            course_deg=float(m.headMot),
            latitude_deg=float(m.lat),
            longitude_deg=float(m.lon),
            altitude_m=m.hMSL / 1000.0,
            fix_quality=int(m.fixType),
            satellites=int(m.numSV),
            sentence="NAV-PVT",
            speed_accuracy_mps=m.sAcc / 1000.0,
        )
