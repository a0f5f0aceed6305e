"""judge.py, case 1's verdict, on a recorded case 1 run (tests/hil/data, from a run under host load: the daemon's
log, the sender's records of the frames and NMEA lines it sent, its --nmea file, the drive's truth). No CAN needed:
runs on the host and in the VM.

The recorded daemon passes; the same frames and NMEA lines put through the estimator with a wrong config
(`slipdaq replay --config`) fail; a sender whose samples lag too much, or NMEA stamped far too late, give no verdict
rather than a pass; NMEA stamped late passes estimates that meet the bounds and gives the others no verdict; a log
whose frames are not the ones sent is refused.
"""

from __future__ import annotations

import dataclasses
import re
from pathlib import Path

import numpy as np
import pytest
from hil_support import read_log, read_nmea, read_nmea_record, read_sent, write_config
from judge import MAX_GPS_SHIFT_PASS_S, MAX_GPS_SHIFT_S, MIN_JUDGED_WINDOWS, gps_shift, judge_drive, load_truth, wheel_frames

DATA = Path(__file__).resolve().parent / "data"
LOG = DATA / "case1-live.mcap"


@pytest.fixture(scope="module")
def recorded() -> tuple[list, dict, list]:  # type: ignore[type-arg]
    """(wheel frames, truth, GPS shift) of the recorded run."""
    log, truth = read_log(LOG), load_truth(DATA / "case1-truth.json.gz")
    zero = truth["time_s"][0]  # drive time 0: the truth's first sample
    planned = [zero + t for t, _ in read_nmea(DATA / "case1-drive.nmea")]
    shift = gps_shift(log, read_nmea_record(DATA / "case1-nmea-sent.csv"), planned)
    return wheel_frames(log, read_sent(DATA / "case1-sent.csv")), truth, shift


def _replayed(tmp_path: Path, *changes: tuple[str, str]) -> Path:
    """The recorded log's raw records through `slipdaq replay` with the HIL config changed by (regex, line)."""
    from slipdaq.cli import main

    cfg = write_config(tmp_path, "/tmp/unused-gps")
    text = cfg.read_text()
    for pattern, line in changes:
        text, n = re.subn(pattern, line, text, count=1, flags=re.M)
        assert n == 1, pattern
    cfg.write_text(text)
    out = tmp_path / "replayed.mcap"
    assert main(["replay", str(LOG), "--config", str(cfg), "-o", str(out)]) == 0
    return out


def test_the_recorded_daemon_passes(recorded) -> None:  # type: ignore[no-untyped-def]
    from slipdaq.logformat.reader import iter_estimates

    wheels, truth, shift = recorded
    verdict = judge_drive(iter_estimates(LOG), truth, wheels, shift)
    assert verdict.problems == [] and verdict.error.samples >= MIN_JUDGED_WINDOWS


@pytest.mark.parametrize("name, changes, caught", [
    ("tire size 205/55 R16 for 195/60 R15, r0 not calibrated",
     [(r"^size = .*$", 'size = "205/55 R16"'), (r"^# calibrate_r0 = true.*$", "calibrate_r0 = false")],
     ["median", "p95"]),
    ("pulses_per_rev 1024 for 1000, r0 not calibrated",
     [(r"^pulses_per_rev = .*$", "pulses_per_rev = 1024"), (r"^# calibrate_r0 = true.*$", "calibrate_r0 = false")],
     ["median", "p95"]),
    ("GPS latency 50 ms for 0", [(r"^latency_s = .*$", "latency_s = 0.05")], ["median", "p95"]),
])
def test_a_wrong_estimate_is_caught(  # type: ignore[no-untyped-def]
    recorded, tmp_path: Path, name: str, changes: list[tuple[str, str]], caught: list[str]
) -> None:
    from slipdaq.logformat.reader import iter_estimates

    wheels, truth, shift = recorded
    verdict = judge_drive(iter_estimates(_replayed(tmp_path, *changes)), truth, wheels, shift)
    assert verdict.error.samples >= MIN_JUDGED_WINDOWS, name  # a verdict, and it is a failure
    assert all(any(p.startswith(c) for p in verdict.problems) for c in caught), (name, verdict.problems)


def test_wrong_signs_are_caught(recorded) -> None:  # type: ignore[no-untyped-def]
    """Slip of the opposite sign (e.g. wheel and GPS distance swapped) within the error bounds' reach is caught."""
    from slipdaq.logformat.reader import iter_estimates

    wheels, truth, shift = recorded
    flipped = [r | {"slip_FL": -r["slip_FL"]} if r["slip_FL"] is not None else r for r in iter_estimates(LOG)]
    problems = judge_drive(flipped, truth, wheels, shift).problems
    assert any("wrong sign while accelerating" in p for p in problems)
    assert any("wrong sign while braking" in p for p in problems)


def test_a_sender_that_lags_gives_no_verdict(recorded) -> None:  # type: ignore[no-untyped-def]
    """Every other frame's count sampled 10 ms before its kernel stamp: the sender's share of a window's slip (up to 2
    points) is too large to judge the daemon on in most windows, and the judge says so rather than passing."""
    from slipdaq.logformat.reader import iter_estimates

    wheels, truth, shift = recorded
    lagging = [dataclasses.replace(w, lags_s=[x + 0.010 * (k % 2) for k, x in enumerate(w.lags_s)]) for w in wheels]
    verdict = judge_drive(iter_estimates(LOG), truth, lagging, shift)
    assert len(verdict.problems) == 1 and verdict.problems[0].startswith("no verdict")
    assert verdict.error.samples < MIN_JUDGED_WINDOWS


def _shifted(shift: list[float], median_s: float) -> list[float]:
    """The recorded NMEA lines' shifts moved so that their median (numpy's, as the judge takes it) is median_s."""
    med = float(np.median(shift))
    return [x - med + median_s for x in shift]


def test_nmea_stamped_very_late_gives_no_verdict(recorded) -> None:  # type: ignore[no-untyped-def]
    """NMEA lines stamped a median 30 ms after plan: past MAX_GPS_SHIFT_PASS_S a correct daemon misses the bounds on
    the shift alone (18 ms: |slip error| median 0.46 points), so even estimates that meet them get no verdict."""
    from slipdaq.logformat.reader import iter_estimates

    wheels, truth, shift = recorded
    problems = judge_drive(iter_estimates(LOG), truth, wheels, _shifted(shift, 0.030)).problems
    assert len(problems) == 1 and problems[0].startswith("no verdict: the daemon stamped the NMEA lines")


def test_nmea_stamped_late_passes_estimates_that_meet_the_bounds(recorded) -> None:  # type: ignore[no-untyped-def]
    """A median shift of 12 ms (over MAX_GPS_SHIFT_S, under MAX_GPS_SHIFT_PASS_S), as a slow host gave: the recorded
    daemon's estimates meet every bound with the shift's error in them: a pass."""
    from slipdaq.logformat.reader import iter_estimates

    wheels, truth, shift = recorded
    verdict = judge_drive(iter_estimates(LOG), truth, wheels, _shifted(shift, 0.012))
    assert MAX_GPS_SHIFT_S < verdict.gps_shift_s < MAX_GPS_SHIFT_PASS_S
    assert verdict.problems == [] and verdict.error.samples >= MIN_JUDGED_WINDOWS


def test_nmea_stamped_late_gives_a_miss_no_verdict(recorded, tmp_path: Path) -> None:  # type: ignore[no-untyped-def]
    """The same shift with a daemon that misses the bounds (tire size 205/55 R16 for 195/60 R15, r0 not calibrated):
    the shift may account for the miss, so no verdict (played again, then the case fails), naming what was missed."""
    from slipdaq.logformat.reader import iter_estimates

    wheels, truth, shift = recorded
    wrong = _replayed(tmp_path, (r"^size = .*$", 'size = "205/55 R16"'),
                      (r"^# calibrate_r0 = true.*$", "calibrate_r0 = false"))
    problems = judge_drive(iter_estimates(wrong), truth, wheels, _shifted(shift, 0.012)).problems
    assert len(problems) == 1 and problems[0].startswith("no verdict: the daemon stamped the NMEA lines")
    assert "missed: median |slip error|" in problems[0]


def test_frames_that_were_not_sent_are_refused() -> None:
    log = read_log(LOG)
    sent = read_sent(DATA / "case1-sent.csv")
    t, data = log.by_id[0x311][100]
    log.by_id[0x311][100] = (t, (int.from_bytes(data[:4], "little") + 1).to_bytes(4, "little") + data[4:])
    with pytest.raises(ValueError, match="frame 100 of 0x311"):
        wheel_frames(log, sent)
