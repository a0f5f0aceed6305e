"""A simulated drive written as this tree logs it, in chunks small enough that a short log holds many."""

from __future__ import annotations

import os
from pathlib import Path

from slipdaq.config import load_config
from slipdaq.offline.run import process_to_log
from slipdaq.sim.emit import SimSettings, generate
from support.paths import CONFIG, write_config


def chunked_log(d: Path, seconds: float, chunk_bytes: int, seed: int) -> Path:
    """d/run.mcap: the cycle drive on paved for `seconds`, imported with chunk_size_bytes = chunk_bytes."""
    cfg = load_config(write_config(d, CONFIG.read_text().replace("# chunk_size_bytes = 1048576",
                                                                 f"chunk_size_bytes = {chunk_bytes}")))
    records = (ev.record for ev in generate(cfg, "cycle", "paved", SimSettings(seed=seed), duration_s=seconds)
               if ev.record is not None)
    with open(os.devnull, "w") as quiet:
        process_to_log(cfg, records, d / "run.mcap", "import", stream=quiet)
    return d / "run.mcap"
