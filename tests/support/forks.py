"""The processes a test's code forks: every fork of this process, and the children it has now (none left behind)."""

from __future__ import annotations

import os
from collections.abc import Callable, Iterable, Iterator
from contextlib import contextmanager
from typing import Any

import pytest

FORKS: list[int] = []
"""The pid of the process that forked, once per fork since this module was imported."""
os.register_at_fork(before=lambda: FORKS.append(os.getpid()))


def children() -> list[str]:
    """This process's children now (their pids), from /proc."""
    with open(f"/proc/{os.getpid()}/task/{os.getpid()}/children") as f:
        return f.read().split()


def failing_in_a_child(decode: Callable[[Any], Iterable[Any]], after: int) -> Callable[[Any], Iterator[Any]]:
    """decode, whose record after `after` raises ValueError("a record that cannot be decoded") in a forked process only
    (a process that reads the log beside the run)."""
    parent = os.getpid()

    def failing(messages: Any) -> Iterator[Any]:
        for k, r in enumerate(decode(messages)):
            if k == after and os.getpid() != parent:
                raise ValueError("a record that cannot be decoded")
            yield r
    return failing


@contextmanager
def made_here(monkeypatch: pytest.MonkeyPatch) -> Iterator[dict[str, int]]:
    """Within the block, the calls made in this process (not a forked one) of the wheel decoder ("decode_batch") and
    of the log's reader ("messages": iter_raw_messages), counted."""
    from slipdaq.decode.can_wheels import WheelDecoder
    from slipdaq.logformat import reader

    here = {"decode_batch": 0, "messages": 0}
    parent = os.getpid()

    def counted(name: str, f: Any) -> Any:
        def call(*args: Any, **kwargs: Any) -> Any:
            here[name] += os.getpid() == parent
            return f(*args, **kwargs)
        return call

    with monkeypatch.context() as m:
        m.setattr(WheelDecoder, "decode_batch", counted("decode_batch", WheelDecoder.decode_batch))
        m.setattr(reader, "iter_raw_messages", counted("messages", reader.iter_raw_messages))
        yield here
