"""An MTi's forward acceleration, without gravity where its packets allow (docs/method.md, "The acceleration without
gravity"), as the pipeline takes it. Pure: no I/O, no clock.

The orientation q_LS (Quaternion), R_LS (RotationMatrix) or roll, pitch, yaw (EulerAngles, R_LS = Rz(yaw) Ry(pitch)
Rx(roll), the aerospace sequence) rotates a vector from the sensor's axes S to the local earth frame L (ENU, NED or
NWU: the XDI's coordinate bits). An accelerometer reads the specific force f_S = a_S + R_LS^T * g*up_L (up_L: +z in
ENU and NWU, -z in NED), so
    a_S       = f_S - g * R_LS^T up_L                           Acceleration with orientation ("imu-orientation")
    a_forward = sign * a_S[axis]
FreeAcceleration is a_L (gravity already out, in L); its forward part is its projection on the vehicle's heading,
the horizontal direction of the forward axis R_LS (sign * e_axis) where the packet has an orientation, else the GNSS
course: the MTi's own VelocityXYZ's, else the GNSS fixes' ("imu-free"; none before a course is known). Acceleration
alone is taken as sent ("imu": gravity in it).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import Any, Literal

from slipdaq.decode.sample_clock import SampleClock
from slipdaq.decode.xbus import MtiPacket, XbusDecoder
from slipdaq.records import XbusBytes

GRAVITY_MPS2 = 9.80665
"""Standard gravity, the MTi's."""
Matrix = tuple[tuple[float, float, float], tuple[float, float, float], tuple[float, float, float]]

SOURCE_RAW = "imu"
SOURCE_ORIENTATION = "imu-orientation"
SOURCE_FREE = "imu-free"


def rotation_from_quaternion(q: Sequence[float]) -> Matrix:
    """R_LS of the unit quaternion q_LS = (q0, q1, q2, q3), q0 real (normalized here)."""
    n = math.sqrt(sum(v * v for v in q)) or 1.0
    q0, q1, q2, q3 = (v / n for v in q)
    return ((1 - 2 * (q2 * q2 + q3 * q3), 2 * (q1 * q2 - q0 * q3), 2 * (q1 * q3 + q0 * q2)),
            (2 * (q1 * q2 + q0 * q3), 1 - 2 * (q1 * q1 + q3 * q3), 2 * (q2 * q3 - q0 * q1)),
            (2 * (q1 * q3 - q0 * q2), 2 * (q2 * q3 + q0 * q1), 1 - 2 * (q1 * q1 + q2 * q2)))


def rotation_from_euler(roll_deg: float, pitch_deg: float, yaw_deg: float) -> Matrix:
    """R_LS = Rz(yaw) Ry(pitch) Rx(roll)."""
    cr, sr = math.cos(math.radians(roll_deg)), math.sin(math.radians(roll_deg))
    cp, sp = math.cos(math.radians(pitch_deg)), math.sin(math.radians(pitch_deg))
    cy, sy = math.cos(math.radians(yaw_deg)), math.sin(math.radians(yaw_deg))
    return ((cp * cy, sr * sp * cy - cr * sy, cr * sp * cy + sr * sy),
            (cp * sy, sr * sp * sy + cr * cy, cr * sp * sy - sr * cy),
            (-sp, sr * cp, cr * cp))


def rotation_of(packet: MtiPacket) -> Matrix | None:
    """The packet's R_LS: from its Quaternion, else RotationMatrix (sent column by column), else EulerAngles."""
    if packet.quaternion is not None:
        return rotation_from_quaternion(packet.quaternion)
    m = packet.rotation_matrix
    if m is not None:
        return ((m[0], m[3], m[6]), (m[1], m[4], m[7]), (m[2], m[5], m[8]))
    if packet.euler_angles_deg is not None:
        return rotation_from_euler(*packet.euler_angles_deg)
    return None


def up_z(frame: str | None) -> float:
    """The z component of 'up' in the local earth frame (ENU and NWU: +1, NED: -1; unknown: ENU, the default)."""
    return -1.0 if frame == "NED" else 1.0


def heading_axis(course_deg: float, frame: str | None) -> tuple[float, float]:
    """The horizontal unit vector (L's x, y) of a course (degrees from north, clockwise)."""
    s, c = math.sin(math.radians(course_deg)), math.cos(math.radians(course_deg))
    if frame == "NED":
        return c, s
    if frame == "NWU":
        return c, -s
    return s, c


def velocity_course_deg(packet: MtiPacket, min_speed_mps: float) -> float | None:
    """The course (degrees from north, clockwise) of the packet's VelocityXYZ, None without it or slower than
    min_speed_mps."""
    v = packet.velocity_mps
    if v is None or math.hypot(v[0], v[1]) < min_speed_mps:
        return None
    east, north = {"NED": (v[1], v[0]), "NWU": (-v[1], v[0])}.get(packet.velocity_frame or "ENU", (v[0], v[1]))
    return math.degrees(math.atan2(east, north)) % 360.0


def gravity_free_forward(packet: MtiPacket, rot: Matrix, axis: int, sign: int) -> float | None:
    """sign * (f_S - g R^T up_L)[axis] of the packet's Acceleration, or None without it."""
    f = packet.acceleration_mps2
    if f is None:
        return None
    return sign * (f[axis] - GRAVITY_MPS2 * up_z(packet.orientation_frame) * rot[2][axis])


def free_forward(packet: MtiPacket, rot: Matrix | None, axis: int, sign: int,
                 course_deg: float | None) -> float | None:
    """The FreeAcceleration's projection on the heading (the forward axis's where rot is given, else the course), or
    None without FreeAcceleration, without a heading, or with the forward axis vertical."""
    a = packet.free_acceleration_mps2
    if a is None:
        return None
    if rot is not None:
        hx, hy = sign * rot[0][axis], sign * rot[1][axis]
        n = math.hypot(hx, hy)
        if n < 1e-3:
            return None
        hx, hy = hx / n, hy / n
    elif course_deg is not None and math.isfinite(course_deg):
        hx, hy = heading_axis(course_deg, packet.orientation_frame)
    else:
        return None
    return a[0] * hx + a[1] * hy


def forward_without_gravity(packet: MtiPacket, axis: Literal["x", "y", "z"], sign: int,
                            course_deg: float | None) -> tuple[float, str] | None:
    """(forward acceleration, its source) by the first that the packet allows: Acceleration with orientation,
    FreeAcceleration on the orientation's heading, Acceleration as sent, FreeAcceleration on the course; else None."""
    k = "xyz".index(axis)
    rot = rotation_of(packet)
    if rot is not None:
        a = gravity_free_forward(packet, rot, k, sign)
        if a is not None:
            return a, SOURCE_ORIENTATION
        a = free_forward(packet, rot, k, sign, None)
        if a is not None:
            return a, SOURCE_FREE
    if packet.acceleration_mps2 is not None:
        return sign * packet.acceleration_mps2[k], SOURCE_RAW
    a = free_forward(packet, None, k, sign, course_deg)
    return (a, SOURCE_FREE) if a is not None else None


class MtiAccel:
    """An MTi's forward acceleration per raw record, as the pipeline takes it ([imu] source = "serial"): each MTData2
    packet's forward_without_gravity on `axis`, times `sign`, at the packet's SampleTimeFine placed on the host's
    clock (decode/sample_clock.py); None for other records or without an IMU on serial. `source` is the last
    sample's; `course_deg` the last course: its VelocityXYZ's, or the GNSS fixes' (the pipeline sets it)."""

    def __init__(self, imu: Any) -> None:
        self.enabled = getattr(imu, "source", "can") == "serial"
        self.axis: Literal["x", "y", "z"] = getattr(imu, "axis", "x")
        self.sign = int(getattr(imu, "sign", 1))
        self.decoder = XbusDecoder()
        self.clock = SampleClock()
        self.course_deg: float | None = None
        self.source = SOURCE_RAW
        self.min_course_speed_mps = 2.0
        """The MTi's VelocityXYZ sets course_deg from this horizontal speed on."""

    def sample(self, record: XbusBytes) -> tuple[float, float] | None:
        """(time on the host's clock, forward acceleration), or None."""
        if not self.enabled:
            return None
        packet = self.decoder.decode(record)
        if packet is None:
            return None
        course = velocity_course_deg(packet, self.min_course_speed_mps)
        if course is not None:
            self.course_deg = course
        got = forward_without_gravity(packet, self.axis, self.sign, self.course_deg)
        if got is None:
            return None
        self.source = got[1]
        return self.clock.place(record.timestamp_s, packet.sample_time_fine), got[0]
