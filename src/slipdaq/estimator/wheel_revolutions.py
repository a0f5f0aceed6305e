"""The wheels' revolutions over time (one ring per wheel, in time order) and what a window takes from them: the arc
2*pi*N rolled over [t0, t1] (revolutions interpolated linearly at both ends), and the driven wheels' slip against
the non-driven ones (slip_nd)."""

from __future__ import annotations

import math

import numpy as np

from slipdaq import WHEELS
from slipdaq.estimator.ring import SeriesRing

TWO_PI = 2.0 * math.pi
MIN_GAP_S = 0.05
"""A wheel's samples with an interval longer than max(MIN_GAP_S, GAP_INTERVALS * its mean interval) inside a window
make the window disturbed: a reader stall (its frames stamped late, in a burst) or many frames lost. Its arc is
withheld (linear interpolation across the gap would put the stalled revolutions in the wrong window)."""
GAP_INTERVALS = 4.0


def slip_from_distances(d_wpt_m: float, d_gps_m: float) -> float:
    """s = (d_wpt - d_gps) / d_gps."""
    return (d_wpt_m - d_gps_m) / d_gps_m


def has_gap(ring: SeriesRing, t0: float, t1: float) -> bool:
    """The samples spanning [t0, t1] have an interval over max(MIN_GAP_S, GAP_INTERVALS * the mean interval)."""
    return ring.longest_gap(t0, t1) > max(MIN_GAP_S, GAP_INTERVALS * ring.mean_interval())


class WheelWindows:
    def __init__(self) -> None:
        self.rings = [SeriesRing(4096) for _ in WHEELS]
        """By wheel index (WHEELS order)."""
        self.by_wheel = dict(zip(WHEELS, self.rings))

    def last_times(self) -> list[float]:
        return [r.last_t for r in self.rings]

    def append(self, wheel: np.ndarray, time_s: np.ndarray, revolutions: np.ndarray, keep: np.ndarray,
               start: int, stop: int) -> None:
        """The kept samples start..stop into their wheels' rings."""
        if stop - start == 1:
            if keep[start]:
                self.rings[wheel[start]].append(time_s[start], revolutions[start])
            return
        kept = np.flatnonzero(keep[start:stop])
        w = wheel[start:stop][kept]
        order = kept[np.argsort(w, kind="stable")]  # by wheel, each wheel's in record order
        t, revs = time_s[start:stop][order], revolutions[start:stop][order]
        at = 0
        for ring, n in zip(self.rings, np.bincount(w, minlength=len(self.rings)).tolist()):
            if n:
                ring.extend(t[at : at + n], revs[at : at + n])
                at += n

    def drop_before(self, t: float) -> None:
        for r in self.rings:
            r.drop_before = t

    def reporting(self, since_s: float) -> list[SeriesRing]:
        return [r for r in self.rings if len(r) and r.last_time >= since_s]

    def arcs_m(self, t0: float, t1: float) -> dict[str, float | None]:
        """Per wheel: 2*pi*revolutions over [t0, t1], or None without samples around both ends or across a gap."""
        return self.window(t0, t1)[0]

    def window(self, t0: float, t1: float) -> tuple[dict[str, float | None], tuple[str, ...]]:
        """arcs_m, and the wheels whose arc is missing for a gap in their samples, or for no samples past t1 after
        samples before t0 (disturbed: a reader stall, frames lost, a wheel that fell silent)."""
        ends = np.array((t0, t1))
        out: dict[str, float | None] = {}
        gaps: list[str] = []
        for w, ring in self.by_wheel.items():
            revs = ring.at(ends, t0, t1)
            if revs is None:
                if len(ring) and ring.first_time <= t0 and ring.last_t < t1:  # it was reporting: stalled or silent
                    gaps.append(w)
            elif has_gap(ring, t0, t1):
                gaps.append(w)
                revs = None
            out[w] = None if revs is None else TWO_PI * (revs[1] - revs[0])
        return out, tuple(gaps)


def reference_slip(arcs: dict[str, float | None], r0: dict[str, tuple[float, str]], reference: tuple[str, ...],
                   driven: tuple[str, ...], min_distance_m: float) -> dict[str, float]:
    """Driven wheels' slip against the mean distance of the non-driven wheels (valid while those roll freely), for
    the driven wheels that have one."""
    refs = [r0[w][0] * arc for w in reference if (arc := arcs[w]) is not None]
    if not refs or len(refs) < len(reference):
        return {}
    d_ref = sum(refs) / len(refs)
    if d_ref < min_distance_m:
        return {}
    return {w: slip_from_distances(r0[w][0] * arc, d_ref) for w in driven if (arc := arcs[w]) is not None}
