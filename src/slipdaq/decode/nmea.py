"""NMEA 0183: bytes -> lines (framing), lines -> GpsFix (pynmea2, checksum checked).

One GpsFix per receiver epoch: speed from RMC (status A) when the receiver sends RMC, else from VTG;
GGA adds fix quality, satellites and altitude to the next fix. Bad lines are counted, never raised.
"""

from __future__ import annotations

import calendar
import datetime as dt

import pynmea2

from slipdaq.records import GpsFix, NmeaLine

KNOT_MPS = 1852.0 / 3600.0
MAX_LINE_BYTES = 256
"""NMEA allows 82 characters; longer lines are cut here and counted as overlong."""


class NmeaFramer:
    """Splits a byte stream into lines; a line that grows beyond MAX_LINE_BYTES is cut and counted."""

    def __init__(self) -> None:
        self._buf = bytearray()
        self.overlong_lines = 0

    def feed(self, data: bytes, timestamp_s: float) -> list[NmeaLine]:
        self._buf += data
        lines: list[NmeaLine] = []
        while True:
            nl = self._buf.find(b"\n")
            if nl < 0:
                break
            raw = bytes(self._buf[:nl])
            del self._buf[: nl + 1]
            if len(raw) > MAX_LINE_BYTES:
                self.overlong_lines += 1
                raw = raw[:MAX_LINE_BYTES]
            text = raw.rstrip(b"\r").decode("latin-1")
            if text:
                lines.append(NmeaLine(timestamp_s, text))
        if len(self._buf) > MAX_LINE_BYTES:
            self.overlong_lines += 1
            lines.append(NmeaLine(timestamp_s, bytes(self._buf[:MAX_LINE_BYTES]).decode("latin-1")))
            self._buf.clear()
        return lines


def _utc_seconds(date: dt.date | None, time: dt.time | None) -> float | None:
    if date is None or time is None:
        return None
    stamp = dt.datetime.combine(date, time.replace(tzinfo=None))
    return calendar.timegm(stamp.timetuple()) + stamp.microsecond * 1e-6


def _float(value: object) -> float | None:
    try:
        return float(value)  # type: ignore[arg-type]
    except (TypeError, ValueError):
        return None


class NmeaDecoder:
    """Stateful, pure: NMEA lines in arrival order -> GpsFix per epoch, with counters."""

    VTG_ONLY_AFTER_S = 1.5
    """VTG gives the speed only when no RMC has come for this long (no double counting)."""

    def __init__(self) -> None:
        self.lines = 0
        self.sentences = 0
        self.bad_sentences = 0
        self.ignored_lines = 0
        self.fixes = 0
        self._last_rmc_s: float | None = None
        self._gga: pynmea2.GGA | None = None

    def decode(self, line: NmeaLine) -> GpsFix | None:
        self.lines += 1
        text = line.line.strip()
        if not text or text.startswith("#"):
            self.ignored_lines += 1
            return None
        try:
            msg = pynmea2.parse(text, check=True)
        except (pynmea2.ParseError, pynmea2.ChecksumError, ValueError, AttributeError, TypeError, IndexError):
            self.bad_sentences += 1
            return None
        self.sentences += 1
        try:
            if isinstance(msg, pynmea2.RMC):
                return self._rmc(msg, line.timestamp_s)
            if isinstance(msg, pynmea2.GGA):
                self._gga = msg
            elif isinstance(msg, pynmea2.VTG):
                return self._vtg(msg, line.timestamp_s)
        except (ValueError, TypeError, AttributeError):  # fields present but malformed
            self.sentences -= 1
            self.bad_sentences += 1
        return None

    def _gga_fields(self) -> dict[str, object]:
        g = self._gga
        if g is None:
            return {}
        return {
            "fix_quality": int(g.gps_qual) if g.gps_qual not in (None, "") else None,
            "satellites": int(g.num_sats) if g.num_sats not in (None, "") else None,
            "altitude_m": _float(g.altitude),
        }

    def _rmc(self, msg: pynmea2.RMC, timestamp_s: float) -> GpsFix | None:
        self._last_rmc_s = timestamp_s
        valid = msg.status == "A"
        speed_kn = _float(msg.spd_over_grnd)
        if speed_kn is None:
            return None
        self.fixes += 1
        return GpsFix(
            timestamp_s=timestamp_s,
            speed_mps=speed_kn * KNOT_MPS,
            fix_time_utc_s=_utc_seconds(msg.datestamp, msg.timestamp),
            valid=valid,
            course_deg=_float(msg.true_course),
            latitude_deg=msg.latitude if msg.lat else None,
            longitude_deg=msg.longitude if msg.lon else None,
            sentence="RMC",
            **self._gga_fields(),  # type: ignore[arg-type]
        )

    def _vtg(self, msg: pynmea2.VTG, timestamp_s: float) -> GpsFix | None:
        if self._last_rmc_s is not None and timestamp_s - self._last_rmc_s < self.VTG_ONLY_AFTER_S:
            return None
        kmph = _float(msg.spd_over_grnd_kmph)
        speed_mps = kmph / 3.6 if kmph is not None else None
        if speed_mps is None:
            kn = _float(msg.spd_over_grnd_kts)
            speed_mps = kn * KNOT_MPS if kn is not None else None
        if speed_mps is None:
            return None
        mode = getattr(msg, "faa_mode", None)
        self.fixes += 1
        return GpsFix(
            timestamp_s=timestamp_s,
            speed_mps=speed_mps,
            valid=mode != "N",
            course_deg=_float(msg.true_track),
            sentence="VTG",
            **self._gga_fields(),  # type: ignore[arg-type]
        )
