"""The soak's short version (benchmarks/soak.py; the 10-minute figures are in docs/reliability.md): 4 wheels x 1 kHz
and 20 Hz NMEA through the daemon on a virtual bus and a pty: no frame lost, memory flat, replay equal."""

from __future__ import annotations

import importlib.util
import sys
from pathlib import Path

from conftest import ROOT


def _soak_module():  # type: ignore[no-untyped-def]
    spec = importlib.util.spec_from_file_location("slipdaq_soak", ROOT / "benchmarks" / "soak.py")
    assert spec and spec.loader
    mod = importlib.util.module_from_spec(spec)
    sys.modules[spec.name] = mod  # (its dataclasses look their module up)
    spec.loader.exec_module(mod)
    return mod


def test_short_soak(tmp_path: Path) -> None:
    soak = _soak_module()
    r = soak.run_soak(5.0, tmp_path, sample_every_s=1.0, warmup_s=2.5)
    assert r.frames_sent == 4 * 1000 * 5 and r.frames_logged == r.frames_sent
    assert r.frames_lost == 0 and r.seq_gaps == 0
    assert r.nmea_lines_logged == r.nmea_lines_sent == 3 * 20 * 5
    assert r.rss_growth_after_warmup_bytes < soak.RSS_LIMIT_BYTES
    assert r.replay_equal and r.estimates > 50
