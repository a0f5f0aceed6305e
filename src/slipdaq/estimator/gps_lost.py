"""While GPS is lost: an estimate every WHEEL_ONLY_STEP_S on the wheels' clock, from the wheels alone: speed and
acceleration from the reference (non-driven) wheels' distance, each wheel's speed, and the driven wheels' slip
against the reference wheels (slip_nd). No GPS distance: no slip, Re, force or Cx."""

from __future__ import annotations

import math

from slipdaq import WHEELS
from slipdaq.estimator.latency import LatencyEstimate
from slipdaq.estimator.phase import phase_of
from slipdaq.estimator.wheel_revolutions import WheelWindows, reference_slip
from slipdaq.records import Estimate, WheelEstimate

WHEEL_ONLY_STEP_S = 0.1


class WheelClockEstimates:
    def __init__(self, window_s: float, reference: tuple[str, ...], driven: tuple[str, ...],
                 min_distance_m: float) -> None:
        self.window_s = window_s
        self.reference = reference
        self.driven = driven
        self.min_distance_m = min_distance_m
        self.next_s: float | None = None
        """The next estimate's centre; None until GPS is lost (again)."""

    def due(self, windows: WheelWindows, r0: dict[str, tuple[float, str]], lat: LatencyEstimate,
            last_center_s: float, gps_last_t: float) -> list[Estimate]:
        """The estimates whose windows the reporting wheels cover now."""
        half = 0.5 * self.window_s
        rings = windows.reporting(-math.inf)
        if not rings:
            return []
        covered = min(r.last_time for r in rings)
        if self.next_s is None:
            start = max(last_center_s, gps_last_t) + WHEEL_ONLY_STEP_S
            self.next_s = max(start, max(r.first_time for r in rings) + half)
        out: list[Estimate] = []
        while self.next_s + half <= covered:
            t_c = self.next_s
            self.next_s = t_c + WHEEL_ONLY_STEP_S
            out.append(self._estimate(windows, r0, t_c, lat))
        return out

    def _estimate(self, windows: WheelWindows, r0: dict[str, tuple[float, str]], t_c: float,
                  lat: LatencyEstimate) -> Estimate:
        window_s = self.window_s
        half = 0.5 * window_s
        refs = self.reference or WHEELS

        def ref_distance(arcs: dict[str, float | None]) -> float | None:
            ds = [r0[w][0] * arc for w in refs if (arc := arcs[w]) is not None]
            return sum(ds) / len(ds) if ds else None

        arcs = windows.arcs_m(t_c - half, t_c + half)
        d = ref_distance(arcs)
        first, second = ref_distance(windows.arcs_m(t_c - half, t_c)), ref_distance(windows.arcs_m(t_c, t_c + half))
        speed = d / window_s if d is not None else 0.0
        accel = (second - first) / (half * half) if first is not None and second is not None else None
        slip_nd = reference_slip(arcs, r0, self.reference, self.driven, self.min_distance_m)
        wheels = {
            w: WheelEstimate(None, None, r0[w][0], None, None,
                             r0[w][0] * arc / window_s if (arc := arcs[w]) is not None else None,
                             r0[w][1], slip_nd.get(w))
            for w in WHEELS
        }
        return Estimate(t_c, speed, accel, None, window_s, wheels, phase=phase_of(speed, accel),
                        source="wheels", gps_latency_s=lat.latency_s, latency_source=lat.source,
                        quality="disturbed")
