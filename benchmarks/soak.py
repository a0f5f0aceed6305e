"""Soak: the live daemon under a long, full-rate drive — 4 wheels x 1 kHz WPT frames on python-can's virtual bus and
20 Hz NMEA (RMC, GGA, VTG: 60 lines/s) on a real pseudo-terminal, simulator and daemon in one process (the virtual
bus only works inside one). Checks what docs/reliability.md promises:

- no frame lost: every frame the simulator sent is in the log (counted per wheel), Seq has no gap, lost_frames = 0;
- memory: the resident set grows by less than 5 MB after the first minute (the first 20 % of a short run); its slope
  after the first 2 minutes (least squares over the samples, MB per hour) is printed: a day's run must not grow;
- the daemon keeps up: the virtual bus's receive queue (the frames not yet read) stays small;
- replay: the log replays to the same estimates, every field of every one, bit for bit.

The process is set up as `slipdaq run`'s: python-can without asammdf (slipdaq.__main__.import_python_can) and the C
allocator's thresholds held fixed (slipdaq/allocator.py).

    .venv/bin/python -m benchmarks.soak [--duration 600] [--wpt-rate-hz 1000] [--gps-rate-hz 20] [--log-dir D]

Prints one line per sample (elapsed, RSS, CAN frames, backlog) and a JSON summary; exit status 1 when a check fails.
tests/live/test_reliability_soak.py runs a short version (run_soak).
"""

# ruff: noqa: E402  (python-can imported first, as the process of `slipdaq run` imports it)
from __future__ import annotations

from slipdaq.__main__ import import_python_can

import_python_can(with_mf4=False)  # without asammdf, and its pandas and pyarrow, as `slipdaq run` has it

import argparse
import asyncio
import contextlib
import io
import json
import os
import sys
import tempfile
import time
from dataclasses import asdict, dataclass, field, replace
from pathlib import Path
from typing import TextIO

import can

from slipdaq.allocator import fix_malloc_thresholds
from slipdaq.config import Config
from slipdaq.live.daemon import new_log_path, open_bus, run_daemon
from slipdaq.live.demo import demo_config
from slipdaq.live.simulate import PtyGps
from slipdaq.logformat.reader import config_from_log, iter_estimates, iter_raw_records
from slipdaq.offline.run import process_to_log
from slipdaq.records import CanFrame
from slipdaq.sim.emit import SimSettings, generate
from slipdaq.sim.realtime import play

RSS_LIMIT_BYTES = 5 * 1024 * 1024
SLOPE_AFTER_S = 120.0
"""The RSS slope is fitted to the samples after this (start-up, numba's kernels and the first maneuvers are in)."""


def rss_bytes() -> int:
    with open("/proc/self/status") as f:
        for line in f:
            if line.startswith("VmRSS:"):
                return int(line.split()[1]) * 1024
    return 0


@dataclass
class SoakResult:
    duration_s: float
    wpt_rate_hz: float
    gps_rate_hz: float
    log_path: str
    log_bytes: int
    frames_sent: int
    frames_logged: int
    frames_lost: int
    seq_gaps: int
    nmea_lines_sent: int
    nmea_lines_logged: int
    estimates: int
    rss_start_bytes: int
    rss_after_warmup_bytes: int
    rss_end_bytes: int
    rss_growth_after_warmup_bytes: int
    rss_max_bytes: int
    warmup_s: float
    backlog_max_frames: int
    backlog_end_frames: int
    drive_wall_s: float
    """Wall time the simulator took to send the drive: about duration_s when the process keeps up with the rate
    (simulator and daemon share one event loop, so a daemon that cannot keep up slows the sender down instead of
    losing frames)."""
    cpu_s: float
    replay_equal: bool
    replay_s: float
    rss_slope_mb_per_h: float | None = None
    """Least-squares slope of the resident set over the samples after slope_after_s, MB per hour (None: fewer than 3)."""
    slope_after_s: float = SLOPE_AFTER_S
    samples: list[tuple[float, int, int, int]] = field(default_factory=list)
    """(elapsed s, RSS bytes, CAN frames sent so far, frames waiting in the daemon's receive queue)."""

    @property
    def ok(self) -> bool:
        return (self.frames_lost == 0 and self.seq_gaps == 0 and self.frames_logged == self.frames_sent
                and self.rss_growth_after_warmup_bytes < RSS_LIMIT_BYTES and self.replay_equal
                and self.nmea_lines_logged == self.nmea_lines_sent)

    def summary(self) -> dict[str, object]:
        d = asdict(self)
        d.pop("samples")
        d["ok"] = self.ok
        return d


class _CountingPty(PtyGps):
    """The GPS port of the soak: what does not fit into the pty's buffer (the daemon shares the event loop and was
    late reading) waits here and goes out with the next write, in order, so a slow daemon delays lines instead of
    losing them, as with the CAN frames (PtyGps alone drops them, as a UART would)."""

    def __init__(self) -> None:
        super().__init__()
        self.lines = 0
        self.pending = b""

    def write(self, data: bytes) -> None:  # type: ignore[override]
        self.lines += data.count(b"\n")
        self.pending += data
        self.flush()

    def flush(self) -> None:
        try:
            while self.pending:
                self.pending = self.pending[os.write(self.master_fd, self.pending):]
        except BlockingIOError:
            pass


def _opened(path: str) -> int:
    """How many of this process's file descriptors are open on path."""
    n = 0
    for fd in os.listdir("/proc/self/fd"):
        with contextlib.suppress(OSError):
            n += os.readlink(f"/proc/self/fd/{fd}") == path
    return n


async def _soak(
    duration_s: float, log_dir: Path, wpt_rate_hz: float, gps_rate_hz: float, sample_every_s: float,
    warmup_s: float, out: TextIO | None,
) -> tuple[SoakResult, Config]:
    gps = _CountingPty()
    channel = f"slipdaq-soak-{os.getpid()}-{id(gps)}"
    cfg = demo_config(gps.path, channel)
    settings = SimSettings(wpt_rate_hz=wpt_rate_hz, gps_rate_hz=gps_rate_hz)
    samples: list[tuple[float, int, int, int]] = []
    sent = {"frames": 0}
    timing = {"drive_wall_s": 0.0}
    stop = asyncio.Event()
    try:
        with open_bus(cfg) as daemon_bus, can.Bus(interface="virtual", channel=channel) as sim_bus:
            queue = getattr(daemon_bus, "queue", None)

            def backlog() -> int:
                return queue.qsize() if queue is not None else 0

            class CountingBus:  # counts what the simulator sends
                def send(self, msg: can.Message, timeout: float | None = None) -> None:
                    sim_bus.send(msg, timeout)
                    sent["frames"] += 1

            async def sampler(t0: float) -> None:
                while not stop.is_set():
                    samples.append((time.monotonic() - t0, rss_bytes(), sent["frames"], backlog()))
                    if out is not None:
                        e, r, n, b = samples[-1]
                        print(f"soak: {e:6.0f} s  RSS {r / 1e6:7.1f} MB  frames {n:9d}  backlog {b:6d}", file=out,
                              flush=True)
                    try:
                        await asyncio.wait_for(stop.wait(), sample_every_s)
                    except TimeoutError:
                        pass

            async def drive() -> None:
                # start once the daemon has the GPS port open (opening it flushes what was written before): under
                # load its start-up takes longer than any fixed delay
                deadline = time.monotonic() + 30.0
                while _opened(gps.path) < 2 and time.monotonic() < deadline:  # ours, and the daemon's
                    await asyncio.sleep(0.02)
                run = replace(settings, start_utc_s=time.time() + 0.1)
                events = generate(cfg, "cycle", "paved", run, duration_s=duration_s)
                t = time.monotonic() + max(0.0, run.start_utc_s - time.time())  # when sim time 0 comes
                await play(events, bus=CountingBus(), nmea_write=gps.write,  # type: ignore[arg-type]
                           start_wall_s=run.start_utc_s)
                timing["drive_wall_s"] = time.monotonic() - t
                # let the daemon read what is queued (it never should be much): the CAN backlog and the GPS lines
                # (the pty's input queue empty twice, 0.1 s apart: the kernel moves written bytes there by itself),
                # then stop it
                deadline = time.monotonic() + 10.0
                while backlog() and time.monotonic() < deadline:
                    await asyncio.sleep(0.05)
                empty = 0
                while empty < 2 and time.monotonic() < deadline:
                    await asyncio.sleep(0.1)
                    gps.flush()
                    empty = empty + 1 if not gps.pending and gps.unread_bytes() == 0 else 0
                await asyncio.sleep(0.5)
                stop.set()

            cpu0 = time.process_time()
            t0 = time.monotonic()
            async with asyncio.TaskGroup() as tg:
                tg.create_task(sampler(t0))
                tg.create_task(drive())
                result = await run_daemon(cfg, daemon_bus, new_log_path(log_dir, "soak"), status_stream=io.StringIO(),
                                          status_every_s=60.0, stop=stop, metadata={"soak": "1"})
            cpu = time.process_time() - cpu0
            samples.append((time.monotonic() - t0, rss_bytes(), sent["frames"], backlog()))
            backlog_end = backlog()
    finally:
        gps.close()
    return _check(result, samples, sent["frames"], gps.lines, duration_s, wpt_rate_hz, gps_rate_hz, warmup_s,
                  backlog_end, cpu, timing["drive_wall_s"]), cfg


def rss_slope_mb_per_h(samples: list[tuple[float, int, int, int]], after_s: float) -> float | None:
    """Least-squares slope of (elapsed s, RSS bytes) over the samples after after_s, in MB per hour."""
    pts = [(t, r / 1e6) for t, r, _, _ in samples if t >= after_s]
    if len(pts) < 3:
        return None
    mt = sum(t for t, _ in pts) / len(pts)
    mr = sum(r for _, r in pts) / len(pts)
    stt = sum((t - mt) ** 2 for t, _ in pts)
    return 3600.0 * sum((t - mt) * (r - mr) for t, r in pts) / stt if stt > 0 else None


def _check(result, samples, frames_sent, lines_sent, duration_s, wpt_rate_hz, gps_rate_hz, warmup_s, backlog_end,
           cpu, drive_wall_s, slope_after_s=SLOPE_AFTER_S) -> SoakResult:  # type: ignore[no-untyped-def]
    path = result.log_path
    last_seq: dict[int, int] = {}
    seq_gaps = frames = lines = 0
    for r in iter_raw_records(path):
        if isinstance(r, CanFrame):
            frames += 1
            s = r.data[7]
            if r.arbitration_id in last_seq and (s - last_seq[r.arbitration_id]) % 256 != 1:
                seq_gaps += 1
            last_seq[r.arbitration_id] = s
        else:
            lines += 1
    t = time.monotonic()
    replay = path.with_name(path.stem + "-replay.mcap")
    process_to_log(config_from_log(path), iter_raw_records(path), replay, "replay", stream=io.StringIO())
    replayed = list(iter_estimates(replay))
    live = list(iter_estimates(path))
    replay_s = time.monotonic() - t
    after = [s for s in samples if s[0] >= warmup_s] or samples[-1:]
    rss_warm = after[0][1]
    return SoakResult(
        duration_s=duration_s, wpt_rate_hz=wpt_rate_hz, gps_rate_hz=gps_rate_hz, log_path=str(path),
        log_bytes=path.stat().st_size, frames_sent=frames_sent, frames_logged=frames,
        frames_lost=result.lost_frames + max(frames_sent - frames, 0), seq_gaps=seq_gaps,
        nmea_lines_sent=lines_sent, nmea_lines_logged=lines, estimates=len(live),
        rss_start_bytes=samples[0][1], rss_after_warmup_bytes=rss_warm, rss_end_bytes=samples[-1][1],
        rss_growth_after_warmup_bytes=max(s[1] for s in after) - rss_warm, rss_max_bytes=max(s[1] for s in samples),
        warmup_s=warmup_s, backlog_max_frames=max(s[3] for s in samples), backlog_end_frames=backlog_end,
        drive_wall_s=drive_wall_s, cpu_s=cpu, replay_equal=replayed == live and len(live) > 0, replay_s=replay_s,
        rss_slope_mb_per_h=rss_slope_mb_per_h(samples, slope_after_s), slope_after_s=slope_after_s, samples=samples,
    )


def run_soak(
    duration_s: float, log_dir: Path, *, wpt_rate_hz: float = 1000.0, gps_rate_hz: float = 20.0,
    sample_every_s: float = 5.0, warmup_s: float | None = None, out: TextIO | None = None,
    slope_after_s: float = SLOPE_AFTER_S,
) -> SoakResult:
    """warmup_s: RSS growth is measured after this (default: 60 s, or a fifth of a shorter run); slope_after_s: the
    RSS slope is fitted after this."""
    warm = warmup_s if warmup_s is not None else min(60.0, duration_s / 5)
    result, _ = asyncio.run(_soak(duration_s, log_dir, wpt_rate_hz, gps_rate_hz, sample_every_s, warm, out))
    return replace(result, rss_slope_mb_per_h=rss_slope_mb_per_h(result.samples, slope_after_s),
                   slope_after_s=slope_after_s)


def _slope_text(slope: float | None) -> str:
    return "— (too few samples)" if slope is None else f"{slope:+.2f} MB/h"


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--duration", type=float, default=600.0, help="seconds of driving (default 600)")
    p.add_argument("--wpt-rate-hz", type=float, default=1000.0)
    p.add_argument("--gps-rate-hz", type=float, default=20.0)
    p.add_argument("--sample-every", type=float, default=10.0, help="RSS sample period, s")
    p.add_argument("--warmup", type=float, default=None, help="RSS growth counts after this, s (default: 60 s or a fifth)")
    p.add_argument("--slope-after", type=float, default=SLOPE_AFTER_S,
                   help=f"the RSS slope is fitted to the samples after this, s (default {SLOPE_AFTER_S:g})")
    p.add_argument("--log-dir", help="where the log goes (default: a temporary directory, deleted)")
    p.add_argument("--json", help="write the summary and the samples here")
    a = p.parse_args(argv)
    fix_malloc_thresholds()  # as the process of slipdaq run or import does (slipdaq/allocator.py)
    with tempfile.TemporaryDirectory() as tmp:
        log_dir = Path(a.log_dir) if a.log_dir else Path(tmp)
        r = run_soak(a.duration, log_dir, wpt_rate_hz=a.wpt_rate_hz, gps_rate_hz=a.gps_rate_hz,
                     sample_every_s=a.sample_every, warmup_s=a.warmup, out=sys.stdout, slope_after_s=a.slope_after)
        s = r.summary()
    print(json.dumps(s, indent=1))
    if a.json:
        Path(a.json).write_text(json.dumps(s | {"samples": r.samples}, indent=1))
    print(f"soak: {'OK' if r.ok else 'FAILED'}: {r.frames_logged}/{r.frames_sent} frames logged, "
          f"{r.frames_lost} lost, {r.seq_gaps} Seq gaps, RSS +{r.rss_growth_after_warmup_bytes / 1e6:.2f} MB after "
          f"{r.warmup_s:.0f} s (max {r.rss_max_bytes / 1e6:.1f} MB), RSS slope after {r.slope_after_s:.0f} s "
          f"{_slope_text(r.rss_slope_mb_per_h)}, backlog max {r.backlog_max_frames} frames, "
          f"drive sent in {r.drive_wall_s:.0f} s of wall time (real time: {r.duration_s:.0f} s), CPU {r.cpu_s:.0f} s, "
          f"replay equal: {r.replay_equal}")
    return 0 if r.ok else 1


if __name__ == "__main__":
    sys.exit(main())
