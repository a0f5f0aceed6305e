"""The C allocator of a slipdaq process: blocks of MMAP_THRESHOLD_BYTES and more mapped on their own, whatever came
before, so that the memory of a transient array goes back to the system when the array is freed.

glibc's malloc starts with a 128 kB threshold and raises it to the size of each mapped block that is freed (up to
32 MB): after a maneuver's summary has freed its 8–16 MB model grids (maneuver/mu_joint.py), later blocks up to that
size come from the heap (the main one, or the summary thread's arena), whose free memory is given back only when
2 x the threshold lies free at its top. The resident set then keeps, or not, several MB of freed arrays depending on
the order of allocations, and its largest value over a run grows with the run's length (a 70-minute import peaked
7 MB higher than a 4.4-minute one, all of it within one summary). mallopt(M_MMAP_THRESHOLD) fixes the threshold
(and so the trim threshold) at glibc's own start value.

`fix_malloc_thresholds()` is called once by the process's entry (`python -m slipdaq`, the `slipdaq` command); other
C libraries (musl, macOS) have no such call and are left as they are.
"""

from __future__ import annotations

import ctypes
import ctypes.util
import platform

M_MMAP_THRESHOLD = -3
"""mallopt's parameter number (malloc.h)."""
MMAP_THRESHOLD_BYTES = 128 * 1024
"""glibc's default start value (DEFAULT_MMAP_THRESHOLD_MIN)."""


def fix_malloc_thresholds() -> bool:
    """The mmap threshold held at MMAP_THRESHOLD_BYTES; False where the C library is not glibc (nothing done)."""
    if platform.libc_ver()[0] != "glibc":
        return False
    try:
        libc = ctypes.CDLL(ctypes.util.find_library("c") or "libc.so.6")
        return bool(libc.mallopt(M_MMAP_THRESHOLD, MMAP_THRESHOLD_BYTES))
    except (OSError, AttributeError):
        return False
