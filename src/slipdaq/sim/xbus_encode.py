"""MTData2 encoding for the simulator's MTi: the inverse of decode/xbus.py. No I/O, no clock.

`mti_message` builds the packet the simulated MTi sends (PacketCounter, SampleTimeFine, UTCTime, Acceleration and
optionally FreeAcceleration, in that order as a real MTi orders them); `SimulatedMti` the simulator's stream of them
from its forward acceleration; `encode_packet` re-encodes any decoded packet item by item in its own order and
formats, byte for byte where its values came from a real message.
"""

from __future__ import annotations

import datetime as dt
import math
import struct
from collections.abc import Sequence
from typing import Any

from slipdaq.decode.sample_clock import TICKS_PER_S
from slipdaq.decode.xbus import (
    FLOAT32,
    FLOAT64,
    FP1220,
    FP1632,
    GNSS_PVT,
    ITEMS,
    MID_MTDATA2,
    PRECISION_MASK,
    TYPE_MASK,
    UTC_TIME,
    UTC_VALID_FLAGS,
    MtiPacket,
    UtcTime,
    xbus_message,
)
from slipdaq.sim.pitch import BodyPitch, cross, quaternion_of

XDI_UTC_TIME = 0x1010
XDI_PACKET_COUNTER = 0x1020
XDI_SAMPLE_TIME_FINE = 0x1060
XDI_QUATERNION = 0x2010
XDI_ACCELERATION = 0x4020
XDI_FREE_ACCELERATION = 0x4030
_INTS = {0x1020: ">H", 0x1060: ">I", 0x1070: ">I", 0x3010: ">I", 0xE010: ">B", 0xE020: ">I"}


def pack_floats(values: Sequence[float], precision: int) -> bytes:
    """Values in an XDI number format (fixed point rounded to nearest; out of range raises struct.error)."""
    if precision == FLOAT32:
        return struct.pack(f">{len(values)}f", *values)
    if precision == FLOAT64:
        return struct.pack(f">{len(values)}d", *values)
    if precision == FP1220:
        return struct.pack(f">{len(values)}i", *(round(v * (1 << 20)) for v in values))
    if precision == FP1632:
        out = b""
        for v in values:
            fixed = round(v * (1 << 32))
            out += struct.pack(">Ih", fixed & 0xFFFFFFFF, fixed >> 32)
        return out
    raise ValueError(f"no number format {precision}")


def encode_item(xdi: int, value: Any) -> bytes:
    """One MTData2 item (XDI, size, value) of a type decode/xbus.py decodes, its value as MtiPacket holds it."""
    kind = xdi & TYPE_MASK
    item = ITEMS[kind]
    if item.floats:
        data = pack_floats((value,) if item.floats == 1 else value, xdi & PRECISION_MASK)
    elif kind == XDI_UTC_TIME:
        u: UtcTime = value
        data = UTC_TIME.pack(u.nanosecond, u.year, u.month, u.day, u.hour, u.minute, u.second, u.flags)
    elif item.attr == "gnss_pvt":
        data = GNSS_PVT.pack(*value)
    else:
        data = struct.pack(_INTS[kind], value)
    return xdi.to_bytes(2, "big") + bytes((len(data),)) + data


def encode_packet(packet: MtiPacket) -> bytes:
    """A decoded packet back to its MTData2 message, its items in `packet.identifiers`' order and formats (a packet
    with unknown or bad items cannot be: their bytes were not kept)."""
    if packet.unknown_items or packet.bad_items:
        raise ValueError("the packet's unknown or bad items were not kept")
    payload = b"".join(encode_item(xdi, getattr(packet, ITEMS[xdi & TYPE_MASK].attr)) for xdi in packet.identifiers)
    return xbus_message(MID_MTDATA2, payload)


def utc_time(epoch_s: float, flags: int = UTC_VALID_FLAGS) -> UtcTime:
    """UTCTime for a time in seconds since the Unix epoch (to the nanosecond)."""
    whole = math.floor(epoch_s)
    seconds, nanosecond = divmod(whole * 1_000_000_000 + round((epoch_s - whole) * 1e9), 1_000_000_000)
    days, rest = divmod(seconds, 86_400)
    year, month, day = _civil(days)
    return UtcTime(nanosecond, year, month, day, rest // 3600, rest // 60 % 60, rest % 60, flags)


def _civil(days: int) -> tuple[int, int, int]:
    """(year, month, day) of a day count since 1970-01-01 (proleptic Gregorian)."""
    d = dt.date(1970, 1, 1) + dt.timedelta(days=days)
    return d.year, d.month, d.day


def mti_message(packet_counter: int, sample_time_fine: int, acceleration_mps2: Sequence[float],
                utc: UtcTime | float | None = None, free_acceleration_mps2: Sequence[float] | None = None,
                precision: int = FLOAT32, quaternion: Sequence[float] | None = None) -> bytes:
    """The simulated MTi's MTData2 message: PacketCounter (mod 2^16), SampleTimeFine (10 kHz ticks, mod 2^32),
    UTCTime where `utc` is given (as sent, or seconds since the Unix epoch: valid), Quaternion (ENU) where given,
    Acceleration and FreeAcceleration in `precision` (Float32: as an MTi sends by default)."""
    if len(acceleration_mps2) != 3 or not all(math.isfinite(v) for v in acceleration_mps2):
        raise ValueError(f"acceleration_mps2 must be three finite values, not {acceleration_mps2!r}")
    items = [encode_item(XDI_PACKET_COUNTER, packet_counter % (1 << 16)),
             encode_item(XDI_SAMPLE_TIME_FINE, sample_time_fine % (1 << 32))]
    if utc is not None:
        items.append(encode_item(XDI_UTC_TIME, utc if isinstance(utc, UtcTime) else utc_time(utc)))
    if quaternion is not None:
        items.append(encode_item(XDI_QUATERNION | precision, tuple(quaternion)))
    items.append(encode_item(XDI_ACCELERATION | precision, tuple(acceleration_mps2)))
    if free_acceleration_mps2 is not None:
        items.append(encode_item(XDI_FREE_ACCELERATION | precision, tuple(free_acceleration_mps2)))
    return xbus_message(MID_MTDATA2, b"".join(items))


GRAVITY_MPS2 = 9.80665


class SimulatedMti:
    """The simulator's MTi, mounted with `axis` forward (`sign` -1: backward, as the config's [imu] axis and sign) and
    another axis up: z, or x where z points forward; the car drives straight on `heading_deg` (from north, clockwise).
    Its messages carry the forward acceleration a as Acceleration (a * sign on the forward axis, +g on the up one: an
    accelerometer's specific force in the sensor's axes) and FreeAcceleration (gravity taken out, in ENU: a along the
    heading), PacketCounter counting from 0, SampleTimeFine the sim time, UTCTime the true UTC (start_utc_s + sim
    time). With a BodyPitch (sim/pitch.py), the sensor pitches with the body and the road's grade: its Acceleration is
    the specific force in its tilted axes, FreeAcceleration the acceleration along the road, and it sends its
    orientation as a Quaternion."""

    def __init__(self, axis: str, sign: int, start_utc_s: float, heading_deg: float,
                 pitch: BodyPitch | None = None) -> None:
        self.forward = "xyz".index(axis)
        self.up = 2 if axis != "z" else 0
        self.sign = sign
        self.start_utc_s = start_utc_s
        self.east_north = (math.sin(math.radians(heading_deg)), math.cos(math.radians(heading_deg)))
        self.heading_deg = heading_deg
        self.pitch = pitch or BodyPitch()
        self.count = 0

    def message(self, time_s: float, accel_mps2: float, true_accel_mps2: float | None = None) -> bytes:
        """The message of the sample at sim time time_s (true_accel_mps2: the acceleration without the sensor's
        noise, which the body pitches by; default accel_mps2)."""
        if self.pitch.active:
            return self._pitched(time_s, accel_mps2, accel_mps2 if true_accel_mps2 is None else true_accel_mps2)
        acc = [0.0, 0.0, 0.0]
        acc[self.forward] = self.sign * accel_mps2
        acc[self.up] += GRAVITY_MPS2
        east, north = self.east_north
        msg = mti_message(self.count, round(time_s * TICKS_PER_S), acc, utc=self.start_utc_s + time_s,
                          free_acceleration_mps2=(accel_mps2 * east, accel_mps2 * north, 0.0))
        self.count += 1
        return msg

    def _pitched(self, time_s: float, accel_mps2: float, true_accel_mps2: float) -> bytes:
        forward, up = self.pitch.body_axes(true_accel_mps2, self.heading_deg)
        axes: list[tuple[float, float, float]] = [(0.0, 0.0, 0.0)] * 3
        axes[self.forward] = (self.sign * forward[0], self.sign * forward[1], self.sign * forward[2])
        axes[self.up] = up
        k = 3 - self.forward - self.up
        axes[k] = cross(axes[(k + 1) % 3], axes[(k + 2) % 3])
        free = self.pitch.free_acceleration(accel_mps2, self.heading_deg)
        specific = (free[0], free[1], free[2] + GRAVITY_MPS2)
        acc = [sum(e[i] * specific[i] for i in range(3)) for e in axes]
        rot = ((axes[0][0], axes[1][0], axes[2][0]), (axes[0][1], axes[1][1], axes[2][1]),
               (axes[0][2], axes[1][2], axes[2][2]))
        msg = mti_message(self.count, round(time_s * TICKS_PER_S), acc, utc=self.start_utc_s + time_s,
                          free_acceleration_mps2=free, quaternion=quaternion_of(rot))
        self.count += 1
        return msg
