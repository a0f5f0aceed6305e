"""`slipdaq run` on SocketCAN (vcan0), fed from other processes, GPS on a pseudo-terminal (issue 3). VM only.

Four daemon runs, one after the other, each `slipdaq run` its own process on interface "socketcan", channel "vcan0":

  case 1  the simulator's drive (accelerate, cruise, brake) put on vcan0 and a pty by tools/replay/replay_bus.py:
          every frame is in the log (by total, by Seq, payload by payload), the estimates follow the simulator's truth;
  case 2  case 1's live log put back on vcan0 by tools/replay/replay_bus.py into a second daemon: its estimates equal
          those of `slipdaq replay` of case 1's log within the tolerance stated below;
  case 4  `ip link set vcan0 down` for 2 s and up: the daemon reports the outage, keeps logging GPS, keeps its log
          valid, resumes within 1 s of the link coming back;
  case 3  load: wheel frames from wpt_sender.py at the highest rate that holds in the VM (see README.md) plus 20 Hz
          NMEA from `slipdaq simulate` for 60 s, then a burst of 10,000 frames at 4 wheels x 1 kHz: no frame lost;
          the daemon's socket has the receive buffer it asked for (SO_RCVBUFFORCE);
  case 5  (in case 3's run) the daemon is stopped (SIGSTOP) for 1 s: the frames sent meanwhile carry kernel receive
          timestamps (SO_TIMESTAMPNS) from inside their send() calls, spread over the pause, while the NMEA lines
          written meanwhile are stamped when read, after SIGCONT.

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
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import pytest

from hil_support import (
    IDS, Daemon, DaemonResult, LogContent, Zygote, bind_pytest, can_unavailable_reason, diagnostics, finished,
    link, percentile, proc_state, rate_while_backlogged, read_log, read_sent, report, sender_index, sender_result,
    seq_gaps, start_replay_bus, start_sender, start_simulate, write_config,
)

_reason = can_unavailable_reason()
if _reason:
    pytest.skip(_reason, allow_module_level=True)


def _env(name: str, default: float) -> float:
    return float(os.environ.get(name, default))


SIM_RATE_HZ = _env("SLIPDAQ_HIL_SIM_RATE_HZ", 25.0)
"""Case 1: WPT frames per second per wheel of the simulated drive (10 Hz GPS)."""
SIM_DURATION_S = _env("SLIPDAQ_HIL_SIM_DURATION_S", 20.0)
"""Case 1: one accelerate-cruise-brake cycle takes about 16 s."""
LOAD_RATE_HZ = _env("SLIPDAQ_HIL_LOAD_RATE_HZ", 25.0)
"""Case 3: sustained WPT frames per second per wheel (the issue's 1 kHz does not hold in the emulated VM)."""
LOAD_DURATION_S = _env("SLIPDAQ_HIL_LOAD_DURATION_S", 60.0)
LOAD_GPS_HZ = 20.0
BURST_FRAMES = int(_env("SLIPDAQ_HIL_BURST_FRAMES", 10_000))
BURST_RATE_HZ = 1000.0
"""Case 3: the burst's rate per wheel (4 kHz in all, the issue's target, as fast as the sender manages)."""
PAUSE_AT_S, PAUSE_S = 20.0, 1.0
"""Case 5: SIGSTOP this long after the load starts, for this long."""
OUTAGE_RATE_HZ = 25.0
OUTAGE_AT_S, OUTAGE_S, OUTAGE_RUN_S = 5.0, 2.0, 14.0
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
    import slipdaq.sim.emit  # noqa: F401
    import slipdaq.sources.mcap_log  # noqa: F401

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
    from slipdaq.sources.mcap_log import read_metadata

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
    source: Path
    src: LogContent
    truth: list[Any]
    start_utc_s: float
    sent: int
    result: DaemonResult
    log: LogContent


@pytest.fixture(scope="module")
def case1(env: Env) -> Case1:
    """The simulator's drive (slipdaq.sim.emit: the generator `slipdaq simulate` plays) written to a log, then put
    on vcan0 and a pty in real time by tools/replay/replay_bus.py (its own process) into `slipdaq run`.

    Why not `slipdaq simulate` itself: it integrates the vehicle model while it plays, and inside the emulated VM that
    costs more than real time (measured: a 20 s drive took 94 s to send), so its frames would not be stamped at
    their simulated times and no estimate could be compared with the truth. The generator is the same; generating
    ahead and replaying keeps the timing.
    """
    from slipdaq.config import load_config
    from slipdaq.records import CanFrame
    from slipdaq.sim.emit import SimSettings, generate
    from slipdaq.sinks.mcap_log import McapLogSink

    d = env.tmp / "case1"
    gps = "/tmp/hil-gps-case1"
    cfg_path = write_config(d, gps)
    cfg = load_config(cfg_path)
    settings = SimSettings(wpt_rate_hz=SIM_RATE_HZ, gps_rate_hz=10.0, seed=1)
    t0 = time.time()
    truth, records = [], []
    for ev in generate(cfg, "cycle", "paved", settings, duration_s=SIM_DURATION_S):
        if ev.truth is not None:
            truth.append(ev.truth)
        elif ev.record is not None:
            records.append(ev.record)
    source = d / "simulated-drive.mcap"
    sink = McapLogSink(source, cfg, mode="simulate", metadata={"hil": "case1 source"})
    for r in records:
        sink.on_raw(r)
    sink.close()
    report(f"case 1: generated the drive ({len(records)} records, {SIM_DURATION_S:g} s) in {time.time() - t0:.0f} s; "
           f"zygote imports took {env.zygote.wait_ready():.0f} s")

    daemon = Daemon(env.zygote, cfg_path, d / "logs")
    replay = start_replay_bus(env.zygote, source, gps, go=daemon.go, delay_s=1.5)
    try:
        t_go = replay.wait_line(r"^zygote-child: go", 600)[0]
        _, m = replay.wait_line(r"replay_bus: sent (\d+) CAN frames", 10 * SIM_DURATION_S + 300)
        t_end = time.time()
        assert replay.wait(60) == 0, replay.output()
        sent = int(m.group(1))
        daemon.wait_frames(sent, 900)
        result = daemon.stop()
    finally:
        replay.kill()
        daemon.proc.kill()
    keep(source, "case1-source.mcap")
    keep(result.log, "case1-live.mcap")
    report(f"case 1: replay_bus played the {SIM_DURATION_S:g} s drive in {t_end - t_go:.1f} s; sent {sent} frames "
           f"({SIM_RATE_HZ:g} Hz x 4) and {sum(1 for r in records if not isinstance(r, CanFrame))} NMEA lines")
    return Case1(source, read_log(source), truth, settings.start_utc_s, sent, result, read_log(result.log))


def test_case1_every_frame_sent_is_in_the_log(case1: Case1) -> None:
    src, log, res = case1.src, case1.log, case1.result
    assert case1.sent == src.total == 4 * int(SIM_RATE_HZ * SIM_DURATION_S)
    # by total, by Seq, and payload by payload in order
    assert log.total == case1.sent == res.can_frames
    assert {i: len(v) for i, v in log.by_id.items()} == {i: case1.sent // 4 for i in IDS}
    assert [seq_gaps(log.by_id[i]) for i in IDS] == [0, 0, 0, 0]
    assert res.lost_frames == 0 and diagnostics(res.log)[-1]["lost_frames"] == dict.fromkeys(("FL", "FR", "RL", "RR"), 0)
    _same_frames(log, src)
    # NMEA: every line from the first one the daemon read (it opens the pty when replay_bus has made it, up to its
    # reconnect back-off of 1 s later; lines written before that are flushed by the open)
    lines = [line for _, line in log.nmea]
    src_lines = [line for _, line in src.nmea]
    missed = len(src_lines) - len(lines)
    assert lines == src_lines[missed:] and 0 <= missed <= 3 * 10 * 2 and res.bad_sentences == 0
    assert finished(res.log)
    report(f"case 1: log has all {log.total} frames (Seq gaps 0, payloads identical), NMEA {len(lines)} of "
           f"{len(src_lines)} lines (the first {missed} written before the daemon had opened the pty); "
           f"SO_RCVBUF {_check_receive_buffer(res.log)} bytes")


def test_case1_estimates_follow_the_simulators_truth(case1: Case1) -> None:
    """Truth on the log's clock: the replay started the drive at (live stamp - simulated stamp), the median over all
    frames; each frame's difference from that is how late the sender sent it. Bounds as the host's live test
    (tests/test_end_to_end.py): median |error| < 0.5 and p95 < 2 percentage points of slip; slip positive while
    accelerating, negative while braking.

    The bounds judge the daemon on the windows whose frames the sender sent on time (within 10 ms, +-0.1 s around
    the window): a frame sent d late moves a window edge by d, a slip error of about d / 0.5 s, which no receiver
    can undo (the kernel stamps when the frame is sent). In the VM the sender (python-can, asyncio) is late now and
    then; at least half of the windows must be on time for the run to say anything. All windows are reported too.
    """
    from slipdaq.sim.truth import slip_error, truth_series
    from slipdaq.sources.mcap_log import iter_estimates

    offsets = _offsets(case1.log, case1.src)
    offset = statistics.median(offsets)
    late = [o - offset for o in offsets]
    src_t = [u for i in case1.src.by_id for u, _ in case1.src.by_id[i]]
    stalled = sorted(u - src_t[0] for u, x in zip(src_t, late) if x > 0.05)
    by_time = sorted(zip(src_t, late))
    times = [u for u, _ in by_time]

    def on_time(row: dict[str, Any]) -> bool:
        t = row["time_s"] - offset  # on the generated drive's clock
        half = 0.5 * row["window_s"] + 0.1
        i, j = bisect.bisect_left(times, t - half), bisect.bisect_right(times, t + half)
        return all(abs(x) <= 0.010 for _, x in by_time[i:j])

    rows = list(iter_estimates(case1.result.log))
    truth = truth_series(case1.truth, case1.start_utc_s + offset)
    fast = [r for r in rows if r["speed_mps"] is not None and r["speed_mps"] > 5.0]
    kept = [r for r in fast if on_time(r)]
    err_all = slip_error(rows, truth)
    err = slip_error(kept, truth)
    report(f"case 1: sender timing: frames stamped {percentile(late, 50) * 1e3:+.1f} ms (median), "
           f"{percentile(late, 95) * 1e3:+.1f} ms (p95), {max(late) * 1e3:+.1f} ms (max) from the median offset; "
           f"{len(stalled)} frames over 50 ms late (drive time {stalled[0] if stalled else 0:.1f}.."
           f"{stalled[-1] if stalled else 0:.1f} s); {len(rows)} estimates; slip error vs truth (speed > 5 m/s): "
           f"{len(kept)} of {len(fast)} estimates sent on time ({err.samples} wheel windows): median "
           f"{err.median_abs_points:.3f}, p95 {err.p95_abs_points:.3f}, max {err.max_abs_points:.3f}, RMS "
           f"{err.rms_points:.3f} points; all {err_all.samples} wheel windows: median {err_all.median_abs_points:.3f}, "
           f"p95 {err_all.p95_abs_points:.3f}, max {err_all.max_abs_points:.3f} points")
    assert len(kept) >= 0.5 * len(fast) and err.samples > 50, "the sender was too late too often to judge the daemon"
    assert err.median_abs_points < 0.5 and err.p95_abs_points < 2.0
    driving = [r for r in rows if r["accel_mps2"] and r["accel_mps2"] > 2 and r["slip_FL"] is not None]
    braking = [r for r in rows if r["accel_mps2"] and r["accel_mps2"] < -4 and r["slip_FL"] is not None]
    assert driving and braking
    assert sum(r["slip_FL"] > 0.01 for r in driving) > 0.8 * len(driving)
    assert sum(r["slip_FL"] < -0.01 for r in braking) > 0.8 * len(braking)


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
    `slipdaq replay` of the same log (which equals case 1's live estimates exactly).

    Same frames, same sentences; only their timestamps differ: the kernel stamps each frame again when replay_bus
    sends it and the daemon stamps each NMEA line when it reads it. After removing the replay's start (the median
    difference), what remains is how far the replay missed the recorded timing, d (measured per frame and per line).
    A window edge moved by d changes a wheel's distance by v*d, relative d/W for a window of W = 0.5 s, at both
    edges; the window itself moves with its GPS epoch's stamp, changing speed and distance by a*d, relative a*d/V.

    Tolerance, stated: for every matched wheel window |slip difference| <= 0.3 points + d_max * (2/W + |a|/V), with
    d_max the largest timing difference within 0.1 s of the window (1 ms: 0.3 + 0.4 points; 10 ms: 0.3 + 4 points);
    speed within 0.01 m/s + d_max * (2V/W + |a|). An epoch of `slipdaq replay` without a live estimate is allowed
    only where the replay was >= 20 ms off (the daemon rejects GPS fixes that arrive bunched with one timestamp).
    No bound on the plain distribution: how much of a run the replay keeps time depends on the VM. There the
    replay's jitter is up to tens of ms, and replay_bus starts its clock before it has read the log's first record,
    so the first seconds of a replay are sent up to 2 s late and then in a burst (see README.md); the windows
    there differ by up to 100 points, as the timing explains.
    """
    from slipdaq.cli import main as slipdaq_main
    from slipdaq.sources.mcap_log import iter_estimates

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
           f"windows: median {statistics.median(ds) * 100:.3f}, p90 {percentile(ds, 90) * 100:.3f}, max "
           f"{max(ds) * 100:.3f} points, over tolerance {len(over)}; where d_max < 10 ms ({len(clean)} windows): "
           f"max {max(clean, default=0) * 100:.3f} points; where < 20 ms ({len(kept_time)}): median "
           f"{statistics.median(kept_time or [0]) * 100:.3f}, max {max(kept_time, default=0) * 100:.3f} points; "
           f"|speed diff| max {max(x for x, _ in speeds):.4f} m/s")
    assert len(ds) >= 80, "the replay was too far off to compare (see the figures)"
    assert not unexplained, [r["time_s"] for r in unexplained]
    assert not over, f"{len(over)} windows over tolerance (diff, tol, d_max): {over[:5]}"
    assert all(x <= tol for x, tol in speeds), max(speeds)


# ---- case 4 ---------------------------------------------------------------------------------------------------

def test_case4_link_down_and_up(env: Env) -> None:
    """vcan0 down for 2 s while wpt_sender.py sends (25 Hz per wheel) and `slipdaq simulate` (GPS only) writes NMEA.

    When the link came back: after the sender's last refused send (ENETDOWN: the link was still down then; it
    tries every 10 ms) and after `ip link set vcan0 up` started — the later of the two is t_up (`ip` itself takes
    up to a second in the VM; IFF_UP polled in sysfs while it runs is reported too, but the poll can lag). From t_up
    the resume is measured twice: (a) to the kernel timestamp of the first frame in the log after the outage, when
    the kernel handed it to the daemon's socket; (b) to the moment the test read the daemon's "CAN receiving again"
    line, so the daemon had read, logged and reported that frame (this includes the pipe to the test). Both are upper
    bounds of the resume time, and both must be under 1 s.

    A frame whose send() succeeded just as the link went down can be dropped by the kernel (still queued for the
    device when it closed): such frames are allowed only there, and they count as lost like the refused ones.
    """
    d = env.tmp / "case4"
    gps = "/tmp/hil-gps-case4"
    cfg_path = write_config(d, gps)
    record = d / "sent.csv"
    daemon = Daemon(env.zygote, cfg_path, d / "logs")
    sim = start_simulate(env.zygote, cfg_path, gps, OUTAGE_RUN_S + 4, wpt_rate_hz=0, gps_rate_hz=10, go=daemon.go,
                         delay_s=0.5, name="simulate-gps")
    sender = start_sender(OUTAGE_RATE_HZ, OUTAGE_RUN_S, go=daemon.go, delay_s=2.0, record=record)
    try:
        _, m = sender.wait_line(r"^sender: go (\S+)", 600)
        t_start = float(m.group(1))
        time.sleep(max(0.0, t_start + OUTAGE_AT_S - time.time()))
        down = link("down")
        time.sleep(max(0.0, down.seen_s + OUTAGE_S - time.time()))
        up = link("up")
        t_err, m_err = daemon.proc.wait_line(r"CAN receive error \((.*)\): no CAN frames until it clears", 60)
        t_back, m_back = daemon.proc.wait_line(
            r"CAN receiving again after ([\d.]+) s \(outage 1; first frame stamped ([\d.]+)\)", 120)
        r = sender_result(sender, 300)
        assert sim.wait(300) == 0, sim.output()
        daemon.wait_frames(r["sent"], 600)
        result = daemon.stop()
    finally:
        if not bool(int(Path("/sys/class/net/vcan0/flags").read_text(), 16) & 1):
            link("up")
        sender.kill()
        sim.kill()
        daemon.proc.kill()

    keep(result.log, "case4-live.mcap")
    keep(record, "case4-sent.csv")
    log = read_log(result.log)
    sent = read_sent(record)
    logged = {(i, sender_index(dd)) for i, v in log.by_id.items() for _, dd in v}
    missing = [(i, k, t0) for i, k, t0, _ in sent if (i, k) not in logged]
    first_after = min(t for v in log.by_id.values() for t, _ in v if t > down.after_s)
    t_up = max(r["fail_last_s"], up.before_s)  # the link was still down at both
    first_ok = min(t1 for _, _, t0, t1 in sent if t0 > r["fail_last_s"])  # and up at this one
    resume_log_s = first_after - t_up
    resume_daemon_s = t_back - t_up
    nmea_in_outage = [t for t, _ in log.nmea if down.after_s < t < up.before_s]
    nmea_gap = max(b - a for (a, _), (b, _) in zip(log.nmea, log.nmea[1:]) if down.before_s - 1 < a < up.after_s + 1)
    diag = diagnostics(result.log)
    during = [x for x in diag if t_err < x["time_s"] < up.before_s]
    report(f"case 4: `ip link set down` ran {down.after_s - down.before_s:.2f} s (link down {down.seen_s - down.before_s:.3f} s "
           f"into it), `up` ran {up.after_s - up.before_s:.2f} s (link up {up.seen_s - up.before_s:.3f} s into it); "
           f"sender: {r['sent']} sent, {r['failed']} refused ({r['first_error']}), {len(missing)} sent but dropped "
           f"by the kernel at link down; the daemon printed the error {t_err - down.before_s:.2f} s after `ip link set "
           f"down` started ({m_err.group(1)}); the link came up between {t_up - up.before_s:.3f} and "
           f"{first_ok - up.before_s:.3f} s after `ip link set up` started; from the first: first frame in the log "
           f"{resume_log_s * 1e3:.0f} ms, 'receiving again' read {resume_daemon_s * 1e3:.0f} ms (daemon's own outage "
           f"figure {m_back.group(1)} s); "
           f"NMEA lines logged during the outage {len(nmea_in_outage)}, largest NMEA gap around it {nmea_gap:.2f} s; "
           f"diagnostics records during the outage {len(during)}")
    # the daemon did not crash and finished a valid log with every frame the link carried
    assert finished(result.log)
    assert len(sent) == r["sent"] and log.total == result.can_frames == r["sent"] - len(missing)
    assert logged <= {(i, k) for i, k, _, _ in sent}
    assert all(down.before_s - 0.1 <= t0 <= down.after_s for _, _, t0 in missing), missing
    assert r["failed"] > 0 and "ENETDOWN" in r["first_error"]
    assert result.lost_frames == r["failed"] + len(missing)  # what the link did not carry shows as Seq gaps
    # it reported the outage: a status-stream line, and the diagnostics
    assert "Network is down" in m_err.group(1) and t_err >= down.before_s
    assert float(m_back.group(2)) == pytest.approx(first_after, abs=1e-6)
    assert during and all(x["can_receiving"] is False and x["can_outages"] == 1 for x in during)
    assert "Network is down" in during[-1]["can_last_error"]
    assert diag[-1]["can_receiving"] is True and diag[-1]["can_outages"] == 1 and diag[-1]["can_reader_errors"] >= 1
    # GPS went on being logged
    assert len(nmea_in_outage) >= 3 * 10 * OUTAGE_S * 0.5 and nmea_gap < 1.0
    # liveness: resumed within 1 s of the link coming back
    assert resume_log_s < RESUME_LIMIT_S and resume_daemon_s < RESUME_LIMIT_S


# ---- case 3 and case 5 ------------------------------------------------------------------------------------------

def test_case3_load_and_case5_kernel_timestamps(env: Env) -> None:
    """Sustained wheel frames plus 20 Hz NMEA for 60 s, a 1 s SIGSTOP of the daemon at 20 s, then a burst of 10,000
    frames at 4 x 1 kHz (the finding: 10,000 frames sent while the reader was not reading arrived as 278; the
    daemon now reads concurrently and its socket has a 16 MiB receive buffer).

    Case 5's evidence: wpt_sender.py records time.time() just before and just after each send(); with vcan the kernel
    stamps the frame for the receiving sockets inside that call, so a kernel timestamp must lie between the two —
    also for the frames sent while the daemon was stopped and read only after SIGCONT (a user-space stamp would be
    after SIGCONT). The NMEA lines written during the pause are stamped when the daemon reads them: none inside it.
    """
    d = env.tmp / "case3"
    gps = "/tmp/hil-gps-case3"
    cfg_path = write_config(d, gps)
    record = d / "sent.csv"
    daemon = Daemon(env.zygote, cfg_path, d / "logs")
    sim = start_simulate(env.zygote, cfg_path, gps, LOAD_DURATION_S + 6, wpt_rate_hz=0, gps_rate_hz=LOAD_GPS_HZ,
                         go=daemon.go, delay_s=0.5, name="simulate-gps")
    sender = start_sender(LOAD_RATE_HZ, LOAD_DURATION_S, go=daemon.go, delay_s=2.0, record=record,
                          then_burst=BURST_FRAMES, burst_rate_hz=BURST_RATE_HZ)
    try:
        _, m = sender.wait_line(r"^sender: go (\S+)", 600)
        t_start = float(m.group(1))
        time.sleep(max(0.0, t_start + PAUSE_AT_S - time.time()))
        t_stop = time.time()
        daemon.proc.signal(signal.SIGSTOP)
        time.sleep(0.1)
        stopped = proc_state(daemon.pid)
        time.sleep(max(0.0, t_stop + PAUSE_S - time.time()))
        daemon.proc.signal(signal.SIGCONT)
        t_cont = time.time()
        r = sender_result(sender, LOAD_DURATION_S + 600)
        assert sim.wait(300) == 0, sim.output()
        n = daemon.wait_frames(r["sent"], 1200)
        result = daemon.stop()
    finally:
        sender.kill()
        sim.kill()
        daemon.proc.kill()

    keep(result.log, "case3-live.mcap")
    keep(record, "case3-sent.csv")
    log = read_log(result.log)
    sent = read_sent(record)
    stamps = {(i, sender_index(dd)): t for i, v in log.by_id.items() for t, dd in v}
    phase = r["phases"][0]
    burst = r["phases"][1] if BURST_FRAMES else {"sent": 0, "start_s": phase["end_s"], "end_s": phase["end_s"],
                                                 "rate_fps": 0.0}
    points = daemon.status_points()
    t_all = next((t for t, k in points if k >= r["sent"]), float("nan"))
    sent_times = sorted(t1 for _, _, _, t1 in sent)
    backlog = [bisect.bisect_right(sent_times, t) - k for t, k in points]  # sent but not yet processed, per line
    steady_backlog = max((b for (t, _), b in zip(points, backlog) if t <= phase["end_s"]), default=0)
    throughput = rate_while_backlogged(points, backlog)
    nmea_s = [t for t, _ in log.nmea]
    report(f"case 3: sender {phase['sent']} frames in {phase['end_s'] - phase['start_s']:.1f} s "
           f"({phase['rate_fps']:.0f} frames/s, schedule {4 * LOAD_RATE_HZ:g}), then a burst of {burst['sent']} in "
           f"{burst['end_s'] - burst['start_s']:.2f} s ({burst['rate_fps']:.0f} frames/s, schedule "
           f"{4 * BURST_RATE_HZ:g}); NMEA {len(log.nmea)} lines ({len(log.nmea) / (nmea_s[-1] - nmea_s[0]):.0f}/s); "
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
    assert set(stamps) == {(i, k) for i, k, _, _ in sent}
    assert result.bad_sentences == 0 and len(log.nmea) >= 0.9 * 3 * LOAD_GPS_HZ * LOAD_DURATION_S

    # case 5: kernel timestamps
    assert stopped == "T", f"daemon state {stopped!r} after SIGSTOP"
    in_send = [stamps[(i, k)] - t0 for i, k, t0, t1 in sent if not t0 - EPS_S <= stamps[(i, k)] <= t1 + EPS_S]
    paused = sorted(stamps[(i, k)] for i, k, t0, t1 in sent if t0 > t_stop + 0.1 and t1 < t_cont)
    nmea_paused = [t for t in nmea_s if t_stop + 0.1 < t < t_cont]
    nmea_after = [t for t in nmea_s if t >= t_cont]
    report(f"case 5: daemon stopped {t_cont - t_stop:.2f} s (state {stopped}); {len(paused)} frames sent meanwhile, "
           f"logged with timestamps from {paused[0] - t_stop:.3f} to {paused[-1] - t_stop:.3f} s after SIGSTOP "
           f"(largest step {max(b - a for a, b in zip(paused, paused[1:])) * 1e3:.0f} ms); "
           f"{len(sent) - len(in_send)} of {len(sent)} frame timestamps lie inside their send() call; "
           f"NMEA lines stamped during the pause {len(nmea_paused)}, first NMEA stamp after it "
           f"{nmea_after[0] - t_cont:+.3f} s from SIGCONT")
    assert not in_send, f"{len(in_send)} frames stamped outside their send(): first offsets {in_send[:5]}"
    assert len(paused) >= 0.5 * 4 * LOAD_RATE_HZ * PAUSE_S
    assert paused[-1] - paused[0] >= 0.5 * PAUSE_S  # spread over the pause, not bunched at SIGCONT
    assert not nmea_paused  # user-space stamps: taken only once the daemon runs again
