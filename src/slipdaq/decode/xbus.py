"""An Xsens MTi's Xbus byte stream -> messages (XbusFramer) -> MTData2 packets (XbusDecoder). Pure: no I/O, no clock.

A message (Xsens MT Low-Level Communication Protocol) is: preamble 0xFA, bus id 0xFF, message id, length (0xFF: an
extended length, a big-endian u16, follows), the payload and a checksum: the 8-bit sum of every byte after the
preamble, checksum included, is 0. A candidate whose checksum fails, whose declared length exceeds MAX_PAYLOAD_BYTES
or which the stream's end cuts short is noise: its preamble is dropped (counted in bad_frames) and framing goes on at
the next byte. The framer emits every byte it is fed: each complete message as one XbusBytes record, and the bytes
between messages as noise records of at most MAX_NOISE_BYTES (cut at fixed offsets from the start of their run), so
the records, logged, keep the stream whole. A noise record never parses as a message (parse_message: it would have
been framed as one). The records do not depend on how the bytes were split into reads; a record takes the time of
the read that brought its last byte.

MTData2 (message id 0x36) is a list of items: a 2-byte data identifier (XDI, big-endian), a 1-byte size and the
value, big-endian. The XDI's bits 15-11 and 7-4 are the data type (10-8 reserved), bits 3-2 the coordinate system
(orientation and velocity: ENU 0x0, NED 0x4, NWU 0x8) and bits 1-0 the number format of floating values: Float32,
FP12.20 (an int32 / 2^20), FP16.32 (a 32-bit fraction then a 16-bit signed integer part, / 2^32) or Float64. An item
of a type not decoded here is skipped by its size and counted (unknown_items); a known one with the wrong size, or an
item cut short, is counted in bad_items. UTCTime's flags are 0x01 time of week valid, 0x02 week number valid, 0x04
UTC valid; utc_time_s is given only with all three.
"""

from __future__ import annotations

import datetime as dt
import struct
from collections import deque
from dataclasses import dataclass
from typing import Any, Literal, NamedTuple

from slipdaq.decode.framing import arrival_s
from slipdaq.records import XbusBytes

PREAMBLE = 0xFA
BUS_ID = 0xFF
"""The master's bus id: every message an MTi sends on its own (MTData2) and every reply on a serial port."""
EXTENDED_LENGTH = 0xFF
MID_MTDATA2 = 0x36
MID_ERROR = 0x42
MAX_PAYLOAD_BYTES = 2048
"""The longest payload the protocol allows; a longer declared length is noise."""
MAX_NOISE_BYTES = 256
"""Noise between messages is emitted in records of at most this many bytes."""

FLOAT32, FP1220, FP1632, FLOAT64 = 0, 1, 2, 3
PRECISION_NAMES = ("Float32", "FP1220", "FP1632", "Float64")
PRECISION_BYTES = (4, 4, 6, 8)
FRAMES = {0x0: "ENU", 0x4: "NED", 0x8: "NWU"}
_FRAME_NAMES = {0x0: "EastNorthUp", 0x4: "NorthEastDown", 0x8: "NorthWestUp"}
TYPE_MASK = 0xFFF0
"""The data type (group, bits 15-11, and type, bits 7-4) with the reserved bits 10-8: an XDI that sets one is unknown."""
FRAME_MASK = 0x000C
PRECISION_MASK = 0x0003

UTC_VALID_FLAGS = 0x07
"""UTCTime's flags that must all be set for its time to be used: time of week, week number and UTC valid."""
_EPOCH_ORDINAL = dt.date(1970, 1, 1).toordinal()

Vec3 = tuple[float, float, float]
Quat = tuple[float, float, float, float]


@dataclass(frozen=True, slots=True)
class UtcTime:
    """MTData2 UTCTime as sent: its calendar fields (UTC) and its validity flags."""

    nanosecond: int
    year: int
    month: int
    day: int
    hour: int
    minute: int
    second: int
    flags: int

    def epoch_ns(self) -> int | None:
        """Nanoseconds since the Unix epoch, or None where the flags say not valid or the fields are out of range."""
        if self.flags & UTC_VALID_FLAGS != UTC_VALID_FLAGS or self.nanosecond >= 1_000_000_000 \
                or self.hour > 23 or self.minute > 59 or self.second > 60:
            return None
        try:
            days = dt.date(self.year, self.month, self.day).toordinal() - _EPOCH_ORDINAL
        except ValueError:
            return None
        return (((days * 24 + self.hour) * 60 + self.minute) * 60 + self.second) * 1_000_000_000 + self.nanosecond


class GnssPvt(NamedTuple):
    """MTData2 GNSSPVTData (94 bytes), the receiver's NAV-PVT as the MTi forwards it: raw integers, units in names."""

    itow_ms: int
    year: int
    month: int
    day: int
    hour: int
    minute: int
    second: int
    valid: int
    t_acc_ns: int
    nano_ns: int
    fix_type: int
    flags: int
    num_sv: int
    reserved1: int
    lon_1e7deg: int
    lat_1e7deg: int
    height_mm: int
    h_msl_mm: int
    h_acc_mm: int
    v_acc_mm: int
    vel_n_mmps: int
    vel_e_mmps: int
    vel_d_mmps: int
    g_speed_mmps: int
    head_mot_1e5deg: int
    s_acc_mmps: int
    head_acc_1e5deg: int
    head_veh_1e5deg: int
    gdop_001: int
    pdop_001: int
    tdop_001: int
    vdop_001: int
    hdop_001: int
    ndop_001: int
    edop_001: int


GNSS_PVT = struct.Struct(">IHBBBBBBIiBBBBiiiiIIiiiiiIIiHHHHHHH")


@dataclass(frozen=True, slots=True)
class MtiPacket:
    """One MTData2 message decoded: each item it carried (None where absent), in SI units (names say which)."""

    timestamp_s: float
    """The record's time (host receive time, or the import's)."""
    packet_counter: int | None = None
    sample_time_fine: int | None = None
    """The sample's time in the MTi's 10 kHz ticks (wraps at 2^32)."""
    sample_time_coarse_s: int | None = None
    utc_time: UtcTime | None = None
    utc_time_s: float | None = None
    """UTCTime as seconds since the Unix epoch; None without UTCTime or where its flags say it is not valid."""
    status_word: int | None = None
    status_byte: int | None = None
    temperature_degc: float | None = None
    acceleration_mps2: Vec3 | None = None
    """Calibrated acceleration in the sensor's axes (specific force: gravity included)."""
    free_acceleration_mps2: Vec3 | None = None
    """Acceleration with gravity removed, in the local earth frame (ENU by default), not the sensor's axes."""
    acceleration_hr_mps2: Vec3 | None = None
    delta_v_mps: Vec3 | None = None
    rate_of_turn_radps: Vec3 | None = None
    rate_of_turn_hr_radps: Vec3 | None = None
    delta_q: Quat | None = None
    quaternion: Quat | None = None
    rotation_matrix: tuple[float, ...] | None = None
    euler_angles_deg: Vec3 | None = None
    orientation_frame: str | None = None
    """The coordinate system of quaternion, rotation_matrix and euler_angles_deg: ENU, NED or NWU."""
    baro_pressure_pa: int | None = None
    altitude_ellipsoid_m: float | None = None
    position_ecef_m: Vec3 | None = None
    lat_lon_deg: tuple[float, float] | None = None
    velocity_mps: Vec3 | None = None
    velocity_frame: str | None = None
    magnetic_field_au: Vec3 | None = None
    gnss_pvt: GnssPvt | None = None
    identifiers: tuple[int, ...] = ()
    """Every item's XDI, in the message's order (unknown ones too)."""
    unknown_items: int = 0
    bad_items: int = 0


class _Item(NamedTuple):
    name: str
    """The Xsens name (as einride/xsens-go prints it)."""
    attr: str
    """The MtiPacket field."""
    floats: int
    """Floating values in the number format of the XDI's low bits; 0: a fixed layout (see _FIXED)."""
    framed: bool = False
    """Carries a coordinate system."""


ITEMS: dict[int, _Item] = {
    0x0810: _Item("Temperature", "temperature_degc", 1),
    0x1010: _Item("UTCTime", "utc_time", 0),
    0x1020: _Item("PacketCounter", "packet_counter", 0),
    0x1060: _Item("SampleTimeFine", "sample_time_fine", 0),
    0x1070: _Item("SampleTimeCoarse", "sample_time_coarse_s", 0),
    0x2010: _Item("Quaternion", "quaternion", 4, True),
    0x2020: _Item("RotationMatrix", "rotation_matrix", 9, True),
    0x2030: _Item("EulerAngles", "euler_angles_deg", 3, True),
    0x3010: _Item("BaroPressure", "baro_pressure_pa", 0),
    0x4010: _Item("DeltaV", "delta_v_mps", 3),
    0x4020: _Item("Acceleration", "acceleration_mps2", 3),
    0x4030: _Item("FreeAcceleration", "free_acceleration_mps2", 3),
    0x4040: _Item("AccelerationHR", "acceleration_hr_mps2", 3),
    0x5020: _Item("AltitudeEllipsoid", "altitude_ellipsoid_m", 1),
    0x5030: _Item("PositionECEF", "position_ecef_m", 3),
    0x5040: _Item("LatLon", "lat_lon_deg", 2),
    0x7010: _Item("GNSSPVTData", "gnss_pvt", 0),
    0x8020: _Item("RateOfTurn", "rate_of_turn_radps", 3),
    0x8030: _Item("DeltaQ", "delta_q", 4),
    0x8040: _Item("RateOfTurnHR", "rate_of_turn_hr_radps", 3),
    0xC020: _Item("MagneticField", "magnetic_field_au", 3),
    0xD010: _Item("VelocityXYZ", "velocity_mps", 3, True),
    0xE010: _Item("StatusByte", "status_byte", 0),
    0xE020: _Item("StatusWord", "status_word", 0),
}
"""The MTData2 data types decoded, by XDI with its coordinate-system and format bits clear."""

UTC_TIME = struct.Struct(">IHBBBBBB")
_FIXED = {0x1010: UTC_TIME, 0x1020: struct.Struct(">H"), 0x1060: struct.Struct(">I"), 0x1070: struct.Struct(">I"),
          0x3010: struct.Struct(">I"), 0x7010: GNSS_PVT, 0xE010: struct.Struct(">B"), 0xE020: struct.Struct(">I")}
"""The layout of each item that has no number format."""
_FLOATS = {(p, n): struct.Struct(f">{n}{'f' if p == FLOAT32 else 'i' if p == FP1220 else 'd'}")
           for p in (FLOAT32, FP1220, FLOAT64) for n in (1, 2, 3, 4, 9)}
_FP1632 = struct.Struct(">Ih")
_SCALE_FP1220 = 1.0 / (1 << 20)
_SCALE_FP1632 = 1 << 32


def xdi_name(xdi: int) -> str:
    """An XDI as einride/xsens-go names it: `EulerAngles(EastNorthUp,Float32)`, `Acceleration(FP1220)`, `UTCTime`."""
    item = ITEMS.get(xdi & TYPE_MASK)
    if item is None:
        return f"Unknown(0x{xdi:04X})"
    precision = PRECISION_NAMES[xdi & PRECISION_MASK]
    if item.framed:
        return f"{item.name}({_FRAME_NAMES.get(xdi & FRAME_MASK, '?')},{precision})"
    return f"{item.name}({precision})" if item.floats else item.name


def item_size(xdi: int) -> int | None:
    """The value's size in bytes for a decoded data type, else None."""
    item = ITEMS.get(xdi & TYPE_MASK)
    if item is None:
        return None
    if item.floats:
        return item.floats * PRECISION_BYTES[xdi & PRECISION_MASK]
    return _FIXED[xdi & TYPE_MASK].size


def unpack_floats(data: bytes | memoryview, offset: int, count: int, precision: int) -> tuple[float, ...]:
    """`count` values in the number format `precision` from data[offset:], as floats."""
    if precision == FP1632:
        out = []
        for k in range(count):
            fraction, integer = _FP1632.unpack_from(data, offset + 6 * k)
            out.append(((integer << 32) | fraction) / _SCALE_FP1632)
        return tuple(out)
    values = _FLOATS[precision, count].unpack_from(data, offset)
    if precision == FP1220:
        return tuple(v * _SCALE_FP1220 for v in values)
    return values


def _value(xdi: int, item: _Item, data: bytes, offset: int) -> Any:
    if item.floats:
        values = unpack_floats(data, offset, item.floats, xdi & PRECISION_MASK)
        return values[0] if item.floats == 1 else values
    fields = _FIXED[xdi & TYPE_MASK].unpack_from(data, offset)
    if item.attr == "utc_time":
        return UtcTime(*fields)
    if item.attr == "gnss_pvt":
        return GnssPvt(*fields)
    return fields[0]


def decode_mtdata2(payload: bytes, timestamp_s: float = 0.0) -> MtiPacket:
    """An MTData2 payload -> its packet; never raises (see the module docstring for what is skipped and counted)."""
    values: dict[str, Any] = {}
    identifiers: list[int] = []
    unknown = bad = 0
    pos, n = 0, len(payload)
    while pos < n:
        if n - pos < 3:
            bad += 1
            break
        xdi = (payload[pos] << 8) | payload[pos + 1]
        size = payload[pos + 2]
        start, pos = pos + 3, pos + 3 + size
        if pos > n:
            bad += 1
            break
        identifiers.append(xdi)
        item = ITEMS.get(xdi & TYPE_MASK)
        if item is None:
            unknown += 1
        elif size != item_size(xdi):
            bad += 1
        else:
            values[item.attr] = _value(xdi, item, payload, start)
            if item.framed:
                frame = FRAMES.get(xdi & FRAME_MASK)
                values["velocity_frame" if item.attr == "velocity_mps" else "orientation_frame"] = frame
    utc = values.get("utc_time")
    if utc is not None:
        ns = utc.epoch_ns()
        values["utc_time_s"] = None if ns is None else ns / 1_000_000_000
    return MtiPacket(timestamp_s, **values, identifiers=tuple(identifiers), unknown_items=unknown, bad_items=bad)


def xbus_checksum(body: bytes | bytearray) -> int:
    """The checksum byte for `body` (bus id to the payload's end): their sum with it is 0 modulo 256."""
    return -sum(body) & 0xFF


def xbus_message(mid: int, payload: bytes, bus_id: int = BUS_ID) -> bytes:
    """One framed message (an extended length from 255 payload bytes on)."""
    if len(payload) > MAX_PAYLOAD_BYTES:
        raise ValueError(f"an Xbus payload holds at most {MAX_PAYLOAD_BYTES} bytes, not {len(payload)}")
    length = bytes((len(payload),)) if len(payload) < EXTENDED_LENGTH else b"\xff" + len(payload).to_bytes(2, "big")
    body = bytes((bus_id, mid)) + length + payload
    return bytes((PREAMBLE,)) + body + bytes((xbus_checksum(body),))


def _declared(data: bytes | bytearray, pos: int) -> tuple[int, int] | None:
    """(header length, payload length) of the candidate at data[pos], or None while its length bytes are not in."""
    n = len(data) - pos
    if n < 4:
        return None
    length = data[pos + 3]
    if length != EXTENDED_LENGTH:
        return 4, length
    return (6, (data[pos + 4] << 8) | data[pos + 5]) if n >= 6 else None


def parse_message(data: bytes) -> tuple[int, bytes] | None:
    """(message id, payload) of one whole valid message (the framer's rule), else None."""
    if len(data) < 5 or data[0] != PREAMBLE or data[1] != BUS_ID:
        return None
    declared = _declared(data, 0)
    if declared is None:
        return None
    header, length = declared
    if length > MAX_PAYLOAD_BYTES or len(data) != header + length + 1 or sum(data[1:]) & 0xFF:
        return None
    return data[2], data[header : header + length]


class XbusFramer:
    """Splits an MTi's byte stream into XbusBytes records: messages and the noise between them (module docstring)."""

    def __init__(self) -> None:
        self._buf = bytearray()
        self._reads: deque[tuple[int, float]] = deque()  # (end offset in _buf, time) of each read still held
        self._noise = 0  # the held bytes _buf[:_noise] are noise already decided
        self.messages = 0
        self.bad_frames = 0
        self.noise_bytes = 0

    @property
    def pending_bytes(self) -> int:
        """Bytes held for a record whose end has not come yet."""
        return len(self._buf)

    def feed(self, data: bytes, timestamp_s: float) -> list[XbusBytes]:
        """The records completed by these bytes, which arrived at timestamp_s."""
        if data:
            self._buf += data
            self._reads.append((len(self._buf), timestamp_s))
        return self._frame(final=False)

    def flush(self) -> list[XbusBytes]:
        """The end of the stream: what is held becomes records (a message cut short is noise)."""
        return self._frame(final=True)

    def _arrival(self, end: int) -> float:
        return arrival_s(self._reads, end)

    def _frame(self, final: bool) -> list[XbusBytes]:
        out: list[XbusBytes] = []
        buf = self._buf
        n = len(buf)
        start, pos = 0, self._noise  # the held noise run is buf[start:pos]
        while pos < n:
            if pos - start >= MAX_NOISE_BYTES:
                start = self._emit_noise(out, start, pos, whole=False)
            if buf[pos] != PREAMBLE:
                nxt = buf.find(PREAMBLE, pos + 1, start + MAX_NOISE_BYTES + 1)
                pos = nxt if nxt >= 0 else min(n, start + MAX_NOISE_BYTES)
                continue
            if pos + 1 == n and not final:
                break  # maybe a message's preamble
            if pos + 1 == n or buf[pos + 1] != BUS_ID:
                pos += 1
                continue
            declared = _declared(buf, pos)
            if declared is not None:
                header, length = declared
                total = header + length + 1
                if length <= MAX_PAYLOAD_BYTES and n - pos >= total:
                    if sum(buf[pos + 1 : pos + total]) & 0xFF == 0:
                        start = self._emit_noise(out, start, pos, whole=True)
                        out.append(XbusBytes(self._arrival(pos + total), bytes(buf[pos : pos + total])))
                        self.messages += 1
                        start = pos = pos + total
                        continue
                elif length <= MAX_PAYLOAD_BYTES and not final:
                    break  # its end has not come yet
            elif not final:
                break  # its length has not come yet
            self.bad_frames += 1  # a bad checksum, a length beyond the limit, or cut short by the stream's end
            pos += 1
        if final:
            start = self._emit_noise(out, start, n, whole=True)
        self._noise = pos - start
        del buf[:start]
        reads = self._reads
        while reads and reads[0][0] <= start:
            reads.popleft()
        for i, (stop, t) in enumerate(reads):
            reads[i] = (stop - start, t)
        return out

    def _emit_noise(self, out: list[XbusBytes], start: int, end: int, whole: bool) -> int:
        """Noise buf[start:end] in records of MAX_NOISE_BYTES (and the rest, if `whole`); returns where it stops."""
        while end - start >= MAX_NOISE_BYTES or (whole and end > start):
            stop = min(end, start + MAX_NOISE_BYTES)
            out.append(XbusBytes(self._arrival(stop), bytes(self._buf[start:stop])))
            self.noise_bytes += stop - start
            start = stop
        return start


class XbusDecoder:
    """XbusBytes records -> MtiPacket from MTData2 messages; other messages and noise are counted. Never raises."""

    def __init__(self) -> None:
        self.messages = 0
        self.packets = 0
        self.other_messages = 0
        self.error_messages = 0
        self.noise_records = 0
        self.unknown_items = 0
        self.bad_items = 0

    def decode(self, record: XbusBytes) -> MtiPacket | None:
        """The record's packet, or None for another message or noise."""
        parsed = parse_message(record.data)
        if parsed is None:
            self.noise_records += 1
            return None
        self.messages += 1
        mid, payload = parsed
        if mid != MID_MTDATA2:
            self.other_messages += 1
            self.error_messages += mid == MID_ERROR
            return None
        packet = decode_mtdata2(payload, record.timestamp_s)
        self.packets += 1
        self.unknown_items += packet.unknown_items
        self.bad_items += packet.bad_items
        return packet


def forward_accel_mps2(packet: MtiPacket, axis: Literal["x", "y", "z"], sign: int) -> float | None:
    """The vehicle's forward acceleration: the packet's Acceleration along the sensor axis that points forward
    (`sign` -1 where it points backward); None without Acceleration."""
    if sign not in (1, -1):
        raise ValueError(f"sign must be 1 or -1, not {sign!r}")
    accel = packet.acceleration_mps2
    if accel is None:
        return None
    return sign * accel["xyz".index(axis)]
