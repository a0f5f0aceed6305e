"""u-blox UBX-TIM-TM2: the receiver's time mark of an edge on its EXTINT pin (a brake-light switch wired to it), in
GNSS or UTC time (u-blox M8/F9 interface description, UBX-TIM-TM2; 28-byte payload, little endian):

    ch U1 | flags X1 | count U2 | wnR U2 | wnF U2 | towMsR U4 | towSubMsR U4 (ns) | towMsF U4 | towSubMsF U4 | accEst U4
    flags: bit 0 mode, 1 run, 2 newFallingEdge, 3-4 timeBase (0 receiver, 1 GNSS, 2 UTC), 5 utc (UTC available),
           6 time (valid), 7 newRisingEdge

An edge's time is week wn, time of week towMs + towSubMs (ns); in UTC seconds since 1970 it is
GPS_EPOCH_UNIX_S + 604800*wn + tow, less the GPS-UTC leap seconds (LEAP_SECONDS) for the GNSS time base.
"""

from __future__ import annotations

import calendar
import struct
from bisect import bisect_right
from dataclasses import dataclass

TIM_TM2 = b"\x0d\x03"
"""Class and id of TIM-TM2, bytes 2-3 of its frame."""
PAYLOAD_BYTES = 28
GPS_EPOCH_UNIX_S = 315_964_800
"""1980-01-06T00:00:00Z: GPS week 0 begins."""
SECONDS_PER_WEEK = 604_800
TIME_BASE_GNSS, TIME_BASE_UTC = 1, 2

_LEAP_DATES = ("1981-07-01", "1982-07-01", "1983-07-01", "1985-07-01", "1988-01-01", "1990-01-01", "1991-01-01",
               "1992-07-01", "1993-07-01", "1994-07-01", "1996-01-01", "1997-07-01", "1999-01-01", "2006-01-01",
               "2009-01-01", "2012-07-01", "2015-07-01", "2017-01-01")
LEAP_SECONDS = tuple(calendar.timegm((int(d[:4]), int(d[5:7]), int(d[8:]), 0, 0, 0, 0, 0, 0)) for d in _LEAP_DATES)
"""UTC instants (s since 1970) from which GPS - UTC grew by one second (IERS Bulletin C); 18 s since 2017."""


def gps_minus_utc_s(gps_unix_s: float) -> int:
    """GPS - UTC (whole leap seconds) at a GPS instant counted in seconds since 1970 without leap seconds."""
    n = 0
    while n < len(LEAP_SECONDS) and gps_unix_s - (n + 1) >= LEAP_SECONDS[n]:
        n += 1
    return n


def utc_to_gps_s(utc_s: float) -> float:
    """UTC seconds since 1970 -> GPS time in seconds since 1970 (the count GPS_EPOCH_UNIX_S + 604800*wn + tow)."""
    return utc_s + bisect_right(LEAP_SECONDS, utc_s)


@dataclass(frozen=True, slots=True)
class TimeMark:
    """One TIM-TM2 message: the last rising and falling edge of its channel, each in UTC seconds since 1970 (None:
    no such edge yet, or a time the receiver does not give in GNSS or UTC time)."""

    channel: int
    count: int
    """Edges counted by the receiver (rising)."""
    rising_utc_s: float | None
    falling_utc_s: float | None
    new_rising: bool
    """A rising edge since the last message."""
    new_falling: bool
    time_base: int
    """0 receiver time, 1 GNSS (GPS), 2 UTC."""
    valid: bool
    """The receiver marks the time valid."""
    accuracy_s: float


def _edge_utc_s(week: int, tow_ms: int, tow_sub_ns: int, time_base: int) -> float | None:
    if time_base not in (TIME_BASE_GNSS, TIME_BASE_UTC):
        return None
    t = GPS_EPOCH_UNIX_S + SECONDS_PER_WEEK * week + tow_ms * 1e-3 + tow_sub_ns * 1e-9
    return t - gps_minus_utc_s(t) if time_base == TIME_BASE_GNSS else t


def decode_tim_tm2(frame: bytes) -> TimeMark | None:
    """A whole UBX frame (sync to checksum) of TIM-TM2 -> TimeMark; None for another message or a short payload.
    The checksum is the framer's (decode/framing.py)."""
    if frame[2:4] != TIM_TM2 or len(frame) < 6 + PAYLOAD_BYTES:
        return None
    (length,) = struct.unpack_from("<H", frame, 4)
    if length < PAYLOAD_BYTES:
        return None
    ch, flags, count, wn_r, wn_f, ms_r, sub_r, ms_f, sub_f, acc = struct.unpack_from("<BBHHHIIIII", frame, 6)
    base = (flags >> 3) & 0x3
    new_rising, new_falling = bool(flags & 0x80), bool(flags & 0x04)
    return TimeMark(
        channel=ch, count=count,
        rising_utc_s=_edge_utc_s(wn_r, ms_r, sub_r, base) if (ms_r or sub_r or wn_r) else None,
        falling_utc_s=_edge_utc_s(wn_f, ms_f, sub_f, base) if (ms_f or sub_f or wn_f) else None,
        new_rising=new_rising, new_falling=new_falling, time_base=base, valid=bool(flags & 0x40),
        accuracy_s=acc * 1e-9,
    )
