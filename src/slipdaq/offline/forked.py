"""What every process forked beside an offline run shares (the log's, the summaries', a feed's): its start, its pipes,
and its error sent back to the run."""

from __future__ import annotations

import contextlib
import fcntl
import gc
import signal
import traceback
from collections.abc import Callable
from multiprocessing import get_context
from multiprocessing.connection import Connection
from typing import Any

PIPE_BYTES = 1 << 20
"""The size of the pipes to and from a process beside the run (a feed's, a log's process's calls) where the system
lets it be set (the default, 64 kB, takes 16 writes a megabyte)."""


def sized_pipe() -> tuple[Connection, Connection]:
    """(reading end, writing end) of a pipe of PIPE_BYTES where the system lets it be set."""
    reading, writing = get_context("fork").Pipe(duplex=False)
    if (set_size := getattr(fcntl, "F_SETPIPE_SZ", None)) is not None:  # Linux
        with contextlib.suppress(OSError):
            fcntl.fcntl(writing.fileno(), set_size, PIPE_BYTES)
    return reading, writing


def started(parent_ends: tuple[Connection, ...]) -> None:
    """A forked process's start: a ^C left to the run (which terminates it), what the run made before the fork out of
    the collector's reach (never walked here, nor copied for it), the run's ends of the pipes closed."""
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    gc.freeze()
    for end in parent_ends:
        end.close()


def send_error(send: Callable[[Any], None], error: BaseException, where: str,
               stand_in: Callable[[str], BaseException]) -> None:
    """The error back to the run, noted with where it was raised and its traceback; stand_in(text) in its place where
    it does not pickle."""
    error.add_note(f"in {where}:\n" + traceback.format_exc())
    try:
        send(error)
    except Exception:  # an error that does not pickle
        send(stand_in(f"{error!r} in {where}"))
