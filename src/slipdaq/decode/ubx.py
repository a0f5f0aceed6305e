"""u-blox UBX: frames -> GpsFix from NAV-PVT (pyubx2); the frames are cut from the byte stream in decode/framing.py.

NAV-PVT gives ground speed (gSpeed, mm/s) with its accuracy estimate (sAcc, mm/s), the fix's UTC time (when the
receiver marks date and time valid), position, and validity (gnssFixOK and a 2D/3D fix).
"""

from __future__ import annotations

import calendar
import datetime as dt

from slipdaq.decode.timemark import TIM_TM2, TimeMark, decode_tim_tm2
from slipdaq.records import GpsFix, UbxFrame

SYNC = b"\xb5\x62"
NAV_PVT = b"\x01\x07"
"""Class and id of NAV-PVT, bytes 2-3 of its frame."""


def ubx_checksum(body: bytes) -> bytes:
    """8-bit Fletcher over class, id, length and payload."""
    a = b = 0
    for byte in body:
        a = (a + byte) & 0xFF
        b = (b + a) & 0xFF
    return bytes((a, b))


class UbxDecoder:
    """UBX frames -> GpsFix from NAV-PVT; other messages are counted as unused (by class and id, without parsing:
    pyubx2 takes about a millisecond for a NAV-SAT or NAV-SIG). Never raises."""

    def __init__(self) -> None:
        self.frames = 0
        self.bad_frames = 0
        self.unused_frames = 0
        self.fixes = 0
        self.time_marks = 0

    @staticmethod
    def is_time_mark(frame: UbxFrame) -> bool:
        return frame.data[2:4] == TIM_TM2

    def time_mark(self, frame: UbxFrame) -> TimeMark | None:
        """A TIM-TM2 frame's time mark (decode/timemark.py), counted in time_marks; None for another message."""
        mark = decode_tim_tm2(frame.data)
        self.time_marks += mark is not None
        return mark

    def decode(self, frame: UbxFrame) -> GpsFix | None:
        from pyubx2 import UBXReader  # imported with the first UBX frame (most logs have none)

        self.frames += 1
        if frame.data[2:4] != NAV_PVT:
            self.unused_frames += 1
            return None
        try:
            return self._nav_pvt(UBXReader.parse(frame.data), frame.timestamp_s)
        except Exception:  # pyubx2 raises several types on malformed payloads
            self.bad_frames += 1
            return None

    def _nav_pvt(self, m, timestamp_s: float) -> GpsFix:
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
