"""Free-rolling radius r0 per wheel, calibrated online from windows where the tire carries little force.

r0 = sum(d_gps) / sum(2*pi*N) over free-rolling windows (a distance-weighted ratio, = V/omega), with a standard
error from the spread of the per-window Re (overlapping windows counted as one per window length).
- usable ('calibrating') once the standard error is below `usable_se_m` (1.5 mm): a tire-size radius is typically
  off by more than that (the loaded radius is several mm below the free one);
- converged ('calibrated') below `converged_se_m` (0.3 mm).
After convergence old windows fade with distance (`track_distance_m`), so r0 tracks wear, pressure and load slowly.
A driven wheel carries a force F in those windows (in cruise the road loads), a slip s = F/Cx: with road loads known
(and the tire's Cx), r0 = (sum(d_gps) + sum(d_gps*F)/Cx) / sum(2*pi*N), since omega*r0 = V*(1 + s).
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass


@dataclass(slots=True)
class RadiusCalibration:
    converged_se_m: float = 0.0003
    usable_se_m: float = 0.0015
    track_distance_m: float = 2000.0
    min_independent_windows: float = 3.0
    independent_per_window: float = 0.2
    """One window of W seconds every fix interval: W / interval windows overlap; 0.1 s / 0.5 s = 0.2."""
    gps_m: float = 0.0
    arc_m: float = 0.0
    sum_w_re: float = 0.0
    sum_w_re2: float = 0.0
    windows: float = 0.0
    converged: bool = False
    road_nm: float = 0.0
    """sum(weight*d_gps*F_road) [N*m]: the road loads this wheel carried over the windows (0 without road loads)."""
    cx_n: float | None = None
    """The tire's Cx for the road loads' slip (None: no correction)."""

    def add(self, gps_distance_m: float, arc_m: float, weight: float = 1.0, road_n: float = 0.0) -> None:
        """One free-rolling window: GPS distance and 2*pi*revolutions; weight from the GPS's stated accuracy; road_n:
        the road loads this tire carried (a driven one)."""
        if arc_m <= 0 or gps_distance_m <= 0:
            return
        lam = math.exp(-gps_distance_m / self.track_distance_m) if self.converged else 1.0
        re = gps_distance_m / arc_m
        w = weight * gps_distance_m
        if road_n or self.road_nm:
            self.road_nm = lam * self.road_nm + w * road_n
        self.gps_m = lam * self.gps_m + w
        self.arc_m = lam * self.arc_m + weight * arc_m
        self.sum_w_re = lam * self.sum_w_re + w * re
        self.sum_w_re2 = lam * self.sum_w_re2 + w * re * re
        self.windows = lam * self.windows + 1.0
        if not self.converged:
            se = self.standard_error_m
            self.converged = (
                se is not None and se <= self.converged_se_m
                and self.windows * self.independent_per_window >= self.min_independent_windows
            )

    @property
    def usable(self) -> bool:
        se = self.standard_error_m
        return self.converged or (
            se is not None and se <= self.usable_se_m and self.windows * self.independent_per_window >= 0.6
        )

    @property
    def radius_m(self) -> float | None:
        if self.arc_m <= 0:
            return None
        if self.road_nm and self.cx_n:
            return (self.gps_m + self.road_nm / self.cx_n) / self.arc_m
        return self.gps_m / self.arc_m

    @property
    def standard_error_m(self) -> float | None:
        if self.windows < 2 or self.gps_m <= 0:
            return None
        mean = self.sum_w_re / self.gps_m
        var = max(self.sum_w_re2 / self.gps_m - mean * mean, 0.0)
        n = max(self.windows * self.independent_per_window, 1.0)
        return math.sqrt(var / n)


def r0_per_wheel(calibrations: dict[str, RadiusCalibration], r_ref_m: float, r_ref_configured: bool,
                 calibrate: bool, stored: Mapping[str, float] | None = None, own: bool = True
                 ) -> dict[str, tuple[float, str]]:
    """(r0, source) per wheel: its stored radius ('stored') until its own calibration converges, else its own when
    usable, else the mean of the other wheels' ('other_wheels'), else the reference radius (tire.free_radius_m,
    'configured', or the tire size, 'tire_size'). own=False: the stored radii only (a second pass)."""
    base = "configured" if r_ref_configured else "tire_size"
    if not calibrate:
        return {w: (r_ref_m, base) for w in calibrations}
    stored = stored or {}
    chosen: dict[str, tuple[float, str]] = {}  # in wheel order
    for w, cal in calibrations.items():
        radius = cal.radius_m
        mine = own and radius is not None and cal.usable
        if w in stored and not (mine and cal.converged):
            chosen[w] = (stored[w], "stored")
        elif mine:
            assert radius is not None
            chosen[w] = (radius, "calibrated" if cal.converged else "calibrating")
    others = [r for r, _ in chosen.values()]
    fallback = (sum(others) / len(others), "other_wheels") if others else (r_ref_m, base)
    return {w: chosen.get(w, fallback) for w in calibrations}
