"""When wheel samples release an estimate: the scan over a batch of wheel samples, sample by sample, in one kernel.

The head epoch (the oldest pending GPS epoch) has a readiness (SlipEstimator._head_consts):
  mode 0: not before a later fix; 1: ready; 2: ready once every reporting wheel (newest sample at or after `since`)
  has a sample at or after `need`.
A sample older than its wheel's newest is skipped (each wheel's ring stays in time order). A sample more than
GPS_LOST_AFTER_S after the newest fix means GPS is lost.
"""

from __future__ import annotations

import numpy as np

from slipdaq.compiled import kernel

GPS_LOST_AFTER_S = 1.0
"""With no GPS fix for this long, estimates continue on the wheels' clock (slip against non-driven wheels)."""

MODE_WAIT, MODE_READY, MODE_WHEELS = 0, 1, 2
SCAN_END, SCAN_READY, SCAN_GPS_LOST = 0, 1, 2


def head_ready(last_t: np.ndarray | list[float], mode: int, need: float, since: float) -> bool:
    """The head epoch is ready, its wheels' newest samples at last_t (per wheel)."""
    if mode != MODE_WHEELS:
        return mode == MODE_READY
    for j in range(len(last_t)):
        if since <= last_t[j] < need:
            return False  # a reporting wheel has not reached the window's end yet
    return True


def _scan(wheel: np.ndarray, time_s: np.ndarray, start: int, last_t: np.ndarray, keep: np.ndarray,
          gps_last_t: float, mode: int, need: float, since: float) -> tuple[int, int]:
    """From position `start`, each sample in turn: keep[k] says whether it goes into its wheel's ring (last_t, per
    wheel, moves on with it); stops at the first kept sample after which GPS is lost or the head epoch is ready.
    Returns (that position, SCAN_GPS_LOST or SCAN_READY), or (len(wheel), SCAN_END)."""
    for k in range(start, len(wheel)):
        w = wheel[k]
        t = time_s[k]
        if t < last_t[w]:
            keep[k] = False
            continue
        keep[k] = True
        last_t[w] = t
        if t - gps_last_t > GPS_LOST_AFTER_S:
            return k, SCAN_GPS_LOST
        if mode != MODE_WAIT and head_ready(last_t, mode, need, since):
            return k, SCAN_READY
    return len(wheel), SCAN_END


scan_samples = kernel(_scan, "UniTuple(int64, 2)(int64[:], float64[:], int64, float64[:], boolean[:], float64, int64, "
                             "float64, float64)", uses=(head_ready,))
"""scan_samples()(...): see _scan."""
