"""The simulated body's pitch and the road's grade as the IMUs see them. Pure.

The body pitches nose up by theta = pitch_deg_per_g * a/g under acceleration a (nose down braking); the road climbs
at grade gamma. The car accelerates along the road, a_L = a*(cos(gamma) h, sin(gamma)) (h: the heading, horizontal),
and an accelerometer reads the specific force f = a_L + g*up along its axes, tilted by tau = theta + gamma from the
horizontal:
    forward  f_x = a*cos(theta) + g*sin(tau)        (about a*(1 + k) + g*sin(gamma), k = theta/a*g in radians per g)
    up       f_z = -a*sin(theta) + g*cos(tau)
The grade is the sensors' only: the vehicle model's road stays level (its force M*a), so to the estimator a grade is
an IMU mounted tilted by it.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

GRAVITY_MPS2 = 9.80665

Vec3 = tuple[float, float, float]


@dataclass(frozen=True, slots=True)
class BodyPitch:
    pitch_deg_per_g: float = 0.0
    """Nose up per g of forward acceleration (degrees; a car: about 1-2)."""
    grade_deg: float = 0.0
    """The road's grade as the IMUs see it (degrees, climbing positive)."""

    @property
    def active(self) -> bool:
        return self.pitch_deg_per_g != 0.0 or self.grade_deg != 0.0

    def pitch_rad(self, accel_mps2: float) -> float:
        """theta, the body's pitch from the road, at the true acceleration."""
        return math.radians(self.pitch_deg_per_g * accel_mps2 / GRAVITY_MPS2)

    def forward_reading(self, true_accel_mps2: float, accel_mps2: float) -> float:
        """f_x for an acceleration accel_mps2 (the true one plus the sensor's noise) at the true one's pitch."""
        theta = self.pitch_rad(true_accel_mps2)
        return accel_mps2 * math.cos(theta) + GRAVITY_MPS2 * math.sin(theta + math.radians(self.grade_deg))

    def body_axes(self, true_accel_mps2: float, heading_deg: float) -> tuple[Vec3, Vec3]:
        """(forward, up) unit vectors of the body in ENU."""
        tau = self.pitch_rad(true_accel_mps2) + math.radians(self.grade_deg)
        east, north = math.sin(math.radians(heading_deg)), math.cos(math.radians(heading_deg))
        c, s = math.cos(tau), math.sin(tau)
        return (c * east, c * north, s), (-s * east, -s * north, c)

    def free_acceleration(self, accel_mps2: float, heading_deg: float) -> Vec3:
        """a_L in ENU: along the road."""
        east, north = math.sin(math.radians(heading_deg)), math.cos(math.radians(heading_deg))
        c, s = math.cos(math.radians(self.grade_deg)), math.sin(math.radians(self.grade_deg))
        return accel_mps2 * c * east, accel_mps2 * c * north, accel_mps2 * s


def quaternion_of(rot: tuple[Vec3, Vec3, Vec3]) -> tuple[float, float, float, float]:
    """The unit quaternion (q0 real) of a rotation matrix (rows), Shepperd's method."""
    (r00, r01, r02), (r10, r11, r12), (r20, r21, r22) = rot
    tr = r00 + r11 + r22
    if tr > 0:
        s = math.sqrt(tr + 1.0) * 2.0
        return 0.25 * s, (r21 - r12) / s, (r02 - r20) / s, (r10 - r01) / s
    if r00 > r11 and r00 > r22:
        s = math.sqrt(1.0 + r00 - r11 - r22) * 2.0
        return (r21 - r12) / s, 0.25 * s, (r01 + r10) / s, (r02 + r20) / s
    if r11 > r22:
        s = math.sqrt(1.0 + r11 - r00 - r22) * 2.0
        return (r02 - r20) / s, (r01 + r10) / s, 0.25 * s, (r12 + r21) / s
    s = math.sqrt(1.0 + r22 - r00 - r11) * 2.0
    return (r10 - r01) / s, (r02 + r20) / s, (r12 + r21) / s, 0.25 * s


def cross(u: Vec3, v: Vec3) -> Vec3:
    return u[1] * v[2] - u[2] * v[1], u[2] * v[0] - u[0] * v[2], u[0] * v[1] - u[1] * v[0]
