"""The driving phase of a window: standstill, accelerate, brake or cruise (used by the estimator and the report)."""

from __future__ import annotations

PHASE_ACCEL_MPS2 = 0.3
"""|a| above this is accelerating or braking; below it, cruising (or coasting)."""
STANDSTILL_SPEED_MPS = 0.5
"""Below this GPS speed the car stands still."""


def phase_of(speed_mps: float, accel_mps2: float | None) -> str:
    """standstill below STANDSTILL_SPEED_MPS; accelerate / brake beyond +-PHASE_ACCEL_MPS2; cruise otherwise."""
    if speed_mps < STANDSTILL_SPEED_MPS:
        return "standstill"
    if accel_mps2 is None or abs(accel_mps2) <= PHASE_ACCEL_MPS2:
        return "cruise"
    return "accelerate" if accel_mps2 > 0 else "brake"
