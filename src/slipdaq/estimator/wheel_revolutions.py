"""The wheels' revolutions over time (one ring per wheel, in time order) and what a window takes from them: the arc
2*pi*N rolled over [t0, t1] (revolutions interpolated linearly at both ends), and the driven wheels' slip against
the non-driven ones (slip_nd)."""

from __future__ import annotations

import math

import numpy as np

from slipdaq import WHEELS
from slipdaq.compiled import kernel
from slipdaq.estimator.numpy_rules import interp_at, search_with_guess
from slipdaq.estimator.ring import SeriesRing, append_each, first_index, longest_gap_of

TWO_PI = 2.0 * math.pi
MIN_GAP_S = 0.05
"""A wheel's samples with an interval longer than max(MIN_GAP_S, GAP_INTERVALS * its mean interval) inside a window
make the window disturbed: a reader stall (its frames stamped late, in a burst) or many frames lost. Its arc is
withheld (linear interpolation across the gap would put the stalled revolutions in the wrong window)."""
GAP_INTERVALS = 4.0


def slip_from_distances(d_wpt_m: float, d_gps_m: float) -> float:
    """s = (d_wpt - d_gps) / d_gps."""
    return (d_wpt_m - d_gps_m) / d_gps_m


def gap_limit(t: np.ndarray) -> float:
    """The longest interval a wheel's samples (times t, at least 2) may have across a window or a line:
    max(MIN_GAP_S, GAP_INTERVALS * their mean interval), as Python's max takes it. The mean interval is (newest -
    oldest) / (samples - 1): a stall followed by a burst of its samples does not change it."""
    n = len(t)
    limit = GAP_INTERVALS * ((t[n - 1] - t[0]) / (n - 1))
    return limit if limit > MIN_GAP_S else MIN_GAP_S


class WheelWindows:
    def __init__(self) -> None:
        self.rings = [SeriesRing(4096) for _ in WHEELS]
        """By wheel index (WHEELS order)."""
        self.by_wheel = dict(zip(WHEELS, self.rings))

    def last_times(self) -> list[float]:
        return [r.last_t for r in self.rings]

    def append(self, wheel: np.ndarray, time_s: np.ndarray, revolutions: np.ndarray, keep: np.ndarray,
               start: int, stop: int) -> None:
        """The kept samples start..stop into their wheels' rings (wheel: int64 indices, keep: bool)."""
        if stop - start == 1:
            if keep[start]:
                self.rings[wheel[start]].append(time_s[start], revolutions[start])
            return
        if append_each(self.rings, wheel, time_s, revolutions, keep, start, stop):
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
        out: dict[str, float | None] = {}
        gaps: list[str] = []
        arc_of = window_arc()
        for w, ring in self.by_wheel.items():
            code, arc = arc_of(ring.times, ring.values, t0, t1)
            out[w] = float(arc) if code == ARC else None  # a Python float, as numba gives it
            if code == ARC_GAP:
                gaps.append(w)
        return out, tuple(gaps)


ARC_NONE, ARC_GAP, ARC = 0, 1, 2
"""window_arc's answers: no arc (no samples around both ends), none for a gap (or a stall), an arc."""


def _window_arc(t: np.ndarray, v: np.ndarray, t0: float, t1: float) -> tuple[int, float]:
    """One wheel's samples (times t, revolutions v) over [t0, t1]: (ARC, 2*pi*(N(t1) - N(t0))) with N interpolated
    linearly (np.interp); (ARC_GAP, nan) where the samples spanning the window have an interval over gap_limit, or
    stop before t1 after samples before t0; (ARC_NONE, nan) otherwise."""
    n = len(t)
    if n < 2 or t[0] > t0 or t[n - 1] < t1:
        stalled = n > 0 and t[0] <= t0 and t[n - 1] < t1
        return (ARC_GAP if stalled else ARC_NONE), np.nan
    if longest_gap_of(t, t0, t1) > gap_limit(t):
        return ARC_GAP, np.nan
    n0, j = interp_at(t0, t, v, 0)  # np.interp(ends, t, v): the second end's search from the first's
    n1, _ = interp_at(t1, t, v, j)
    return ARC, TWO_PI * (n1 - n0)


window_arc = kernel(_window_arc, "Tuple((int64, float64))(float64[:], float64[:], float64, float64)",
                    uses=(first_index, longest_gap_of, gap_limit, search_with_guess, interp_at))
"""window_arc()(t, v, t0, t1): see _window_arc (WheelWindows.window)."""


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
