"""A growable ring of (time, value) samples kept contiguous in numpy arrays, for windowed look-ups."""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from slipdaq.compiled import kernel


class SeriesRing:
    """Samples in time order; `times`/`values` are contiguous views of the kept samples.

    Appending is O(1) amortised: when the arrays are full, samples older than `drop_before` (set by the
    owner) are dropped by one move of the rest to the front; the arrays double only when that frees nothing.
    """

    def __init__(self, capacity: int = 4096) -> None:
        self._t = np.empty(capacity, dtype=np.float64)
        self._v = np.empty(capacity, dtype=np.float64)
        self._start = 0
        self._end = 0
        self.drop_before = -np.inf
        self.last_t = -np.inf
        """The newest sample's time as a Python float (-inf when empty): readiness checks compare it per frame."""
        self.dropped = 0
        """Samples dropped from the front so far: `times[i]` is the (dropped + i)-th sample appended (the key of its
        line in line_cache)."""
        self._lines: dict[int, tuple[np.ndarray, np.ndarray]] = {}

    def __len__(self) -> int:
        return self._end - self._start

    @property
    def times(self) -> np.ndarray:
        return self._t[self._start : self._end]

    @property
    def values(self) -> np.ndarray:
        return self._v[self._start : self._end]

    @property
    def last_time(self) -> float:
        return self.last_t

    @property
    def first_time(self) -> float:
        return float(self._t[self._start]) if self._end > self._start else np.inf

    def longest_gap(self, t_first: float, t_last: float) -> float:
        """The longest interval between consecutive samples from the last one at or before t_first to the first one
        at or after t_last (the samples an interpolation over [t_first, t_last] uses); 0 when that is one sample."""
        return float(longest_gap()(self._t[self._start : self._end], t_first, t_last))

    def local_linear(self, times: np.ndarray, half: int) -> np.ndarray | None:
        """The values at `times` from a least-squares line through the 2*half+1 samples nearest each time (by
        index: those around the first sample at or after it), or None with fewer samples. Unlike linear
        interpolation between the two samples around a time, its noise from jittered sample times hardly depends on
        where the time falls between samples."""
        lines = self.local_lines(times, half)
        return None if lines is None else lines[0]

    def local_lines(self, times: np.ndarray, half: int) -> tuple[np.ndarray, np.ndarray] | None:
        """local_linear's values at `times` and the slopes of their lines (value per second), or None."""
        s, e = self._start, self._end
        if e - s < 2 * half + 1:
            return None
        out = np.empty(len(times))
        slopes = np.empty(len(times))
        local_lines()(self._t[s:e], self._v[s:e], times, half, out, slopes)
        return out, slopes

    def line_cache(self, half: int, per_call: int) -> tuple[np.ndarray, np.ndarray]:
        """The lines through 2*half+1 samples computed so far (keys, lines: cached_line_values), kept with the ring
        for the kernels that compute them fix after fix over overlapping times; room for at least LINE_CACHE_SIZE
        lines and twice the times of a call (per_call), so that one call's lines do not take each other's slots."""
        cache = self._lines.get(half)
        if cache is None or len(cache[0]) < 2 * per_call:
            size = max(LINE_CACHE_SIZE, 1 << (2 * per_call - 1).bit_length())
            cache = self._lines[half] = new_line_cache(size)
        return cache

    def count_from(self, t: float) -> int:
        """Samples at or after t."""
        return self._end - self._start - int(np.searchsorted(self.times, t, side="left"))

    def append(self, t: float, v: float) -> None:
        if self._end == len(self._t):
            self._make_room()
        self._t[self._end] = t
        self._v[self._end] = v
        self._end += 1
        self.last_t = float(t)

    def extend(self, ts: np.ndarray, vs: np.ndarray) -> None:
        """append() for each (t, v) in order, in bulk: _make_room runs at the same points, so the kept samples
        are the same as after one-by-one appends."""
        i, n = 0, len(ts)
        end = self._end
        if n and end + n <= len(self._t):  # room for all: the loop below in one step
            self._t[end : end + n] = ts
            self._v[end : end + n] = vs
            self._end = end + n
            self.last_t = float(ts[n - 1])
            return
        while i < n:
            if self._end == len(self._t):
                self._make_room()
            k = min(n - i, len(self._t) - self._end)
            self._t[self._end : self._end + k] = ts[i : i + k]
            self._v[self._end : self._end + k] = vs[i : i + k]
            self._end += k
            i += k
        if n:
            self.last_t = float(ts[n - 1])

    def _make_room(self) -> None:
        keep_from = self._start + int(np.searchsorted(self.times, self.drop_before, side="left"))
        n = self._end - keep_from
        if n > len(self._t) // 2:
            t = np.empty(2 * len(self._t), dtype=np.float64)
            v = np.empty(2 * len(self._v), dtype=np.float64)
        else:
            t, v = self._t, self._v
        t[:n] = self._t[keep_from : self._end]
        v[:n] = self._v[keep_from : self._end]
        self._t, self._v = t, v
        self.dropped += keep_from - self._start
        self._start, self._end = 0, n


def append_each(rings: Sequence[SeriesRing], ring: np.ndarray, ts: np.ndarray, vs: np.ndarray, keep: np.ndarray,
                start: int, stop: int) -> bool:
    """Each kept sample start..stop (keep: bool) appended to its ring of the four (ring: int64 indices), in order, as
    SeriesRing.append one by one: at once where every ring has room for its samples (extend's fast path); False,
    nothing appended, where one has not (or an index is not 0-3)."""
    a, b, c, d = rings
    ends = np.array((a._end, b._end, c._end, d._end), dtype=np.int64)
    last = np.empty(4)
    if not scatter_kept()(ring, ts, vs, keep, start, stop, a._t, a._v, b._t, b._v, c._t, c._v, d._t, d._v, ends,
                          last):
        return False
    for r, end, t in zip(rings, ends.tolist(), last.tolist()):
        if end != r._end:
            r._end = end
            r.last_t = t
    return True


def _scatter_kept(ring: np.ndarray, ts: np.ndarray, vs: np.ndarray, keep: np.ndarray, start: int, stop: int,
                  t0: np.ndarray, v0: np.ndarray, t1: np.ndarray, v1: np.ndarray, t2: np.ndarray, v2: np.ndarray,
                  t3: np.ndarray, v3: np.ndarray, ends: np.ndarray, last: np.ndarray) -> bool:
    """append_each's samples written after each ring's end (ends[k]; ring k's arrays t_k, v_k) in order; ends moved
    past them, last[k] the newest time written to ring k. False, nothing written, where an index is not 0-3 or a
    ring has no room for all of its samples."""
    n = np.zeros(4, dtype=np.int64)
    for i in range(start, stop):
        if keep[i]:
            k = ring[i]
            if k < 0 or k > 3:
                return False
            n[k] += 1
    if ends[0] + n[0] > len(t0) or ends[1] + n[1] > len(t1) or ends[2] + n[2] > len(t2) or ends[3] + n[3] > len(t3):
        return False
    for i in range(start, stop):
        if keep[i]:
            k = ring[i]
            e = ends[k]
            if k == 0:
                t0[e], v0[e] = ts[i], vs[i]
            elif k == 1:
                t1[e], v1[e] = ts[i], vs[i]
            elif k == 2:
                t2[e], v2[e] = ts[i], vs[i]
            else:
                t3[e], v3[e] = ts[i], vs[i]
            ends[k] = e + 1
            last[k] = ts[i]
    return True


scatter_kept = kernel(_scatter_kept, "boolean(int64[:], float64[:], float64[:], boolean[:], int64, int64, "
                      + ", ".join(["float64[:]"] * 8) + ", int64[:], float64[:])")
"""scatter_kept()(ring, ts, vs, keep, start, stop, t0, v0, ..., t3, v3, ends, last): see _scatter_kept (append_each)."""


def first_index(t: np.ndarray, x: float, lo: int, after: bool) -> int:
    """The first index from lo on with t > x (after) or t >= x: searchsorted's right or left side, for kernels."""
    hi = len(t)
    while lo < hi:
        mid = (lo + hi) // 2
        if t[mid] < x or (after and t[mid] == x):
            lo = mid + 1
        else:
            hi = mid
    return lo


MIN_LINE_SPAN_S = 1e-6
"""Samples spanning less than this are one instant to local_linear (a line through them has no slope)."""


LINE_CACHE_SIZE = 1024
"""Lines a ring's line_cache holds at least (a power of two): twice the latency rows' lagged times of a fix with the
default max_latency_s."""


def new_line_cache(size: int) -> tuple[np.ndarray, np.ndarray]:
    """An empty cache of `size` lines (a power of two) for cached_line_values: (keys, lines), every key -1."""
    return np.full(size, -1, dtype=np.int64), np.empty((size, 3))


def line_through(t: np.ndarray, v: np.ndarray, c: int, half: int) -> tuple[float, float, float]:
    """(mean time, mean value, slope) of the least-squares line through samples c - half .. c + half; slope 0 when
    they span less than MIN_LINE_SPAN_S (samples all at one instant, a burst stamped together: their mean). Samples
    are indexed by unsigned integers: numba then adds no check for a negative index to each access."""
    k = 2 * half + 1
    first = np.uint64(c - half)
    st = sv = 0.0
    for j in range(np.uint64(k)):
        st += t[first + j]
        sv += v[first + j]
    t_mean, v_mean = st / k, sv / k
    sxx = sxy = 0.0
    for j in range(np.uint64(k)):
        d = t[first + j] - t_mean
        sxx += d * d
        sxy += d * (v[first + j] - v_mean)
    slope = sxy / sxx if t[c + half] - t[c - half] > MIN_LINE_SPAN_S else 0.0
    return t_mean, v_mean, slope


def cached_line_values(t: np.ndarray, v: np.ndarray, times: np.ndarray, half: int, base: int, keys: np.ndarray,
                       lines: np.ndarray, out: np.ndarray, slopes: np.ndarray) -> None:
    """local_line_values with each line's (mean time, mean value, slope) kept in a cache (new_line_cache) under the
    key base + c, c its centre sample: base the count of samples before t[0] (SeriesRing.dropped), so that a key names
    the same samples, and so the same line, call after call while the ring grows and drops old samples; a line found
    there is the one line_through gives, the same bits. keys: a power of two of them (a line's slot: key modulo
    their number; another key in it is replaced)."""
    n = len(t)
    mask = len(keys) - 1
    last_c = -1
    t_mean = v_mean = slope = 0.0
    r = 0
    for q in range(len(times)):
        x = times[q]
        if q == 0:
            r = first_index(t, x, 0, False)
        else:  # as first_index(t, x, 0, False) over samples in order
            while r > 0 and t[r - 1] >= x:
                r -= 1
            while r < n and t[r] < x:
                r += 1
        c = min(max(r, half), n - half - 1)
        if c != last_c:
            key = base + c
            slot = key & mask
            if keys[slot] == key:
                t_mean, v_mean, slope = lines[slot, 0], lines[slot, 1], lines[slot, 2]
            else:
                t_mean, v_mean, slope = line_through(t, v, c, half)
                keys[slot] = key
                lines[slot, 0], lines[slot, 1], lines[slot, 2] = t_mean, v_mean, slope
            last_c = c
        out[q] = v_mean + slope * (x - t_mean)
        slopes[q] = slope


def local_line_values(t: np.ndarray, v: np.ndarray, times: np.ndarray, half: int, out: np.ndarray,
                      slopes: np.ndarray) -> None:
    """out[q]: the least-squares line through samples c - half .. c + half at times[q] (line_through), c the first
    sample at or after times[q] (kept within the samples); slopes[q]: that line's slope. A line is fitted once for
    consecutive times that share it. t in time order, as a ring keeps it: from the first time's sample on, each next
    one is found by stepping from the last (times a step apart are a sample or two apart), not by bisecting the ring
    again. cached_line_values with a cache of one line, this call's own (its two small arrays: about 30 ns)."""
    keys, lines = new_line_cache(1)
    cached_line_values(t, v, times, half, 0, keys, lines, out, slopes)


LINE_USES = (first_index, line_through, new_line_cache, cached_line_values, local_line_values)
"""The plain functions a kernel that fits local lines calls (its `uses`)."""

local_lines = kernel(local_line_values,
                     "void(float64[:], float64[:], float64[:], int64, float64[:], float64[:])", uses=LINE_USES)
"""local_lines()(t, v, times, half, out, slopes): see local_line_values (SeriesRing.local_lines)."""


def longest_gap_of(t: np.ndarray, t_first: float, t_last: float) -> float:
    """SeriesRing.longest_gap over the times t (in order)."""
    n = len(t)
    i = max(first_index(t, t_first, 0, True) - 1, 0)
    j = min(first_index(t, t_last, i, False) + 1, n)
    gap = 0.0
    for k in range(i + 1, j):
        gap = max(gap, t[k] - t[k - 1])
    return gap


longest_gap = kernel(longest_gap_of, "float64(float64[:], float64, float64)", uses=(first_index,))
"""longest_gap()(t, t_first, t_last): see longest_gap_of."""
