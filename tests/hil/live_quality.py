"""A recorded live run judged per window by its `quality`: its raw records replayed with GPS latency "auto" (live and
replay are one estimator, bit for bit), each judged wheel window above MIN_SPEED_MPS against the drive's truth.
Shared by benchmarks/live_recorded.py and tests/test_live_recorded.py."""

from __future__ import annotations

import contextlib
import io
import re
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
from hil_support import read_log, read_sent, write_config
from judge import MIN_SPEED_MPS, WheelFrames, judged, load_truth, wheel_frames

from slipdaq import WHEELS
from slipdaq.cli import main as slipdaq
from slipdaq.logformat.reader import iter_estimates
from slipdaq.sim.truth import slip_errors


@dataclass(frozen=True)
class RecordedRun:
    """A HIL run's artifacts (SLIPDAQ_HIL_ARTIFACTS): the daemon's log, the frames sent, the drive's truth."""

    log: Path
    truth: dict[str, np.ndarray]
    wheels: list[WheelFrames]

    @classmethod
    def load(cls, folder: Path) -> RecordedRun:
        log = folder / "case1-live.mcap"
        return cls(log, load_truth(folder / "case1-truth.json.gz"),
                   wheel_frames(read_log(log), read_sent(folder / "case1-sent.csv")))


def replay_auto_latency(log: Path, tmp: Path, name: str, *flags: str) -> list[dict[str, Any]]:
    """The log's raw records through `slipdaq replay` with the HIL config, GPS latency "auto"; the estimates."""
    cfg = write_config(tmp, "/tmp/unused-gps")
    text, n = re.subn(r"^latency_s = .*$", 'latency_s = "auto"', cfg.read_text(), count=1, flags=re.M)
    assert n == 1
    cfg.write_text(text)
    out = tmp / f"{name}.mcap"
    with contextlib.redirect_stderr(io.StringIO()):
        rc = slipdaq(["replay", str(log), "--config", str(cfg), "-o", str(out), *flags])
    assert rc == 0, name
    return list(iter_estimates(out))


def cold_and_stored(run: RecordedRun, tmp: Path) -> tuple[list[dict[str, Any]], list[dict[str, Any]]]:
    """The run's estimates cold (no calibration) and with the calibration a first replay of it stored."""
    cal = tmp / "calibration.toml"
    cold = replay_auto_latency(run.log, tmp, "cold", "--no-calibration")
    replay_auto_latency(run.log, tmp, "learn", "--calibration", str(cal))
    return cold, replay_auto_latency(run.log, tmp, "stored", "--calibration", str(cal))


def errors_by_quality(rows: list[dict[str, Any]], run: RecordedRun) -> dict[str, list[tuple[float, str, float]]]:
    """Per quality: (time from the first estimate, wheel, slip error in points) of each judged wheel window above
    MIN_SPEED_MPS."""
    fast = [r for r in rows if r["speed_mps"] is not None and r["speed_mps"] > MIN_SPEED_MPS]
    out: dict[str, list[tuple[float, str, float]]] = {}
    for w, frames in zip(WHEELS, run.wheels):
        for r in fast:
            e = slip_errors([r], run.truth, MIN_SPEED_MPS, wheels=[w]) if judged(r, frames) else np.empty(0)
            if e.size:
                out.setdefault(r["quality"], []).append((r["time_s"] - rows[0]["time_s"], w, 100 * float(e[0])))
    return out


def rms(errors: list[tuple[float, str, float]]) -> float:
    return float(np.sqrt(np.mean(np.array([e[2] for e in errors]) ** 2)))
