"""Per-sample loops (kernels) compiled with numba.

A kernel is one plain Python function over numpy arrays and numbers, written in the subset numba compiles: the rule
lives once, whatever the batch (one frame is a batch of one). `kernel()` returns the compiled function: from the
extension module that holds every kernel compiled ahead of time (ahead.py: built once per version, imported in
under a millisecond), else numba's JIT (compiled once per machine, `cache=True`, loaded from its cache after that:
numba's import and the load take about 0.35 s). SLIPDAQ_JIT=0 in the environment, or numba missing, runs the same
function interpreted (about 3 us a sample, against 1.8 us a call compiled: docs/architecture.md). The tests run
them all and check they agree bit for bit.

The kernels are loaded on the first kernel call: a run calls `prepare()` before its sources start, so that the
first frames do not wait for it.
"""

from __future__ import annotations

import os
import sys
import threading
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from typing import Any, Generic, TypeVar, cast

from slipdaq.compiled import ahead, registry

F = TypeVar("F", bound=Callable[..., Any])

_lock = threading.RLock()  # reentrant: the module compiled ahead of time is found with it held, importing modules
_kernels: list[Kernel[Any]] = registry.KERNELS


def jit_enabled() -> bool:
    return os.environ.get("SLIPDAQ_JIT", "1") != "0"


class Kernel(Generic[F]):
    """`kernel()` is the function to run: compiled, or the Python function itself where numba is off or missing."""

    def __init__(self, fn: F, signature: str, uses: tuple[Callable[..., Any], ...] = ()) -> None:
        self.py_func = fn
        self.signature = signature
        self.uses = uses
        self.export_name = f"{fn.__module__.removeprefix('slipdaq.').replace('.', '_')}_{fn.__name__.lstrip('_')}"
        """Its name in the module compiled ahead of time."""
        self._run: F | None = None
        _kernels.append(self)

    def __call__(self) -> F:
        run = self._run
        if run is None:
            with _lock:
                if self._run is None:
                    self._run = self._choose()
                run = self._run
        return run

    def reset(self) -> None:
        """Decide again on the next call (after SLIPDAQ_JIT or SLIPDAQ_AOT changed)."""
        self._run = None

    def _choose(self) -> F:
        if not jit_enabled():
            return self.py_func
        built = ahead.module() if ahead.enabled() else None
        run = getattr(built, self.export_name, None)
        return cast(F, run) if run is not None else self._compile()

    def _compile(self) -> F:
        with _without_scipy_blas():
            return self._compile_now()

    def _compile_now(self) -> F:
        try:
            import numba
            from numba.extending import register_jitable
        except ImportError:
            return self.py_func
        for fn in self.uses:  # plain functions the kernel calls: compiled where it is
            register_jitable(fn)
        # the signature makes numba compile (or load from its cache) now, not at the first call
        try:
            return cast(F, numba.njit(self.signature, cache=True, nogil=True)(self.py_func))
        except RuntimeError:  # no writable cache directory (a service user without a home): compile in memory
            return cast(F, numba.njit(self.signature, cache=False, nogil=True)(self.py_func))


SCIPY_LINALG = "scipy.linalg"
NUMBA_ARRAYMATH = "numba.np.arraymath"


@contextmanager
def _without_scipy_blas() -> Iterator[None]:
    """numba's first kernel without scipy.linalg: numba's array maths, imported as the first kernel loads, imports
    scipy.linalg (0.15 s of CPU) only to call BLAS for np.dot of 1-d arrays, which no kernel here uses (1-d np.dot
    in a kernel would then sum in a loop, not as numpy does). scipy.linalg imports as usual afterwards; nothing is
    hidden where scipy.linalg or numba's array maths are imported already."""
    hide = SCIPY_LINALG not in sys.modules and NUMBA_ARRAYMATH not in sys.modules
    if hide:
        sys.modules[SCIPY_LINALG] = None  # type: ignore[assignment]  # its import raises ImportError meanwhile
    try:
        yield
    finally:
        if hide and SCIPY_LINALG in sys.modules and sys.modules[SCIPY_LINALG] is None:
            del sys.modules[SCIPY_LINALG]


def kernel(fn: F, signature: str, uses: tuple[Callable[..., Any], ...] = ()) -> Kernel[F]:
    """fn as a Kernel; signature: its numba types (arrays of any layout: `int64[:]`); `uses`: the plain functions
    (rules shared with Python code) it calls."""
    return Kernel(fn, signature, uses)


def kernels() -> list[Kernel[Any]]:
    """The kernels of the modules imported so far."""
    return list(_kernels)


def prepare() -> None:
    """Load every kernel of the modules imported so far (from the module compiled ahead of time, built first where
    it is missing; else numba's JIT, from its cache); their first call then runs at once, and processes forked
    afterwards have them loaded."""
    for k in list(_kernels):
        k()


def reset() -> None:
    ahead.forget()
    for k in list(_kernels):
        k.reset()
