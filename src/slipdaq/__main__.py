"""`python -m slipdaq` and the `slipdaq` command: the CLI, its modules imported with the garbage collector paused and
then frozen out of its reach (gc.freeze): they make about 200,000 objects that live as long as the process, and
collections that walk them free nothing (a fifth of the start-up).

python-can imports asammdf when it is installed (the `mdf` extra), for its MF4 reader and writer, and asammdf
imports pandas and sympy: 0.65-1.5 s of a start. Only `import` reads files through python-can, and only an MF4 file
(`--mf4`, or a `.mf4` log) through asammdf, so every other command imports python-can as if asammdf were absent;
asammdf itself stays importable (`export --mf4` imports it). `replay`, `report` and `export` import python-can (with
cantools) only where they parse a DBC (import_cantools): a wheel layout kept in the cache spares them both
(decode/can_wheels.py).

numpy's OpenBLAS runs on one thread unless OPENBLAS_NUM_THREADS says otherwise: slipdaq's matrix products are
small, or memory-bound (the maneuver fits' bootstrap: 40 products of a 1920 x n grid by a vector), where a second
thread only contends with the process's own (the log's compression): a 300 s replay took 0.84x the wall time and
0.84x the CPU with it, the same bytes.

The commands that log for hours (ALLOCATOR_FIXED_VERBS) hold glibc's mmap and trim thresholds fixed
(slipdaq/allocator.py): a transient array's memory goes back to the system when it is freed, and the peak does not grow
with the run. Other commands keep glibc's own: mapping each block of 1 MB and more anew costs a 300 s replay 5 % of
its time (1.05x wall and CPU, 3 interleaved rounds)."""

import gc
import os
import sys
from collections.abc import Sequence
from types import ModuleType

PYTHON_CAN_MF4_VERBS = frozenset({"import"})
"""The verbs that may read a file through python-can's LogReader (an .mf4 one needs python-can's MF4Reader)."""


PYTHON_CAN_AT_NEED_VERBS = frozenset({"replay", "report", "export", "batch"})
"""The verbs that import python-can only where they need it: with cantools, to parse a DBC whose wheel layout is not
in the cache (decode/can_wheels.py), or to decode other sensors' signals (import_cantools)."""


ALLOCATOR_FIXED_VERBS = frozenset({"run", "demo", "import"})
"""The verbs whose process holds the allocator's thresholds fixed: a live day's run, and an import of a day's log."""

OFFLINE_VERBS = frozenset({"import", "replay", "report", "export", "batch"})
"""The verbs that process whole logs as fast as they can: their processes (and those they fork) collect the garbage
collector's youngest generation every OFFLINE_GC_THRESHOLD[0] new containers, not Python's 700. A run makes millions
of short-lived containers, which reference counting frees; each collection walks the young ones still alive (a 300 s
replay: 4 collections in place of 181, 0.012 s in place of 0.051 s; docs/performance.md, "The garbage collector in
offline runs"). Live verbs keep Python's thresholds, whose pauses are shorter."""
OFFLINE_GC_THRESHOLD = (10_000, 10, 10)


def verb_of(argv: Sequence[str]) -> str | None:
    """The verb of a command line (its first word that is not an option), None without one."""
    return next((a for a in argv if not a.startswith("-")), None)


def reads_mf4(argv: Sequence[str]) -> bool:
    """A command line that may read an MF4 file through python-can: a verb of PYTHON_CAN_MF4_VERBS with `--mf4` or
    an argument naming a .mf4 file (python-can picks its reader by the suffix)."""
    return verb_of(argv) in PYTHON_CAN_MF4_VERBS and any(
        a == "--mf4" or a.startswith("--mf4=") or ".mf4" in a.lower() for a in argv)


def import_python_can(with_mf4: bool) -> None:
    """python-can imported now; with_mf4=False: as if asammdf were not installed (its MF4 reader and writer then
    refuse to work, the rest of python-can is the same). Nothing happens once python-can is imported."""
    if "can" in sys.modules:
        return
    hide = not with_mf4 and "asammdf" not in sys.modules
    if hide:
        sys.modules["asammdf"] = None  # type: ignore[assignment]  # an import of it raises ImportError
    try:
        import can  # noqa: F401
    finally:
        if hide and sys.modules.get("asammdf", 0) is None:
            del sys.modules["asammdf"]


def import_cantools() -> ModuleType:
    """cantools, imported where it is first needed (a DBC to parse), python-can with it as import_python_can(False)
    has it (cantools imports python-can)."""
    import_python_can(with_mf4=False)
    import cantools

    return cantools


def main() -> int:
    os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")  # read when numpy loads OpenBLAS: before any import of numpy
    if verb_of(sys.argv[1:]) in ALLOCATOR_FIXED_VERBS:
        from slipdaq.allocator import fix_malloc_thresholds  # ctypes.util: 10 ms, for these verbs only

        fix_malloc_thresholds()  # before the first large block (slipdaq/allocator.py)
    if verb_of(sys.argv[1:]) in OFFLINE_VERBS:
        gc.set_threshold(*OFFLINE_GC_THRESHOLD)
    gc.disable()
    try:
        if verb_of(sys.argv[1:]) not in PYTHON_CAN_AT_NEED_VERBS:
            import_python_can(with_mf4=reads_mf4(sys.argv[1:]))
        from slipdaq.cli import main as cli_main

        gc.freeze()
    finally:
        gc.enable()
    return cli_main()


if __name__ == "__main__":
    sys.exit(main())
