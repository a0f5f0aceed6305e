"""The live estimator on HIL runs recorded in the VM with the host clock months off the sentences' UTC (GPS latency
"auto": from the wheels), judged per window against the drive's truth: the issue's live targets on `ok` windows,
cold and with a stored calibration. One run was recorded under heavy host load: the daemon read its NMEA lines a
median 15 ms late (p95 123 ms), the median moving with the load; placing fixes by the median of (arrival - UTC)
gave its `ok` windows 0.51 points RMS, worst 2.8."""

from __future__ import annotations

from pathlib import Path

import pytest
from live_quality import RecordedRun, cold_and_stored, errors_by_quality, rms

DATA = Path(__file__).parents[1] / "hil" / "data"


@pytest.mark.parametrize("folder", [DATA, DATA / "loaded"], ids=["recorded", "heavy-load"])
def test_live_ok_windows_within_the_targets(folder: Path, tmp_path: Path) -> None:
    run = RecordedRun.load(folder)
    for rows in cold_and_stored(run, tmp_path):
        by_quality = errors_by_quality(rows, run)
        ok = by_quality.get("ok", [])
        total = sum(len(v) for v in by_quality.values())
        assert total > 300
        assert len(ok) >= 0.5 * total  # the 20 s run is short: its cold start is 44 % of it
        assert rms(ok) <= 0.3
        assert max(abs(e[2]) for e in ok) <= 5.0
