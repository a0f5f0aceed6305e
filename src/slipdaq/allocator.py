"""The C allocator of a slipdaq process: blocks of MMAP_THRESHOLD_BYTES and more mapped on their own, whatever came
before, so that the memory of a large transient array goes back to the system when the array is freed.

glibc's malloc starts with a 128 kB mmap threshold and raises it to the size of each mapped block that is freed (up
to 32 MB), and its trim threshold to twice that: after a maneuver's summary has freed its 8–16 MB model grids
(maneuver/mu_joint.py), later blocks up to that size come from the heap (the main one, or the summary thread's
arena), whose free memory goes back to the system only when twice that lies free at its top. The resident set then
keeps several MB of freed arrays, or not, depending on the order of allocations, and its largest value over a run
grows with the run's length. Both thresholds are held fixed instead: MMAP_THRESHOLD_BYTES (the summary's arrays of
1 MB and more are mapped on their own; at glibc's 128 kB start value every chunk and commit buffer of the log would
be mapped and faulted anew: 20 times the system time of an import) and TRIM_THRESHOLD_BYTES (twice it, glibc's own
ratio).

`fix_malloc_thresholds()` is called once by the process's entry for the verbs that log for hours (`run`, `demo`,
`import`: `__main__.ALLOCATOR_FIXED_VERBS`; a replay mapping its 1 MB blocks anew would take 5 % longer); other
C libraries (musl, macOS) have no such call and are left as they are.

Free memory among blocks still in use stays in the heap whatever the thresholds, and each thread that allocates (the
event loop, the log's compression, the maneuver summaries) gets an arena of its own from glibc, a heap that fills and
fragments apart from the others. The same processes keep one arena (M_ARENA_MAX = ARENAS_MAX: the threads share the
main heap), and the live daemon gives the whole free pages among the blocks in use back as each maneuver arrives
(its summary's arrays are freed as it ends) and every RELEASE_EVERY_S (`release_free_memory()`, glibc's
`malloc_trim(0)`: about 1 MB each time, in 0.2–2 ms, in the soak on the 2-core machine).
"""

from __future__ import annotations

import ctypes
import ctypes.util
import functools
import platform

M_TRIM_THRESHOLD = -1
M_MMAP_THRESHOLD = -3
M_ARENA_MAX = -8
"""mallopt's parameter numbers (malloc.h)."""
MMAP_THRESHOLD_BYTES = 1 << 20
TRIM_THRESHOLD_BYTES = 2 * MMAP_THRESHOLD_BYTES
ARENAS_MAX = 1
RELEASE_EVERY_S = 30.0
"""How often a live run gives its free pages back (release_free_memory)."""


@functools.cache
def _glibc() -> ctypes.CDLL | None:
    """The process's C library when it is glibc, else None."""
    if platform.libc_ver()[0] != "glibc":
        return None
    try:
        return ctypes.CDLL(ctypes.util.find_library("c") or "libc.so.6")
    except OSError:
        return None


def fix_malloc_thresholds() -> bool:
    """glibc's mmap and trim thresholds held at MMAP_THRESHOLD_BYTES and TRIM_THRESHOLD_BYTES, and at most ARENAS_MAX
    arenas (called before the process's threads start); False where the C library is not glibc (nothing done)."""
    libc = _glibc()
    try:
        return libc is not None and bool(libc.mallopt(M_MMAP_THRESHOLD, MMAP_THRESHOLD_BYTES)) and \
            bool(libc.mallopt(M_TRIM_THRESHOLD, TRIM_THRESHOLD_BYTES)) and bool(libc.mallopt(M_ARENA_MAX, ARENAS_MAX))
    except AttributeError:
        return False


def release_free_memory() -> bool:
    """glibc's malloc_trim(0): the whole free pages of the heap and of every thread's arena back to the system. True
    when some memory went back; False when none did, or where the C library is not glibc (nothing done)."""
    libc = _glibc()
    try:
        return libc is not None and bool(libc.malloc_trim(0))
    except AttributeError:
        return False
