"""Records pickled as a call of their class with their fields' values: a frozen dataclass with slots otherwise
unpickles through dataclasses' __setstate__, a fields() lookup and an object.__setattr__ per field, about four times
the time (what a replay's log process unpickles for each estimate: offline/log_process.py; what a two-pass run's first
pass is fed: offline/first_pass_feed.py)."""

from __future__ import annotations

import copyreg
from dataclasses import fields
from operator import attrgetter
from typing import Any


def by_fields(*classes: type) -> None:
    """Each class (a dataclass whose __init__ takes every field, in order, and keeps it as given) pickled as
    cls(*values) through copyreg's dispatch table."""
    for cls in classes:
        names = tuple(f.name for f in fields(cls))
        if len(names) < 2 or any(not f.init for f in fields(cls)):
            raise TypeError(f"{cls.__name__}: not a record of two or more fields its __init__ takes")
        values = attrgetter(*names)

        def reduce(record: Any, cls: type = cls, values: attrgetter[Any] = values) -> tuple[type, tuple[Any, ...]]:
            return cls, values(record)

        copyreg.pickle(cls, reduce)
