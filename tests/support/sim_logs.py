"""Simulated drives written as this tree logs them: in chunks small enough that a short log holds many; logs to be
compared byte for byte."""

from __future__ import annotations

import os
from pathlib import Path

from slipdaq.config import load_config
from slipdaq.offline.run import process_to_log
from slipdaq.sim.emit import SimSettings, generate
from support.paths import CONFIG, write_config

FIXED_META = {"created_utc": "2026-01-01T00:00:00+00:00"}
"""The one value of a log that names the time of the run: given to both of two logs to be compared byte for byte."""


def chunked_log(d: Path, seconds: float, chunk_bytes: int, seed: int) -> Path:
    """d/run.mcap: the cycle drive on paved for `seconds`, imported with chunk_size_bytes = chunk_bytes."""
    cfg = load_config(write_config(d, CONFIG.read_text().replace("# chunk_size_bytes = 1048576",
                                                                 f"chunk_size_bytes = {chunk_bytes}")))
    records = (ev.record for ev in generate(cfg, "cycle", "paved", SimSettings(seed=seed), duration_s=seconds)
               if ev.record is not None)
    with open(os.devnull, "w") as quiet:
        process_to_log(cfg, records, d / "run.mcap", "import", stream=quiet)
    return d / "run.mcap"
