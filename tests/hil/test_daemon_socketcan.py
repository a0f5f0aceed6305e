"""`slipdaq run` on SocketCAN (vcan0), fed from other processes, GPS on a pseudo-terminal. VM only.

Four daemon runs, one after the other, each `slipdaq run` its own process on interface "socketcan", channel "vcan0",
the traffic from wpt_sender.py (frames on a raw socket, NMEA on a pty, every send recorded) unless stated:

  case 1  the simulator's drive (accelerate, cruise, brake), each frame's count sampled when it is sent: every frame
          and line is in the log, the estimates follow the simulator's truth (judge.py) and equal `slipdaq replay`
          of the daemon's own log;
  case 2  case 1's live log put back on vcan0 and a pty by tools/replay/replay_bus.py into a second daemon: its
          estimates equal `slipdaq replay` of its own log, and those of case 1's log within the tolerance its timing
          explains (stated below);
  case 4  `ip link set vcan0 down` for 2 s or more and up: the daemon reports the outage, keeps logging GPS, keeps its
          log valid, takes the first frame after the outage and reports it within 1 s;
  case 3  load: wheel frames at 4 x 25 Hz plus 20 Hz NMEA for 60 s, then a burst of 10,000 frames at 4 wheels x
          1 kHz: no frame or line lost; the daemon's socket has the receive buffer it asked for (SO_RCVBUFFORCE);
  case 5  (in case 3's run) the daemon is stopped (SIGSTOP) for 1 s or more: the frames sent meanwhile carry kernel
          receive timestamps (SO_TIMESTAMPNS) from inside their send() calls, spread over the pause, while the NMEA
          lines written meanwhile are stamped when read, after SIGCONT.

Every verdict is on what was actually sent (the sender's records, the kernel's stamps) and what the daemon logged,
not on the sender's plan, so a sender the busy machine holds back does not decide it; where too little could be
judged, a case waits or plays again, and as a last resort fails saying why.

Every figure is printed as a `hil:` line. Rates and durations can be changed with environment variables (below).
Skipped where the kernel has no SocketCAN or no vcan0 (the host): run it with tests/hil/run_vm.sh.
"""

from __future__ import annotations

import bisect
import os
import shutil
import signal
import statistics
import time
from collections.abc import Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import pytest
from hil_support import (
    IDS,
    Daemon,
    DaemonResult,
    LogContent,
    SenderProgress,
    SentFrame,
    Zygote,
    bind_pytest,
    can_unavailable_reason,
    cruise_nmea,
    diagnostics,
    finished,
    link,
    percentile,
    proc_state,
    pulse_count,
    rate_while_backlogged,
    read_log,
    read_nmea_record,
    read_sent,
    replay_differences,
    report,
    sender_result,
    seq_gaps,
    start_replay_bus,
    start_sender,
    wait_progress,
    write_config,
    write_drive,
    write_nmea,
)
from judge import DriveVerdict, gps_shift, judge_drive, save_truth, wheel_frames

_reason = can_unavailable_reason()
if _reason:
    pytest.skip(_reason, allow_module_level=True)


def _env(name: str, default: float) -> float:
    return float(os.environ.get(name, default))


SIM_RATE_HZ = _env("SLIPDAQ_HIL_SIM_RATE_HZ", 25.0)
"""Case 1: WPT frames per second per wheel of the simulated drive (10 Hz GPS)."""
SIM_DURATION_S = _env("SLIPDAQ_HIL_SIM_DURATION_S", 20.0)
"""Case 1: one accelerate-cruise-brake cycle takes about 16 s."""
CASE1_ATTEMPTS = 3
"""Case 1: drives played when the machine did not run them in real time, before the case fails for it."""
LOAD_RATE_HZ = _env("SLIPDAQ_HIL_LOAD_RATE_HZ", 25.0)
"""Case 3: sustained WPT frames per second per wheel (the issue's 1 kHz does not hold in the emulated VM)."""
LOAD_DURATION_S = _env("SLIPDAQ_HIL_LOAD_DURATION_S", 60.0)
LOAD_GPS_HZ = 20.0
BURST_FRAMES = int(_env("SLIPDAQ_HIL_BURST_FRAMES", 10_000))
BURST_RATE_HZ = 1000.0
"""Case 3: the burst's rate per wheel (4 kHz in all, the issue's target, as fast as the sender manages)."""
PAUSE_AT_S, PAUSE_S, PAUSE_MAX_S = 20.0, 1.0, 10.0
"""Case 5: SIGSTOP this long after the load starts, for at least PAUSE_S and until the sender has sent
PAUSE_MIN_FRAMES frames (over at least 0.5 s) and 3 NMEA lines, at most PAUSE_MAX_S."""
PAUSE_MIN_FRAMES = 50
OUTAGE_RATE_HZ = 25.0
OUTAGE_AT_S, OUTAGE_S, OUTAGE_MAX_S, OUTAGE_AFTER_S = 5.0, 2.0, 8.0, 3.0
"""Case 4: link down this long after the sender starts, for at least OUTAGE_S and until the sender has tried to
send and written NMEA meanwhile, at most OUTAGE_MAX_S; the sender is stopped OUTAGE_AFTER_S of frames after."""
RESUME_LIMIT_S = 1.0
"""Case 4: the issue's liveness bound (the only time bound asserted)."""

EPS_S = 2e-6
"""Slack for comparing timestamps that went through float seconds (double precision at 1.8e9 s: ~0.24 us)."""


@dataclass
class Env:
    tmp: Path
    zygote: Zygote


@pytest.fixture(scope="module")
def env(tmp_path_factory: pytest.TempPathFactory, pytestconfig: pytest.Config) -> Iterator[Env]:
    bind_pytest(pytestconfig)
    t0 = time.time()
    zygote = Zygote()  # imports in parallel with this process's own imports below
    import slipdaq.cli  # noqa: F401
    import slipdaq.logformat.reader  # noqa: F401
    import slipdaq.sim.emit  # noqa: F401

    report(f"test process imported slipdaq in {time.time() - t0:.0f} s")
    try:
        yield Env(tmp_path_factory.mktemp("hil"), zygote)
    finally:
        zygote.close()


@pytest.fixture(autouse=True)
def _bind(pytestconfig: pytest.Config) -> None:
    bind_pytest(pytestconfig)


def keep(path: Path, name: str) -> None:
    """Copy a log or record to $SLIPDAQ_HIL_ARTIFACTS (if set; run_vm.sh passes it on) for a look afterwards."""
    target = os.environ.get("SLIPDAQ_HIL_ARTIFACTS")
    if target:
        Path(target).mkdir(parents=True, exist_ok=True)
        shutil.copyfile(path, Path(target) / name)


def _check_receive_buffer(log: Path) -> int:
    """The daemon's CAN socket got the receive buffer it asked for: Linux reports twice the size set."""
    from slipdaq.logformat.reader import read_metadata

    meta = read_metadata(log)
    got, asked = int(meta["can_receive_buffer_bytes"]), int(meta["can_receive_buffer_requested_bytes"])
    assert asked == 8 * 1024 * 1024 and got >= asked, meta
    return got


def _same_frames(a: LogContent, b: LogContent) -> None:
    """Both logs have the same frames per id, payload by payload, in the same order."""
    assert sorted(a.by_id) == sorted(b.by_id)
    for i in a.by_id:
        assert [d for _, d in a.by_id[i]] == [d for _, d in b.by_id[i]], hex(i)


def _offsets(live: LogContent, ref: LogContent) -> list[float]:
    """Live timestamp minus reference timestamp of each frame (matched by position per id: same frames)."""
    return [t - u for i in ref.by_id for (t, _), (u, _) in zip(live.by_id[i], ref.by_id[i])]


# ---- case 1 ---------------------------------------------------------------------------------------------------

@dataclass
class Case1:
    truth: dict[str, Any]
    """slipdaq.sim.truth.truth_series on the log's clock: drive time 0 is the sender's zero_s."""
    nmea: list[tuple[float, str]]
    """The drive's NMEA lines: (drive time, sentence)."""
    sender: dict[str, Any]
    """wpt_sender.py's result line."""
    sent: list[SentFrame]
    nmea_written: list[tuple[int, float, float]]
    result: DaemonResult
    log: LogContent
    verdict: DriveVerdict | None = None
    attempts: int = 1
    drive: list[Any] = field(default_factory=list)
    """The drive's truth samples (slipdaq.sim.vehicle.TruthSample), for another run of it."""


def _drive(env: Env, d: Path) -> tuple[list[Any], list[tuple[float, str]]]:
    """The simulator's drive: its truth (every 10 ms) and NMEA lines, the --drive and --nmea files of the sender."""
    from slipdaq.config import load_config
    from slipdaq.records import NmeaLine
    from slipdaq.sim.emit import SimSettings, generate

    cfg = load_config(write_config(d, "/tmp/hil-gps-case1"))
    settings = SimSettings(wpt_rate_hz=0.0, gps_rate_hz=10.0, seed=1)  # the frames are made by the sender
    t0 = time.time()
    truth, nmea = [], []
    for ev in generate(cfg, "cycle", "paved", settings, duration_s=SIM_DURATION_S):
        if ev.truth is not None:
            truth.append(ev.truth)
        elif isinstance(ev.record, NmeaLine):
            nmea.append((ev.time_s, ev.record.line))
    write_drive(d / "drive.json", truth, cfg.wpt.pulses_per_rev, settings.start_count)
    write_nmea(d / "drive.nmea", nmea)
    report(f"case 1: generated the drive ({len(truth)} truth samples, {len(nmea)} NMEA lines, {SIM_DURATION_S:g} s) "
           f"in {time.time() - t0:.0f} s; zygote imports took {env.zygote.wait_ready():.0f} s")
    return truth, nmea


def _play(env: Env, d: Path, drive: Path, nmea: Path, latency: str = "0.0") -> tuple[dict[str, Any], DaemonResult]:
    """One daemon (its gps.latency_s: latency), the drive played into it by wpt_sender.py; its records in d."""
    gps = "/tmp/hil-gps-case1"
    cfg_path = write_config(d, gps, latency)
    daemon = Daemon(env.zygote, cfg_path, d / "logs")
    sender = start_sender(SIM_RATE_HZ, SIM_DURATION_S, go=daemon.go, delay_s=1.5, record=d / "sent.csv",
                          drive=drive, nmea=nmea, gps_link=gps, nmea_record=d / "nmea-sent.csv",
                          gps_reader_pid=daemon.pid)
    try:
        r = sender_result(sender, 10 * SIM_DURATION_S + 900)
        daemon.wait_frames(r["sent"], 900)
        result = daemon.stop()
    finally:
        sender.kill()
        daemon.proc.kill()
    report(f"case 1: wpt_sender.py played the {SIM_DURATION_S:g} s drive in {r['end_s'] - r['start_s']:.1f} s; sent "
           f"{r['sent']} frames ({SIM_RATE_HZ:g} Hz x 4) and {r['nmea_written']} NMEA lines")
    return r, result


@pytest.fixture(scope="module")
def case1(env: Env) -> Case1:
    """The simulator's drive (slipdaq.sim.emit.generate: the generator `slipdaq simulate` plays) generated first —
    its truth, each wheel's pulses every 10 ms, its NMEA — then played by wpt_sender.py --drive onto vcan0 and a pty
    into `slipdaq run`, each frame's PulseCount sampled just before its send(), and judged (judge.py).

    Why not `slipdaq simulate`: it integrates the vehicle model while it plays, and inside the emulated VM that costs
    more than real time (measured: a 20 s drive took 94 s to send). Why not a replay of the generated frames
    (replay_bus.py, case 2): each frame then carries the count of its planned time, and a frame the busy VM sends
    late carries a count that its kernel stamp contradicts, an error no receiver can undo (on a loaded host 70 % of
    the estimates had such a frame at a window edge). A transducer samples its counter when it transmits; so does
    the sender here: a frame sent late is late, not wrong.

    When the run cannot be judged (the machine did not run the sender or the daemon in real time: see judge.py),
    the drive is played again into a new daemon, up to CASE1_ATTEMPTS times; then the verdict's reason fails the case.
    """
    base = env.tmp / "case1"
    truth, nmea = _drive(env, base)
    return _judged_run(env, base, truth, nmea, "case1")


def _judged_run(env: Env, base: Path, truth: list[Any], nmea: list[tuple[float, str]], name: str,
                latency: str = "0.0") -> Case1:
    """The drive in base played into a daemon and judged, played again (up to CASE1_ATTEMPTS) while no verdict."""
    from slipdaq.logformat.reader import iter_estimates
    from slipdaq.sim.truth import truth_series

    for attempt in range(1, CASE1_ATTEMPTS + 1):
        d = base / f"{name}-attempt{attempt}"
        r, result = _play(env, d, base / "drive.json", base / "drive.nmea", latency)
        log = read_log(result.log)
        c = Case1(truth_series(truth, r["zero_s"]), nmea, r, read_sent(d / "sent.csv"),
                  read_nmea_record(d / "nmea-sent.csv"), result, log, attempts=attempt, drive=truth)
        try:
            shift = gps_shift(log, c.nmea_written, [r["zero_s"] + t for t, _ in nmea])
            c.verdict = judge_drive(iter_estimates(result.log), c.truth, wheel_frames(log, c.sent), shift)
        except ValueError as e:  # frames or lines in the log are not the ones sent: test_case1_every_frame_... says
            report(f"{name}: no verdict: {e}")
            break
        if not c.verdict.problems or not c.verdict.problems[0].startswith("no verdict"):
            break
        report(f"{name}: attempt {attempt}: {c.verdict.problems[0]}; {c.verdict.summary()}")
    for what, path in (("live.mcap", result.log), ("sent.csv", d / "sent.csv"), ("nmea-sent.csv", d / "nmea-sent.csv"),
                       ("drive.nmea", base / "drive.nmea")):
        keep(path, f"{name}-{what}")
    if os.environ.get("SLIPDAQ_HIL_ARTIFACTS"):
        save_truth(Path(os.environ["SLIPDAQ_HIL_ARTIFACTS"]) / f"{name}-truth.json.gz", c.truth)
    return c


def test_case1_every_frame_sent_is_in_the_log(case1: Case1) -> None:
    """Every frame sent is in the log (by total, by Seq, frame by frame with the count sampled for it), stamped by
    the kernel inside its send(); every NMEA line written, in order (the sender started once the daemon had the
    pseudo-terminal open and ended once it had read everything)."""
    c, log, res = case1, case1.log, case1.result
    assert c.sender["sent"] == len(c.sent) == 4 * int(SIM_RATE_HZ * SIM_DURATION_S) and c.sender["failed"] == 0
    assert log.total == c.sender["sent"] == res.can_frames
    assert {i: len(v) for i, v in log.by_id.items()} == {i: c.sender["sent"] // 4 for i in IDS}
    assert [seq_gaps(log.by_id[i]) for i in IDS] == [0, 0, 0, 0]
    assert res.lost_frames == 0 and diagnostics(res.log)[-1]["lost_frames"] == dict.fromkeys(("FL", "FR", "RL", "RR"), 0)
    wheel_frames(log, c.sent)  # frame by frame: ValueError if a frame differs from the one sent
    stamps = {(i, k): t for i, v in log.by_id.items() for k, (t, _) in enumerate(v)}
    outside = [s for s in c.sent if not s.t_before - EPS_S <= stamps[(s.can_id, s.n)] <= s.t_after + EPS_S]
    assert not outside, f"{len(outside)} frames stamped outside their send(): {outside[:3]}"
    lines = [line for _, line in log.nmea]
    assert c.sender["nmea_written"] == len(c.nmea) and c.sender["nmea_dropped"] == c.sender["nmea_unread"] == 0
    assert lines == [line for _, line in c.nmea] and res.bad_sentences == 0
    assert finished(res.log)
    report(f"case 1: log has all {log.total} frames (Seq gaps 0, each the frame sent, stamped inside its send()), "
           f"NMEA {len(lines)} of {len(c.nmea)} lines; SO_RCVBUF {_check_receive_buffer(res.log)} bytes")


def test_case1_estimates_follow_the_simulators_truth(env: Env, case1: Case1) -> None:
    """The verdict of judge.py: median |slip error| < 0.5 and p95 < 2 percentage points (the host's live test's
    bounds), slip positive while accelerating and negative while braking, over the wheel windows whose edges the
    sender covered (frames at most 0.08 s apart, sampling lag worth at most 0.2 points), at least 200 of them, with
    the NMEA lines stamped a median of at most 10 ms after plan; and the daemon's estimates are the ones
    `slipdaq replay` computes from its own log. Reported beside: how late the sender sent frames and lines against
    its plan (the verdict does not depend on it) and how long the daemon took to read a line."""
    c = case1
    assert c.verdict is not None
    zero, period = c.sender["zero_s"], 1.0 / (4 * SIM_RATE_HZ)
    late = [s.t_before - (zero + (4 * s.n + IDS.index(s.can_id)) * period) for s in c.sent]
    lags = [t - s.t_before for s in c.sent for t in [c.log.by_id[s.can_id][s.n][0]]]
    nmea_late = [t0 - (zero + c.nmea[i][0]) for i, t0, _ in c.nmea_written]
    read_delay = [t - t1 for (t, _), (_, _, t1) in zip(c.log.nmea, c.nmea_written)]
    rejected = diagnostics(c.result.log)[-1]["estimator"]["rejected_fixes"]
    own = replay_differences(c.result.log, env.tmp / "case1" / "slipdaq-replay-own.mcap")
    report(f"case 1 (attempt {c.attempts}): sender against its plan: frames {percentile(late, 50) * 1e3:+.1f} ms "
           f"(median), {percentile(late, 95) * 1e3:+.1f} (p95), {max(late) * 1e3:+.1f} (max), "
           f"{sum(x > 0.05 for x in late)} over 50 ms late; count sampled before the kernel stamp: median "
           f"{percentile(lags, 50) * 1e6:.0f} us, p99 {percentile(lags, 99) * 1e3:.2f} ms, "
           f"max {max(lags) * 1e3:.2f} ms; "
           f"NMEA written {percentile(nmea_late, 50) * 1e3:+.1f} ms (median), {percentile(nmea_late, 95) * 1e3:+.1f} "
           f"(p95), {max(nmea_late) * 1e3:+.1f} (max) late, read by the daemon {percentile(read_delay, 50) * 1e3:.1f} "
           f"ms (median), {percentile(read_delay, 95) * 1e3:.1f} (p95), {max(read_delay) * 1e3:.1f} (max) after; "
           f"{c.result.estimates} estimates, {rejected} GPS fixes rejected; {c.verdict.summary()}; against "
           f"`slipdaq replay` of its own log: {len(own)} differences")
    assert not c.verdict.problems, c.verdict.problems
    assert not own, f"the daemon's estimates differ from `slipdaq replay` of its own log: {own[:5]}"


# ---- case 6: cold, GPS latency "auto", the host clock months off the GPS's UTC ---------------------------------

def test_case6_cold_without_utc_finds_the_latency_and_flags_what_came_before(env: Env, case1: Case1) -> None:
    """Case 1's drive into a daemon with gps.latency_s = "auto" and no calibration: the sentences' UTC (the drive is
    dated 2026-01-01) is months off the host clock, so only the wheels can give the latency. The daemon finds it
    within the first acceleration, near the delay the sentences really had (their stamps against plan); every
    window before is not `ok` (and has no slip while the speed changes); the judge's bounds hold over the windows
    with a slip; no window says a slip beyond 50 %; and its estimates are what `slipdaq replay` computes from its
    own log."""
    c = _judged_run(env, env.tmp / "case1", case1.drive, case1.nmea, "case6", latency='"auto"')
    assert c.verdict is not None
    rows = list(_estimates(c.result.log))
    before = [r for r in rows if r["latency_source"] == "none"]
    known = [r for r in rows if r["latency_source"] == "wheels"]
    shift = c.verdict.gps_shift_s
    report(f"case 6 (attempt {c.attempts}): latency {known[-1]['gps_latency_s'] * 1e3 if known else float('nan'):.1f} "
           f"ms from the wheels (the sentences' median stamp against plan: {shift * 1e3:.1f} ms); "
           f"{len(before)} estimates before it, first known at {known[0]['time_s'] - rows[0]['time_s'] if known else -1:.1f} s "
           f"into the log; qualities {sorted({r['quality'] for r in rows})}; {c.verdict.summary()}")
    assert known, "the latency was never found from the wheels"
    assert abs(known[-1]["gps_latency_s"] - shift) < 0.015
    assert all(r["quality"] != "ok" for r in before)
    assert not [r for r in rows if r["speed_mps"] > 5 for w in ("FL", "FR", "RL", "RR")
                if r[f"slip_{w}"] is not None and abs(r[f"slip_{w}"]) > 0.5]
    assert not c.verdict.problems, c.verdict.problems
    own = replay_differences(c.result.log, env.tmp / "case1" / "case6-replay-own.mcap")
    assert not own, f"the daemon's estimates differ from `slipdaq replay` of its own log: {own[:5]}"


def _estimates(log: Path) -> Iterator[dict[str, Any]]:
    from slipdaq.logformat.reader import iter_estimates

    return iter_estimates(log)


# ---- case 2 ---------------------------------------------------------------------------------------------------

def _match_by_time(ref: list[dict[str, Any]], rows: list[dict[str, Any]], offset: float, within_s: float
                   ) -> list[tuple[dict[str, Any], dict[str, Any]]]:
    """(ref row, row) pairs: each ref row with the row whose time_s - offset is nearest, if within within_s."""
    times = [r["time_s"] - offset for r in rows]
    order = sorted(range(len(rows)), key=times.__getitem__)
    sorted_times = [times[i] for i in order]
    pairs = []
    for a in ref:
        j = bisect.bisect_left(sorted_times, a["time_s"])
        near = [k for k in (j - 1, j) if 0 <= k < len(order)]
        if near:
            k = min(near, key=lambda k: abs(sorted_times[k] - a["time_s"]))
            if abs(sorted_times[k] - a["time_s"]) <= within_s:
                pairs.append((a, rows[order[k]]))
    return pairs


def test_case2_replay_bus_into_the_daemon_equals_slipdaq_replay(env: Env, case1: Case1) -> None:
    """Case 1's live log back onto vcan0 and a pty (tools/replay/replay_bus.py) into a second `slipdaq run`, against
    `slipdaq replay` of the same log (which equals case 1's live estimates, checked in case 1).

    Whatever the replay's timing: every frame and NMEA line arrives, and the second daemon's estimates are the ones
    `slipdaq replay` computes from its own log (what it received, as it stamped it): every field of every estimate.

    Same frames, same sentences; only their timestamps differ: the kernel stamps each frame again when replay_bus
    sends it and the daemon stamps each NMEA line when it reads it. After removing the replay's start (the median
    difference), what remains is how far the replay missed the recorded timing, d (measured per frame and per line).
    A window edge moved by d changes a wheel's distance by v*d, relative d/W for a window of W = 0.5 s, at both
    edges; the window itself moves with its GPS epoch's stamp, changing speed and distance by a*d, relative a*d/V.

    Tolerance, stated: for every matched wheel window |slip difference| <= 0.3 points + d_max * (2/W + |a|/V), with
    d_max the largest timing difference within 0.1 s of the window (1 ms: 0.3 + 0.4 points; 10 ms: 0.3 + 4 points);
    speed within 0.01 m/s + d_max * (2V/W + |a|). An epoch of `slipdaq replay` without a live estimate is allowed
    only where the replay was >= 20 ms off (the daemon rejects GPS fixes that arrive bunched with one timestamp).
    No bound on how many windows that compares: how much of a run the replay keeps time depends on the VM and the
    host's load (replay_bus sends python-can messages from an asyncio loop: quiet, |d| is 1.4 ms median, 24 ms p95;
    under load it fell 0.9 s behind, median, and 16 windows matched); a window with a large d gets a tolerance to
    match, and the check of the daemon against its own log above holds whatever d was.
    """
    from slipdaq.cli import main as slipdaq_main
    from slipdaq.logformat.reader import iter_estimates

    d = env.tmp / "case2"
    gps = "/tmp/hil-gps-case2"
    cfg_path = write_config(d, gps)
    daemon = Daemon(env.zygote, cfg_path, d / "logs")
    replay = start_replay_bus(env.zygote, case1.result.log, gps, go=daemon.go, delay_s=1.5)
    try:
        _, m = replay.wait_line(r"replay_bus: sent (\d+) CAN frames", 10 * SIM_DURATION_S + 300)
        assert replay.wait(60) == 0, replay.output()
        sent = int(m.group(1))
        daemon.wait_frames(sent, 900)
        result = daemon.stop()
    finally:
        replay.kill()
        daemon.proc.kill()
    keep(result.log, "case2-live.mcap")
    own = replay_differences(result.log, d / "slipdaq-replay-own.mcap")
    offline = d / "slipdaq-replay.mcap"
    assert slipdaq_main(["replay", str(case1.result.log), "-o", str(offline)]) == 0

    live = read_log(result.log)
    assert sent == case1.log.total == live.total and result.lost_frames == 0
    _same_frames(live, case1.log)
    offset = statistics.median(_offsets(live, case1.log))
    # the replay's timing error d of every frame and every NMEA line, on case 1's clock
    deviations = [(u, t - u - offset) for i in live.by_id for (t, _), (u, _) in zip(live.by_id[i], case1.log.by_id[i])]
    missed = len(case1.log.nmea) - len(live.nmea)
    assert [x for _, x in live.nmea] == [x for _, x in case1.log.nmea[missed:]]
    deviations += [(u, t - u - offset) for (t, _), (u, _) in zip(live.nmea, case1.log.nmea[missed:])]
    deviations.sort()
    dev_times = [u for u, _ in deviations]

    def d_max(t0: float, t1: float) -> float:
        i, j = bisect.bisect_left(dev_times, t0), bisect.bisect_right(dev_times, t1)
        return max((abs(x) for _, x in deviations[i:j]), default=0.0)

    rows = list(iter_estimates(result.log))
    ref = list(iter_estimates(offline))
    pairs = _match_by_time(ref, rows, offset, within_s=0.03)  # GPS epochs are 0.1 s apart
    matched = {id(a) for a, _ in pairs}
    ref_moving = [r for r in ref if r["speed_mps"] is not None and r["speed_mps"] > 1.0]
    unmatched = [r for r in ref_moving if id(r) not in matched]
    unexplained = [r for r in unmatched if d_max(r["time_s"] - 0.75, r["time_s"] + 0.75) < 0.02]
    windows = []  # (|slip difference|, its tolerance, d_max)
    speeds = []  # (|speed difference|, its tolerance)
    for a, b in pairs:
        if a["speed_mps"] is None or a["speed_mps"] <= 1.0 or b["speed_mps"] is None:
            continue
        half, v, acc = 0.5 * a["window_s"], a["speed_mps"], abs(a["accel_mps2"] or 3.0)
        dm = d_max(a["time_s"] - half - 0.1, a["time_s"] + half + 0.1)
        tol = 0.003 + dm * (2 / a["window_s"] + acc / v)
        windows += [(abs(a[f"slip_{w}"] - b[f"slip_{w}"]), tol, dm) for w in ("FL", "FR", "RL", "RR")
                    if a[f"slip_{w}"] is not None and b[f"slip_{w}"] is not None]
        speeds.append((abs(a["speed_mps"] - b["speed_mps"]), 0.01 + dm * (2 * v / a["window_s"] + acc)))
    ds = [x for x, _, _ in windows]
    clean = [x for x, _, dm in windows if dm < 0.01]
    kept_time = [x for x, _, dm in windows if dm < 0.02]
    devs = [abs(x) for _, x in deviations]
    over = [(x, tol, dm) for x, tol, dm in windows if x > tol]
    report(f"case 2: replay_bus -> daemon: {live.total} frames (all), NMEA {len(live.nmea)} of "
           f"{len(case1.log.nmea)} lines, {len(rows)} estimates; `slipdaq replay`: {len(ref)} estimates, "
           f"{len(ref_moving)} moving, {len(unmatched)} of them without a live estimate (all where the replay was "
           f">= 20 ms off: {not unexplained}); replay timing error |d| median {statistics.median(devs) * 1e3:.1f} ms, "
           f"p95 {percentile(devs, 95) * 1e3:.1f} ms, max {max(devs) * 1e3:.0f} ms; |slip diff| over {len(ds)} wheel "
           f"windows: median {statistics.median(ds or [0]) * 100:.3f}, p90 {percentile(ds or [0], 90) * 100:.3f}, "
           f"max {max(ds, default=0) * 100:.3f} points, over tolerance {len(over)}; where d_max < 10 ms "
           f"({len(clean)} windows): "
           f"max {max(clean, default=0) * 100:.3f} points; where < 20 ms ({len(kept_time)}): median "
           f"{statistics.median(kept_time or [0]) * 100:.3f}, max {max(kept_time, default=0) * 100:.3f} points; "
           f"|speed diff| max {max((x for x, _ in speeds), default=0):.4f} m/s; the daemon's {len(rows)} estimates "
           f"against `slipdaq replay` of its own log: {len(own)} differences")
    assert not own, f"the daemon's estimates differ from `slipdaq replay` of its own log: {own[:5]}"
    assert not unexplained, [r["time_s"] for r in unexplained]
    assert not over, f"{len(over)} windows over tolerance (diff, tol, d_max): {over[:5]}"
    assert all(x <= tol for x, tol in speeds), max(speeds)


# ---- case 4 ---------------------------------------------------------------------------------------------------

def test_case4_link_down_and_up(env: Env) -> None:
    """vcan0 down for at least 2 s while wpt_sender.py sends frames (25 Hz per wheel) and NMEA (10 Hz).

    The link stays down for at least 2 s and until the sender has tried to send (refused: ENETDOWN) and written NMEA
    lines over the outage (a busy host can hold the sender back) and 1.5 s have passed since the daemon reported the
    outage (so a /diagnostics record, one a second, falls inside), up to 8 s (the Seq byte counts 256 frames per
    wheel: 10 s at 25 Hz).
    When the link came back: after the sender's last refused send and after `ip link set vcan0 up` started — the
    later of the two is t_up (`ip` itself takes up to a second in the VM; IFF_UP polled in sysfs while it runs is
    reported too). Resume, as the daemon can be held to it whatever the sender's timing: the first frame the sender
    got through after the outage is the first frame in the log after it (nothing the link carried was missed), and
    the daemon's "CAN receiving again" line for that frame was read within 1 s of the frame's kernel stamp. From
    t_up to that stamp is the sender's part, reported with the rest.

    A frame whose send() succeeded just as the link went down can be dropped by the kernel (still queued for the
    device when it closed): such frames are allowed only there, and they count as lost like the refused ones.
    GPS: every NMEA line written is in the log, and each line written during the outage was read within 1 s.
    """
    d = env.tmp / "case4"
    gps = "/tmp/hil-gps-case4"
    cfg_path = write_config(d, gps)
    record, nmea_record = d / "sent.csv", d / "nmea-sent.csv"
    gps_lines = cruise_nmea(10.0, 120.0)  # more than the run needs: the sender is stopped
    write_nmea(d / "gps.nmea", gps_lines)
    sentences = [line for _, line in gps_lines]
    daemon = Daemon(env.zygote, cfg_path, d / "logs")
    sender = start_sender(OUTAGE_RATE_HZ, 600.0, go=daemon.go, delay_s=2.0, record=record, nmea=d / "gps.nmea",
                          gps_link=gps, nmea_record=nmea_record, gps_reader_pid=daemon.pid)
    try:
        _, m = sender.wait_line(r"^sender: go (\S+)", 600)
        t_start = float(m.group(1))
        time.sleep(max(0.0, t_start + OUTAGE_AT_S - time.time()))
        down = link("down")
        t_err, m_err = daemon.proc.wait_line(r"CAN receive error \((.*)\): no CAN frames until it clears",
                                             OUTAGE_MAX_S)

        def outage_seen(p: list[SenderProgress]) -> bool:
            first = next((x for x in p if x.at_s >= down.seen_s), None)
            return (first is not None and p[-1].at_s >= max(down.seen_s + OUTAGE_S, t_err + 1.5)
                    and p[-1].failed - first.failed >= 10 and p[-1].nmea - first.nmea >= 10)

        outage_ok = wait_progress(sender, outage_seen, OUTAGE_MAX_S - (time.time() - down.seen_s))
        up = link("up")
        assert outage_ok, (f"within {OUTAGE_MAX_S:g} s of outage, the sender did not try to send and write NMEA for "
                           f"{OUTAGE_S:g} s, or not for 1.5 s after the daemon reported the error")
        t_back, m_back = daemon.proc.wait_line(
            r"CAN receiving again after ([\d.]+) s \(outage 1; first frame stamped ([\d.]+)\)", 120)

        def traffic_after_up(p: list[SenderProgress]) -> bool:
            base = next((x for x in p if x.at_s > up.after_s), None)
            return base is not None and p[-1].sent - base.sent >= 4 * OUTAGE_RATE_HZ * OUTAGE_AFTER_S

        after_up = wait_progress(sender, traffic_after_up, 600)
        sender.signal(signal.SIGTERM)
        r = sender_result(sender, 300)
        assert after_up, "the sender did not get frames out after the outage"
        daemon.wait_frames(r["sent"], 600)
        result = daemon.stop()
    finally:
        if not bool(int(Path("/sys/class/net/vcan0/flags").read_text(), 16) & 1):
            link("up")
        sender.kill()
        daemon.proc.kill()

    keep(result.log, "case4-live.mcap")
    keep(record, "case4-sent.csv")
    log = read_log(result.log)
    sent = read_sent(record)
    written = read_nmea_record(nmea_record)
    logged = {(i, pulse_count(dd)) for i, v in log.by_id.items() for _, dd in v}
    missing = [s for s in sent if (s.can_id, s.n) not in logged]
    first_after = min(t for v in log.by_id.values() for t, _ in v if t > down.after_s)
    first_ok = min((s for s in sent if s.t_before > r["fail_last_s"]), key=lambda s: s.t_before)
    stamp_ok = {(i, pulse_count(dd)): t for i, v in log.by_id.items() for t, dd in v}.get((first_ok.can_id, first_ok.n))
    t_up = max(r["fail_last_s"], up.before_s)  # the link was still down at both
    resume_daemon_s = t_back - first_after
    lines = [line for _, line in log.nmea]
    read_at = dict(zip((i for i, _, _ in written), (t for t, _ in log.nmea)))
    in_outage = [(i, t1, read_at.get(i)) for i, t0, t1 in written if down.seen_s < t0 and t1 < up.before_s]
    outage_read_delay = max((t - t1 for _, t1, t in in_outage if t is not None), default=float("inf"))
    diag = diagnostics(result.log)
    during = [x for x in diag if t_err < x["time_s"] < up.before_s]
    report(f"case 4: `ip link set down` ran {down.after_s - down.before_s:.2f} s (link down {down.seen_s - down.before_s:.3f} s "
           f"into it), link down {up.seen_s - down.seen_s:.2f} s, `up` ran {up.after_s - up.before_s:.2f} s (link up "
           f"{up.seen_s - up.before_s:.3f} s into it); sender: {r['sent']} sent, {r['failed']} refused "
           f"({r['first_error']}), {len(missing)} sent but dropped by the kernel at link down; the daemon printed the "
           f"error {t_err - down.before_s:.2f} s after `ip link set down` started ({m_err.group(1)}); the sender's "
           f"first frame after the outage was sent {first_ok.t_before - t_up:.3f} s after t_up and is the first in "
           f"the log after it: {stamp_ok == first_after}; 'receiving again' read {resume_daemon_s * 1e3:.0f} ms "
           f"after its kernel stamp ({(t_back - t_up) * 1e3:.0f} ms after t_up; daemon's own outage figure "
           f"{m_back.group(1)} s); NMEA lines written during the outage {len(in_outage)}, all logged, read at most "
           f"{outage_read_delay * 1e3:.0f} ms after written; diagnostics records during the outage {len(during)}")
    # the daemon did not crash and finished a valid log with every frame the link carried
    assert finished(result.log)
    assert len(sent) == r["sent"] and log.total == result.can_frames == r["sent"] - len(missing)
    assert logged <= {(s.can_id, s.n) for s in sent}
    assert all(down.before_s - 0.1 <= s.t_before <= down.after_s for s in missing), missing
    assert r["failed"] > 0 and "ENETDOWN" in r["first_error"]
    assert result.lost_frames == r["failed"] + len(missing)  # what the link did not carry shows as Seq gaps
    # it reported the outage: a status-stream line, and the diagnostics
    assert "Network is down" in m_err.group(1) and t_err >= down.before_s
    assert float(m_back.group(2)) == pytest.approx(first_after, abs=1e-6)
    assert during and all(x["can_receiving"] is False and x["can_outages"] == 1 for x in during)
    assert "Network is down" in during[-1]["can_last_error"]
    assert diag[-1]["can_receiving"] is True and diag[-1]["can_outages"] == 1 and diag[-1]["can_reader_errors"] >= 1
    # GPS went on being logged: every line written, in order; those of the outage read while it lasted
    assert r["nmea_dropped"] == 0 and lines == [sentences[i] for i, _, _ in written] and result.bad_sentences == 0
    assert len(in_outage) >= 10 and outage_read_delay < RESUME_LIMIT_S
    # liveness: from the first frame after the outage, and reported within 1 s of its arrival
    assert stamp_ok == first_after, (first_ok, stamp_ok, first_after)
    assert resume_daemon_s < RESUME_LIMIT_S


# ---- case 3 and case 5 ------------------------------------------------------------------------------------------

def test_case3_load_and_case5_kernel_timestamps(env: Env) -> None:
    """Sustained wheel frames plus 20 Hz NMEA for 60 s, a SIGSTOP of the daemon at 20 s, then a burst of 10,000
    frames at 4 x 1 kHz (the finding: 10,000 frames sent while the reader was not reading arrived as 278; the
    daemon now reads concurrently and its socket has a 16 MiB receive buffer). Nothing lost: by total, Seq and frame
    by frame; every NMEA line written is in the log.

    Case 5's evidence: wpt_sender.py records time.time() just before and just after each send(); with vcan the kernel
    stamps the frame for the receiving sockets inside that call, so a kernel timestamp must lie between the two —
    also for the frames sent while the daemon was stopped and read only after SIGCONT (a user-space stamp would be
    after SIGCONT). The NMEA lines written during the pause are stamped when the daemon reads them: none inside it.
    The daemon stays stopped for at least 1 s and until the sender has sent 50 frames over at least 0.5 s and 3 NMEA
    lines while it was (a busy host can hold the sender back), up to 10 s.
    """
    d = env.tmp / "case3"
    gps = "/tmp/hil-gps-case3"
    cfg_path = write_config(d, gps)
    record, nmea_record = d / "sent.csv", d / "nmea-sent.csv"
    gps_lines = cruise_nmea(LOAD_GPS_HZ, LOAD_DURATION_S + 2)
    write_nmea(d / "gps.nmea", gps_lines)
    sentences = [line for _, line in gps_lines]
    daemon = Daemon(env.zygote, cfg_path, d / "logs")
    sender = start_sender(LOAD_RATE_HZ, LOAD_DURATION_S, go=daemon.go, delay_s=2.0, record=record,
                          then_burst=BURST_FRAMES, burst_rate_hz=BURST_RATE_HZ, nmea=d / "gps.nmea", gps_link=gps,
                          nmea_record=nmea_record, gps_reader_pid=daemon.pid)
    try:
        _, m = sender.wait_line(r"^sender: go (\S+)", 600)
        t_start = float(m.group(1))
        time.sleep(max(0.0, t_start + PAUSE_AT_S - time.time()))
        t_stop = time.time()
        daemon.proc.signal(signal.SIGSTOP)
        time.sleep(0.1)
        stopped = proc_state(daemon.pid)

        def paused_enough(p: list[SenderProgress]) -> bool:
            first = next((x for x in p if x.at_s > t_stop + 0.1), None)
            return (first is not None and time.time() >= t_stop + PAUSE_S and p[-1].at_s - first.at_s >= 0.5
                    and p[-1].sent - first.sent >= PAUSE_MIN_FRAMES and p[-1].nmea - first.nmea >= 3)

        wait_progress(sender, paused_enough, PAUSE_MAX_S - (time.time() - t_stop))
        t_cont = time.time()  # before the signal: the daemon may read (and stamp) before this process runs again
        daemon.proc.signal(signal.SIGCONT)
        r = sender_result(sender, LOAD_DURATION_S + 600)
        n = daemon.wait_frames(r["sent"], 1200)
        result = daemon.stop()
    finally:
        sender.kill()
        daemon.proc.kill()

    keep(result.log, "case3-live.mcap")
    keep(record, "case3-sent.csv")
    log = read_log(result.log)
    sent = read_sent(record)
    written = read_nmea_record(nmea_record)
    stamps = {(i, pulse_count(dd)): t for i, v in log.by_id.items() for t, dd in v}
    phase = r["phases"][0]
    burst = r["phases"][1] if BURST_FRAMES else {"sent": 0, "start_s": phase["end_s"], "end_s": phase["end_s"],
                                                 "rate_fps": 0.0}
    points = daemon.status_points()
    t_all = next((t for t, k in points if k >= r["sent"]), float("nan"))
    sent_times = sorted(s.t_after for s in sent)
    backlog = [bisect.bisect_right(sent_times, t) - k for t, k in points]  # sent but not yet processed, per line
    steady_backlog = max((b for (t, _), b in zip(points, backlog) if t <= phase["end_s"]), default=0)
    throughput = rate_while_backlogged(points, backlog)
    nmea_s = [t for t, _ in log.nmea]
    report(f"case 3: sender {phase['sent']} frames in {phase['end_s'] - phase['start_s']:.1f} s "
           f"({phase['rate_fps']:.0f} frames/s, schedule {4 * LOAD_RATE_HZ:g}), then a burst of {burst['sent']} in "
           f"{burst['end_s'] - burst['start_s']:.2f} s ({burst['rate_fps']:.0f} frames/s, schedule "
           f"{4 * BURST_RATE_HZ:g}); NMEA {len(written)} lines written, {len(log.nmea)} logged "
           f"({len(log.nmea) / (nmea_s[-1] - nmea_s[0]):.0f}/s); "
           f"daemon: {log.total} frames in the log, {r['sent'] - log.total} lost, Seq gaps "
           f"{[seq_gaps(log.by_id[i]) for i in IDS]}; backlog (sent, not yet processed) at most {steady_backlog} frames "
           f"before the burst, {max(backlog, default=0)} in all; processed "
           f"{f'{throughput:.0f}' if throughput else '(never 500 behind)'} frames/s while >= 500 behind; the "
           f"status line first showed all frames {t_all - burst['end_s']:.0f} s after the burst (lines every 5 s); "
           f"SO_RCVBUF "
           f"{_check_receive_buffer(result.log)} bytes")
    # case 3: nothing lost, by total, by Seq and frame by frame
    assert finished(result.log) and n == r["sent"] == len(sent) == phase["sent"] + burst["sent"]
    assert r["failed"] == 0 and burst["sent"] == BURST_FRAMES
    assert log.total == r["sent"] == result.can_frames and result.lost_frames == 0
    assert [seq_gaps(log.by_id[i]) for i in IDS] == [0, 0, 0, 0]
    assert set(stamps) == {(s.can_id, s.n) for s in sent}
    assert r["nmea_dropped"] == 0 and [line for _, line in log.nmea] == [sentences[i] for i, _, _ in written]
    assert result.bad_sentences == 0

    # case 5: kernel timestamps
    assert stopped == "T", f"daemon state {stopped!r} after SIGSTOP"
    in_send = [stamps[(s.can_id, s.n)] - s.t_before for s in sent
               if not s.t_before - EPS_S <= stamps[(s.can_id, s.n)] <= s.t_after + EPS_S]
    paused = sorted(stamps[(s.can_id, s.n)] for s in sent if s.t_before > t_stop + 0.1 and s.t_after < t_cont)
    read_at = dict(zip((i for i, _, _ in written), nmea_s))
    nmea_paused = [read_at[i] for i, t0, t1 in written if t0 > t_stop + 0.1 and t1 < t_cont]
    report(f"case 5: daemon stopped {t_cont - t_stop:.2f} s (state {stopped}); {len(paused)} frames sent meanwhile, "
           f"logged with timestamps from {paused[0] - t_stop:.3f} to {paused[-1] - t_stop:.3f} s after SIGSTOP "
           f"(largest step {max(b - a for a, b in zip(paused, paused[1:])) * 1e3:.0f} ms); "
           f"{len(sent) - len(in_send)} of {len(sent)} frame timestamps lie inside their send() call; "
           f"{len(nmea_paused)} NMEA lines written during the pause, stamped {min(nmea_paused) - t_cont:+.3f} to "
           f"{max(nmea_paused) - t_cont:+.3f} s from SIGCONT")
    assert not in_send, f"{len(in_send)} frames stamped outside their send(): first offsets {in_send[:5]}"
    assert len(paused) >= PAUSE_MIN_FRAMES, f"the sender got only {len(paused)} frames out during the pause"
    assert paused[-1] - paused[0] >= 0.5  # spread over the pause, not bunched at SIGCONT
    assert len(nmea_paused) >= 3 and min(nmea_paused) >= t_cont  # user-space stamps: taken once the daemon runs
