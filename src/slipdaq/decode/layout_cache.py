"""Data derived from a DBC kept between runs (the wheel decoder's layout: decode/can_wheels.py), in slipdaq's cache
directory beside the compiled kernels (compiled.ahead.cache_dir): one pickle per name and key, written whole
(outputs.atomic_output: a temporary file renamed into place) and read back only whole. A file that cannot be read or
written is a miss: the caller derives the data again."""

from __future__ import annotations

import contextlib
import pickle
from pathlib import Path
from typing import Any

from slipdaq.compiled.ahead import cache_dir
from slipdaq.outputs import OutputError, atomic_output


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
    """value kept under name and key; nothing where the cache directory cannot be written (RuntimeError: no home
    directory to find it in)."""
    with contextlib.suppress(OSError, OutputError, RuntimeError), atomic_output(_path(name, key)) as tmp:
        tmp.write_bytes(pickle.dumps(value, protocol=pickle.HIGHEST_PROTOCOL))
