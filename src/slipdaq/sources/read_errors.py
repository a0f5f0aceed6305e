"""Errors while an input file is read: one line naming the file and how far reading got, whatever the reader raised."""

from __future__ import annotations

import logging
from collections.abc import Iterable, Iterator
from pathlib import Path
from typing import TypeVar

T = TypeVar("T")
log = logging.getLogger(__name__)


class InputError(Exception):
    """An input file that cannot be read; the message names the file (and where in it)."""


def _undecodable_line(path: Path, encoding: str) -> int | None:
    """The number of the first line of a text file that does not decode (None when none is found)."""
    try:
        with open(path, "rb") as f:
            for number, raw in enumerate(f, 1):
                try:
                    raw.decode(encoding)
                except UnicodeDecodeError:
                    return number
    except (OSError, LookupError):
        pass
    return None


def _text(path: str | Path, e: Exception, read: int, unit: str) -> str:
    """'PATH: cannot read it after record N: what (ErrorType)'; for bytes that are not text, the line that has them."""
    where = f"after {unit} {read}" if read else "at its start"
    if isinstance(e, UnicodeDecodeError):
        line = _undecodable_line(Path(path), e.encoding)
        if line is not None:
            return f"{path}: cannot read it: line {line} is not {e.encoding} text ({e.reason})"
    kind = type(e).__qualname__ if type(e).__module__ == "builtins" else f"{type(e).__module__}.{type(e).__qualname__}"
    detail = f"unknown key {e}" if isinstance(e, KeyError) else str(e) or "no detail"
    return f"{path}: cannot read it {where}: {detail} ({kind})"


def read_error(path: str | Path, e: Exception, read: int, unit: str = "record") -> InputError:
    """The InputError for what a reader of `path` raised after `read` `unit`s (with -v, its traceback is logged)."""
    log.info("reading %s", path, exc_info=e)
    return InputError(_text(path, e, read, unit))


def guarded(path: str | Path, items: Iterable[T], unit: str = "record") -> Iterator[T]:
    """The items of a reader of `path`; an error the reader raises becomes one InputError naming the file and the
    number of `unit`s read before it (with -v, the reader's traceback is logged too)."""
    it = iter(items)
    read = 0
    while True:
        try:
            item = next(it)
        except StopIteration:
            return
        except InputError:
            raise
        except Exception as e:
            raise read_error(path, e, read, unit) from None
        read += 1
        yield item
