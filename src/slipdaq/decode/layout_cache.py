"""Data derived from a DBC kept between runs (the wheel decoder's layout: decode/can_wheels.py), in slipdaq's cache
directory beside the compiled kernels (compiled.ahead.cache_dir): one pickle per name and key, written whole (a
temporary file renamed into place) and read back only whole. A file that cannot be read or written is a miss: the
caller derives the data again."""

from __future__ import annotations

import contextlib
import os
import pickle
import tempfile
from pathlib import Path
from typing import Any

from slipdaq.compiled.ahead import cache_dir


def _path(name: str, key: str) -> Path:
    return cache_dir() / f"{name}-{key}.pickle"


def load(name: str, key: str) -> Any | None:
    """What store(name, key, ...) kept; None where there is none, or it does not read back."""
    try:
        with open(_path(name, key), "rb") as f:
            return pickle.load(f)
    except Exception:  # missing, cut short, or written by another version of a library it holds
        return None


def store(name: str, key: str, value: Any) -> None:
    """value kept under name and key (atomically); nothing where the cache directory cannot be written."""
    with contextlib.suppress(OSError, RuntimeError):  # RuntimeError: no home directory to find the cache in
        path = _path(name, key)
        path.parent.mkdir(parents=True, exist_ok=True)
        fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=f".{path.name}.")
        try:
            with os.fdopen(fd, "wb") as f:
                pickle.dump(value, f, protocol=pickle.HIGHEST_PROTOCOL)
            os.replace(tmp, path)
        except BaseException:
            with contextlib.suppress(OSError):
                os.unlink(tmp)
            raise
