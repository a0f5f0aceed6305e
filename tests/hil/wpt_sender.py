#!/usr/bin/env python3
"""A minimal WPT traffic source for the HIL tests: standard library only (starts in a fraction of the time
`slipdaq simulate` needs inside the emulated VM) and writes straight to a raw SocketCAN socket.

Frames follow config/wpt.dbc: WPT_FL..RR at 0x310..0x313, PulseCount uint32 little-endian at bit 0, Seq uint8 at
bit 56. Slot k (k = 0, 1, ...) is due at start + k / (4 * rate) and belongs to wheel k % 4; its frame index per
wheel is n = k // 4, PulseCount = n (unique per wheel, so every frame can be identified in a log) and Seq = n % 256.

A send that fails because the link is down (ENETDOWN, ENXIO) is counted and the slot skipped, as a transducer keeps
counting while the logger's link is down; a full transmit queue (ENOBUFS) is retried. When behind schedule, frames
are sent back to back until caught up (the achieved rate is reported).

    wpt_sender.py --channel vcan0 --rate-hz 100 --duration 10 [--record sent.csv] [--then-burst N
                  [--burst-rate-hz R]] [--go GLOB [--delay S]]

--then-burst N: after the schedule, N more frames (same numbering) at R frames/s per wheel (0: back to back).

--record writes one line per sent frame: `can_id,n,t_before,t_after` (time.time() just before and just after the
send() that the kernel stamped). At the end one JSON line `{"sent": ..., "failed": ..., ...}` goes to stdout.
"""

from __future__ import annotations

import argparse
import errno
import glob
import json
import signal
import socket
import struct
import sys
import time

IDS = (0x310, 0x311, 0x312, 0x313)
CAN_FRAME = struct.Struct("=IB3x8s")
LINK_DOWN = (errno.ENETDOWN, errno.ENXIO, errno.ENODEV)


def payload(n: int) -> bytes:
    return struct.pack("<I3xB", n & 0xFFFFFFFF, n & 0xFF)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--channel", default="vcan0")
    ap.add_argument("--rate-hz", type=float, default=100.0, help="frames per second per wheel")
    ap.add_argument("--duration", type=float, default=10.0, help="seconds of schedule")
    ap.add_argument("--then-burst", type=int, default=0, help="after the schedule, this many frames more")
    ap.add_argument("--burst-rate-hz", type=float, default=0.0, help="their rate per wheel (0: back to back)")
    ap.add_argument("--record", help="write every sent frame's id, index and send-time bounds to this file")
    ap.add_argument("--start-at", type=float, help="wall-clock time (time.time()) of slot 0 (default: now)")
    ap.add_argument("--go", help="glob: start once a file matches it (e.g. the daemon's log)")
    ap.add_argument("--delay", type=float, default=0.0, help="seconds to wait after --go matched")
    a = ap.parse_args(argv)
    if a.go:
        while not glob.glob(a.go):
            time.sleep(0.05)
        time.sleep(a.delay)
    print(f"sender: go {time.time():.6f}", flush=True)

    stop = False

    def on_signal(_sig: int, _frame: object) -> None:
        nonlocal stop
        stop = True

    signal.signal(signal.SIGTERM, on_signal)
    signal.signal(signal.SIGINT, on_signal)
    sock = socket.socket(socket.AF_CAN, socket.SOCK_RAW, socket.CAN_RAW)
    sock.bind((a.channel,))
    sock.setsockopt(socket.SOL_CAN_RAW, socket.CAN_RAW_FILTER, b"")  # send only: receive nothing
    record = open(a.record, "w") if a.record else None
    sent = failed = retries = 0
    first_error: str | None = None
    fail_first: float | None = None
    fail_last: float | None = None
    if a.start_at is not None:
        time.sleep(max(0.0, a.start_at - time.time()))
    phases = [(int(a.duration * a.rate_hz * len(IDS)), 1.0 / (a.rate_hz * len(IDS)) if a.rate_hz > 0 else 0.0)]
    if a.then_burst > 0:
        phases.append((a.then_burst, 1.0 / (a.burst_rate_hz * len(IDS)) if a.burst_rate_hz > 0 else 0.0))
    start = a.start_at if a.start_at is not None else time.time()
    t_first = time.time()
    lines: list[str] = []
    k = 0
    phase_times: list[tuple[float, float, int]] = []
    for slots, period_s in phases:
        phase_start, phase_sent = time.time(), sent
        if k > 0:
            start = phase_start - k * period_s  # this phase's schedule starts now
        for _ in range(slots):
            if stop:
                break
            if period_s:
                ahead = start + k * period_s - time.time()
                if ahead > 0.0005:
                    time.sleep(ahead)
            can_id = IDS[k % 4]
            n = k // 4
            k += 1
            frame = CAN_FRAME.pack(can_id, 8, payload(n))
            while True:
                t0 = time.time()
                try:
                    sock.send(frame)
                except OSError as e:
                    if e.errno == errno.ENOBUFS:
                        retries += 1
                        time.sleep(0.0005)
                        continue
                    if e.errno in LINK_DOWN:
                        failed += 1
                        first_error = first_error or f"{errno.errorcode.get(e.errno, e.errno)}: {e.strerror}"
                        fail_first = fail_first if fail_first is not None else t0
                        fail_last = t0
                        break
                    raise
                t1 = time.time()
                sent += 1
                if record is not None:
                    lines.append(f"{can_id},{n},{t0:.9f},{t1:.9f}\n")
                    if len(lines) >= 1000:
                        record.writelines(lines)
                        lines.clear()
                break
        phase_times.append((phase_start, time.time(), sent - phase_sent))
    t_last = time.time()
    if record is not None:
        record.writelines(lines)
        record.close()
    elapsed = t_last - t_first
    print(json.dumps({
        "sent": sent, "failed": failed, "retries": retries, "slots": k, "elapsed_s": elapsed,
        "rate_fps": sent / elapsed if elapsed > 0 else 0.0, "first_error": first_error,
        "fail_first_s": fail_first, "fail_last_s": fail_last, "start_s": t_first, "end_s": t_last,
        "phases": [{"start_s": a0, "end_s": a1, "sent": n, "rate_fps": n / (a1 - a0) if a1 > a0 else 0.0}
                   for a0, a1, n in phase_times],
    }), flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
