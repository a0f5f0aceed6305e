"""The processes a test's code forks: every fork of this process, and the children it has now (none left behind)."""

from __future__ import annotations

import os

FORKS: list[int] = []
"""The pid of the process that forked, once per fork since this module was imported."""
os.register_at_fork(before=lambda: FORKS.append(os.getpid()))


def children() -> list[str]:
    """This process's children now (their pids), from /proc."""
    with open(f"/proc/{os.getpid()}/task/{os.getpid()}/children") as f:
        return f.read().split()
