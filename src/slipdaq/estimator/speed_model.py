"""The vehicle's longitudinal motion as a Kalman filter state x = [v, a] with white-noise jerk, and its two
measurements: a speed (GPS, a CAN reference) and an acceleration (an IMU). The smoother (smoother.py) and the online
vehicle-speed filter (vehicle_speed.py) both step it with these functions.

A state is (v, a, c00, c01, c11): speed, acceleration and the covariance's three elements.
  predict over dt (exact discretisation of a' = w, w white with spectral density q):
    F = [[1, dt], [0, 1]],  Q = q * [[dt^3/3, dt^2/2], [dt^2/2, dt]],  x <- F x,  P <- F P F' + Q
  update with a measurement z = H x + e, e ~ N(0, r), H = [1, 0] (speed) or [0, 1] (acceleration):
    s = H P H' + r,  K = P H' / s,  x <- x + K (z - H x),  P <- P - K H P
"""

from __future__ import annotations

State = tuple[float, float, float, float, float]


def predict(x: State, dt: float, q: float) -> State:
    v, a, c00, c01, c11 = x
    qdt = q * dt
    return (v + dt * a, a, c00 + dt * (2.0 * c01 + dt * c11) + qdt * dt * dt / 3.0, c01 + dt * c11 + 0.5 * qdt * dt,
            c11 + qdt)


def update_speed(x: State, z: float, r: float) -> tuple[State, float, float]:
    """The state after a speed measurement z of variance r, the innovation y and its variance s."""
    v, a, c00, c01, c11 = x
    s = c00 + r
    y = z - v
    k0 = c00 / s
    k1 = c01 / s
    return (v + k0 * y, a + k1 * y, c00 * r / s, c01 * r / s, c11 - k1 * c01), y, s


def update_accel(x: State, z: float, r: float) -> State:
    """The state after an acceleration measurement z of variance r."""
    v, a, c00, c01, c11 = x
    s = c11 + r
    y = z - a
    k0 = c01 / s
    k1 = c11 / s
    return v + k0 * y, a + k1 * y, c00 - k0 * c01, c01 * r / s, c11 * r / s
