"""The estimator's wheel input written sample by sample in Python, as it was before the readiness kernel: the
oracle SlipEstimator.add_wheels (estimator/readiness.py) is checked against. Not used by slipdaq."""

from __future__ import annotations

from slipdaq.estimator import SlipEstimator
from slipdaq.estimator.readiness import GPS_LOST_AFTER_S
from slipdaq.records import Estimate


class ReferenceEstimator(SlipEstimator):
    def add_wheel_at(self, wheel: int, time_s: float, revolutions: float) -> list[Estimate]:
        ring = self._windows.rings[wheel]
        if time_s < ring.last_t:
            return []  # out of order: keep the ring monotonic
        ring.append(time_s, revolutions)
        if time_s - self._track.last_t > GPS_LOST_AFTER_S:
            return self._gps_lost()
        if not self._pending:
            return []
        mode, need, since = self._head or self._head_consts()
        if mode == 0:
            return []
        if mode == 2:
            for r in self._windows.rings:
                if since <= r.last_t < need:
                    return []  # a reporting wheel has not reached the window's end yet
        return self._drain()
