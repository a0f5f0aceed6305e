"""Per-sample loops (kernels) compiled with numba when a batch is large enough to pay for it.

A kernel is one plain Python function over numpy arrays and numbers, written in the subset numba compiles. The same
function runs interpreted for small batches (a live read of a few frames; no compile, no import of numba) and
compiled for large ones (replay, import): one rule, one source, and the tests check both give the same results
bit for bit. numba compiles a kernel once per machine (`cache=True`, next to the module) on its first large batch.

SLIPDAQ_JIT=0 in the environment keeps every kernel interpreted (numba absent works the same way).
"""

from __future__ import annotations

import os
import threading
from collections.abc import Callable
from typing import Any, Generic, TypeVar, cast

F = TypeVar("F", bound=Callable[..., Any])

JIT_MIN_SAMPLES = 256
"""Below this many samples a kernel runs interpreted: numba's call overhead and the first call's compile cost more
than the loop (benchmarks/batch_size.py)."""

_lock = threading.Lock()


def jit_enabled() -> bool:
    return os.environ.get("SLIPDAQ_JIT", "1") != "0"


class Kernel(Generic[F]):
    """`kernel(n)` is the function to run over a batch of n samples: compiled when n >= JIT_MIN_SAMPLES and numba is
    there, else the Python function itself."""

    def __init__(self, fn: F, uses: tuple[Callable[..., Any], ...] = ()) -> None:
        self.py_func = fn
        self.uses = uses
        self._compiled: F | None = None
        self._failed = False

    def __call__(self, n: int) -> F:
        if n < JIT_MIN_SAMPLES or self._failed or not jit_enabled():
            return self.py_func
        if self._compiled is None:
            with _lock:
                if self._compiled is None:
                    self._compiled = self._compile()
        return self._compiled

    def compiled(self) -> F:
        """The compiled function (compiling it now); the Python one where numba is missing."""
        return self(JIT_MIN_SAMPLES) if jit_enabled() else self.py_func

    def _compile(self) -> F:
        try:
            import numba  # lazily: 0.5 s to import, needed only by large batches
            from numba.extending import register_jitable
        except ImportError:
            self._failed = True
            return self.py_func
        for fn in self.uses:  # plain functions the kernel calls: compiled where it is
            register_jitable(fn)
        return cast(F, numba.njit(cache=True, nogil=True)(self.py_func))


def kernel(fn: F, uses: tuple[Callable[..., Any], ...] = ()) -> Kernel[F]:
    """fn as a Kernel; `uses`: the plain functions (kernels' rules shared with Python code) it calls."""
    return Kernel(fn, uses)
