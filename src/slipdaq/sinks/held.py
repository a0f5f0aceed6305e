"""A fan-out's calls held back, in order, behind results still being computed elsewhere (a maneuver's summary in
another process): each result goes out at the point it was awaited, the calls after it once it is in. The sinks get
the same calls in the same order as if every result had been there at once, however long each took."""

from __future__ import annotations

from collections import deque
from collections.abc import Callable
from concurrent.futures import Future
from typing import Any, TypeVar

from slipdaq.sinks import SINK_CALLS, Sink

HOLD_MAX_CALLS = 16384
"""More calls held than this: the first awaited result is waited for (what is held stays bounded). A replay makes
about 240 calls a second of 4 x 1 kHz, so this is about a minute of log: a run whose summaries fall behind while the
second core is busy (a two-pass replay's second pass) goes on meanwhile rather than waiting (docs/performance.md)."""


T = TypeVar("T")


class HeldCalls(Sink):
    """Takes a sink's calls and keeps them for `out`, with marks between them: a Future and what to do with its
    result. `release` passes them on in order up to the first mark whose result is not in yet."""

    def __init__(self, out: Sink) -> None:
        self._calls: deque[tuple[Callable[..., None] | None, Any]] = deque()
        self._out = {name: getattr(out, name) for name in SINK_CALLS}

    def __len__(self) -> int:
        return len(self._calls)

    def mark(self, result: Future[Any], deliver: Callable[[Any], None]) -> None:
        """Here, deliver(result's value) once it is in (an error it holds is raised by `release`)."""
        self._calls.append((None, (result, deliver)))

    def release(self, wait: bool = False) -> bool:
        """The calls held, in order, up to the first mark not done (wait: that one waited for, and past it what
        else is done); True when nothing is held any more."""
        calls = self._calls
        while calls:
            call, args = calls[0]
            if call is None:
                result, deliver = args
                if not (wait or result.done()):
                    return False
                wait = False
                calls.popleft()
                deliver(result.result())
            else:
                calls.popleft()
                call(*args)
        return True

    def release_all(self) -> None:
        """Every call held, each mark waited for in turn."""
        while not self.release(wait=True):
            pass


def ready(value: T) -> Future[T]:
    """A Future that holds value already."""
    f: Future[T] = Future()
    f.set_result(value)
    return f


def _held(name: str) -> Callable[..., None]:
    def call(self: HeldCalls, *args: Any) -> None:
        self._calls.append((self._out[name], args))
    call.__name__ = call.__qualname__ = name
    call.__doc__ = f"{name}, held."
    return call


for _name in SINK_CALLS:
    setattr(HeldCalls, _name, _held(_name))
