"""Where the tests' inputs are (the repository, the example config, tests/data) and the helpers every folder uses."""

from __future__ import annotations

import contextlib
import os
from collections.abc import Iterator
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
CONFIG = ROOT / "config" / "slipdaq.toml"
DATA = ROOT / "tests" / "data"
HIL_DATA = ROOT / "tests" / "hil" / "data"


def write_config(tmp_path: Path, text: str, dbc: str | None = None) -> Path:
    """A config file in tmp_path with the example DBC beside it (or the given DBC text)."""
    (tmp_path / "wpt.dbc").write_text(dbc if dbc is not None else (ROOT / "config" / "wpt.dbc").read_text())
    p = tmp_path / "slipdaq.toml"
    p.write_text(text)
    return p


@contextlib.contextmanager
def kernels(compiled_: bool) -> Iterator[None]:
    """The numba kernels compiled (True) or run as plain Python (False) inside the block."""
    from slipdaq import compiled

    saved = os.environ.get("SLIPDAQ_JIT")
    os.environ["SLIPDAQ_JIT"] = "1" if compiled_ else "0"
    compiled.reset()
    try:
        yield
    finally:
        if saved is None:
            os.environ.pop("SLIPDAQ_JIT", None)
        else:
            os.environ["SLIPDAQ_JIT"] = saved
        compiled.reset()
