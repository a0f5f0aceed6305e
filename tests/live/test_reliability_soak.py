"""The soak's short version (benchmarks/soak.py run as a program; the 10-minute figures are in docs/reliability.md):
4 wheels x 1 kHz and 20 Hz NMEA through the daemon on a virtual bus and a pty: no frame lost, memory flat, replay
equal."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

from support.paths import ROOT


def test_short_soak(tmp_path: Path) -> None:
    out = tmp_path / "soak.json"
    run = subprocess.run([sys.executable, "-m", "benchmarks.soak", "--duration", "5", "--sample-every",
                          "1", "--warmup", "2.5", "--log-dir", str(tmp_path), "--json", str(out)],
                         capture_output=True, text=True, timeout=300, cwd=ROOT)
    assert run.returncode == 0, run.stdout[-2000:] + run.stderr[-2000:]
    r = json.loads(out.read_text())
    assert r["frames_sent"] == 4 * 1000 * 5 and r["frames_logged"] == r["frames_sent"]
    assert r["frames_lost"] == 0 and r["seq_gaps"] == 0
    assert r["nmea_lines_logged"] == r["nmea_lines_sent"] == 3 * 20 * 5
    assert r["replay_equal"] and r["estimates"] > 50
    assert r["ok"]  # includes the RSS growth after the warm-up below the soak's limit
