#!/usr/bin/env python3
"""The HIL tests' traffic source: WPT frames straight to a raw SocketCAN socket and, optionally, NMEA lines to a
pseudo-terminal. Standard library only (starts in a fraction of the time `slipdaq simulate` needs inside the
emulated VM), one process, every send and write recorded with the time just before and just after it.

Frames follow config/wpt.dbc: WPT_FL..RR at 0x310..0x313, PulseCount uint32 little-endian at bit 0, Seq uint8 at
bit 56. Slot k (k = 0, 1, ...) is due at start + k / (4 * rate) and belongs to wheel k % 4; its frame index per
wheel is n = k // 4 and Seq = n % 256. PulseCount is n (unique per wheel, so every frame can be found in a log),
or with --drive the wheel's pulse count at the moment the frame is sent: a transducer samples its counter when it
transmits, so a frame sent late (the machine was busy) is late but not wrong: its count and its kernel receive
timestamp describe the same instant, to within its send() call (recorded).

A send that fails because the link is down (ENETDOWN, ENXIO) is counted and the slot skipped, as a transducer keeps
counting while the logger's link is down; a full transmit queue (ENOBUFS) is retried. When behind schedule, frames
are sent back to back until caught up (the achieved rate is reported).

    wpt_sender.py --channel vcan0 --rate-hz 100 --duration 10 [--record sent.csv] [--drive drive.json]
                  [--then-burst N [--burst-rate-hz R]] [--nmea lines.txt --gps-link L [--nmea-record nmea.csv]]
                  [--mti messages.txt --mti-link L]
                  [--go GLOB [--gps-reader-pid PID] [--delay S]]

--then-burst N: after the schedule, N more frames (same numbering) at R frames/s per wheel (0: back to back).
--drive: JSON {"start_count": C, "times_s": [...], "pulses": [[...] x 4 wheels]}: pulses since the start (float)
at drive times; PulseCount = (C + floor(pulses interpolated at time.time() - start)) mod 2^32 (as
slipdaq.sim.emit.pulse_count), taken just before each send() (and again before a retried one).
--nmea: lines `T SENTENCE`, written (with CRLF, one write per line) T seconds after the start to a new
pseudo-terminal in raw mode; --gps-link makes a symlink to it. The pty exists from the sender's start; with
--gps-reader-pid the sender also waits (after --go) until that process has it open. At the end the sender waits
(up to 60 s) until its reader has read everything written before it closes the pty.
--mti: an Xsens MTi's messages, lines `T HEX` (the message's bytes in hex), written one write each T seconds after
the start to a second pseudo-terminal (--mti-link), as --nmea's lines; with --gps-reader-pid that process must have
both open.

--record writes one line per sent frame: `can_id,n,t_before,t_after[,PulseCount]` (time.time() just before and just
after the send() that the kernel stamped; PulseCount with --drive); --nmea-record one line per written line:
`i,t_before,t_after` (i: its line number in --nmea, from 0). While running, `sender: at T sent S failed F nmea M`
every 0.25 s; at the end one JSON line `{"sent": ..., "failed": ..., ...}`.
"""

from __future__ import annotations

import argparse
import bisect
import errno
import fcntl
import glob
import json
import math
import os
import pty
import signal
import socket
import struct
import sys
import termios
import time
import tty

IDS = (0x310, 0x311, 0x312, 0x313)
CAN_FRAME = struct.Struct("=IB3x8s")
LINK_DOWN = (errno.ENETDOWN, errno.ENXIO, errno.ENODEV)
PROGRESS_EVERY_S = 0.25
DRAIN_S = 60.0
"""At the end, how long to wait for the reader to read what was written to the pseudo-terminal."""
SLEEP_MIN_S = 0.0005
"""Sleep only when the next event is more than this far ahead."""


def payload(count: int, n: int) -> bytes:
    return struct.pack("<I3xB", count & 0xFFFFFFFF, n & 0xFF)


class Drive:
    """A wheel's pulse count as a function of drive time: linear between the table's samples, held at its ends."""

    def __init__(self, path: str) -> None:
        with open(path) as f:
            d = json.load(f)
        self.start_count = int(d["start_count"])
        self.times_s = [float(t) for t in d["times_s"]]
        self.pulses = [[float(p) for p in wheel] for wheel in d["pulses"]]
        assert len(self.pulses) == len(IDS) and all(len(p) == len(self.times_s) for p in self.pulses)

    @staticmethod
    def save(path: str | os.PathLike[str], start_count: int, times_s: list[float], pulses: list[list[float]]) -> None:
        """The --drive file: pulses since the start per wheel (IDS order) at times_s (increasing)."""
        with open(path, "w") as f:
            json.dump({"start_count": start_count, "times_s": times_s, "pulses": pulses}, f)

    def count(self, wheel: int, drive_s: float) -> int:
        ts, ps = self.times_s, self.pulses[wheel]
        j = bisect.bisect_right(ts, drive_s)
        if j == 0:
            p = ps[0]
        elif j == len(ts):
            p = ps[-1]
        else:
            t0, t1 = ts[j - 1], ts[j]
            p = ps[j - 1] + (ps[j] - ps[j - 1]) * (drive_s - t0) / (t1 - t0)
        return (self.start_count + math.floor(p)) % 2**32


class PtyWriter:
    """A pseudo-terminal standing in for the GPS receiver's serial port (as slipdaq.live.simulate.PtyGps)."""

    def __init__(self, link: str) -> None:
        self.master_fd, self.slave_fd = pty.openpty()
        tty.setraw(self.slave_fd)
        os.set_blocking(self.master_fd, False)
        self.path = os.ttyname(self.slave_fd)
        self.link = link
        if os.path.lexists(link):
            os.unlink(link)
        os.symlink(self.path, link)
        self.dropped = 0

    def opened_by(self, pid: int) -> bool:
        """Whether process pid has the pty's slave open."""
        fd_dir = f"/proc/{pid}/fd"
        for fd in os.listdir(fd_dir):
            try:
                if os.readlink(os.path.join(fd_dir, fd)) == self.path:
                    return True
            except FileNotFoundError:
                continue
        return False

    def write(self, data: bytes) -> bool:
        """Write a line; when nobody reads and the buffer is full, the line is dropped (as a UART would)."""
        try:
            os.write(self.master_fd, data)
            return True
        except BlockingIOError:
            self.dropped += 1
            return False

    def drain(self, timeout_s: float) -> int:
        """Wait until the reader has read every byte written (closing the master would discard them): the slave's
        input queue is empty twice, 0.1 s apart (the kernel moves written bytes there asynchronously). Returns the
        bytes left after timeout_s."""
        deadline = time.monotonic() + timeout_s
        empty = 0
        while True:
            time.sleep(0.1)
            left = struct.unpack("i", fcntl.ioctl(self.slave_fd, termios.FIONREAD, b"\0" * 4))[0]
            empty = empty + 1 if left == 0 else 0
            if empty == 2 or time.monotonic() > deadline:
                return left

    def close(self) -> None:
        if os.path.lexists(self.link):
            os.unlink(self.link)
        os.close(self.master_fd)
        os.close(self.slave_fd)


def write_nmea(path: str | os.PathLike[str], lines: list[tuple[float, str]]) -> None:
    """The --nmea file: `T SENTENCE` per line."""
    with open(path, "w") as f:
        f.writelines(f"{t:.6f} {sentence}\n" for t, sentence in lines)


def read_nmea(path: str | os.PathLike[str]) -> list[tuple[float, str]]:
    """The --nmea file's (T, sentence) pairs."""
    out = []
    with open(path) as f:
        for line in f:
            t, sentence = line.rstrip("\n").split(" ", 1)
            out.append((float(t), sentence))
    return out


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--channel", default="vcan0")
    ap.add_argument("--rate-hz", type=float, default=100.0, help="frames per second per wheel")
    ap.add_argument("--duration", type=float, default=10.0, help="seconds of schedule")
    ap.add_argument("--then-burst", type=int, default=0, help="after the schedule, this many frames more")
    ap.add_argument("--burst-rate-hz", type=float, default=0.0, help="their rate per wheel (0: back to back)")
    ap.add_argument("--drive", help="PulseCount from this drive table at the moment of sending (default: n)")
    ap.add_argument("--record", help="write every sent frame's id, index and send-time bounds to this file")
    ap.add_argument("--nmea", help="NMEA lines `T SENTENCE` to write to a pseudo-terminal (needs --gps-link)")
    ap.add_argument("--gps-link", help="the pseudo-terminal's symlink")
    ap.add_argument("--nmea-record", help="write every written line's index and write-time bounds to this file")
    ap.add_argument("--mti", help="MTi messages `T HEX` to write to a second pseudo-terminal (needs --mti-link)")
    ap.add_argument("--mti-link", help="that pseudo-terminal's symlink")
    ap.add_argument("--start-at", type=float, help="wall-clock time (time.time()) of slot 0 (default: now)")
    ap.add_argument("--go", help="glob: start once a file matches it (e.g. the daemon's log)")
    ap.add_argument("--gps-reader-pid", type=int, help="and once this process has the pseudo-terminal open")
    ap.add_argument("--delay", type=float, default=0.0, help="seconds to wait after that")
    a = ap.parse_args(argv)
    if a.nmea and not a.gps_link:
        ap.error("--nmea needs --gps-link")
    if a.mti and not a.mti_link:
        ap.error("--mti needs --mti-link")
    drive = Drive(a.drive) if a.drive else None
    nmea = [(t, line.encode("ascii") + b"\r\n") for t, line in read_nmea(a.nmea)] if a.nmea else []
    gps = PtyWriter(a.gps_link) if a.gps_link else None
    if gps is not None:
        print(f"sender: gps {gps.path} linked at {a.gps_link}", flush=True)
    mti = [(t, bytes.fromhex(h)) for t, h in read_nmea(a.mti)] if a.mti else []
    imu = PtyWriter(a.mti_link) if a.mti_link else None
    if imu is not None:
        print(f"sender: mti {imu.path} linked at {a.mti_link}", flush=True)
    if a.go:
        while not glob.glob(a.go):
            time.sleep(0.05)
    if a.gps_reader_pid is not None:
        while not all(w.opened_by(a.gps_reader_pid) for w in (gps, imu) if w is not None):
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
    nmea_record = open(a.nmea_record, "w") if a.nmea_record else None
    sent = failed = retries = nmea_written = mti_written = 0
    first_error: str | None = None
    fail_first: float | None = None
    fail_last: float | None = None
    if a.start_at is not None:
        time.sleep(max(0.0, a.start_at - time.time()))
    phases = [(int(a.duration * a.rate_hz * len(IDS)), 1.0 / (a.rate_hz * len(IDS)) if a.rate_hz > 0 else 0.0)]
    if a.then_burst > 0:
        phases.append((a.then_burst, 1.0 / (a.burst_rate_hz * len(IDS)) if a.burst_rate_hz > 0 else 0.0))
    zero = a.start_at if a.start_at is not None else time.time()  # drive time 0 and the NMEA lines' time 0
    start = zero
    t_first = time.time()
    lines: list[str] = []
    nmea_lines: list[str] = []
    next_nmea = next_mti = 0
    next_progress = t_first

    def progress(now: float) -> None:
        nonlocal next_progress
        if now >= next_progress:
            print(f"sender: at {now:.6f} sent {sent} failed {failed} nmea {nmea_written}", flush=True)
            next_progress = now + PROGRESS_EVERY_S

    def write_due_nmea(now: float) -> None:
        """Every NMEA line and MTi message due by now, one write each."""
        nonlocal next_nmea, nmea_written, next_mti, mti_written
        while gps is not None and next_nmea < len(nmea) and zero + nmea[next_nmea][0] <= now:
            w0 = time.time()
            if gps.write(nmea[next_nmea][1]):
                nmea_written += 1
                nmea_lines.append(f"{next_nmea},{w0:.9f},{time.time():.9f}\n")
            next_nmea += 1
            now = time.time()
        while imu is not None and next_mti < len(mti) and zero + mti[next_mti][0] <= now:
            mti_written += imu.write(mti[next_mti][1])
            next_mti += 1
            now = time.time()

    def next_serial_due() -> float:
        return min(zero + nmea[next_nmea][0] if next_nmea < len(nmea) else math.inf,
                   zero + mti[next_mti][0] if next_mti < len(mti) else math.inf)

    def wait_until(due: float) -> None:
        """Sleep until due, writing the NMEA lines that fall due meanwhile."""
        while not stop:
            now = time.time()
            write_due_nmea(now)
            progress(now)
            ahead = min(due, next_serial_due()) - time.time()
            if due - time.time() <= SLEEP_MIN_S:
                return
            if ahead > SLEEP_MIN_S:
                time.sleep(min(ahead, PROGRESS_EVERY_S))

    k = 0
    phase_times: list[tuple[float, float, int]] = []
    for slots, period_s in phases:
        phase_start, phase_sent = time.time(), sent
        if k > 0:
            start = phase_start - k * period_s  # this phase's schedule starts now
        for _ in range(slots):
            if stop:
                break
            wait_until(start + k * period_s if period_s else -math.inf)
            wheel, n = k % 4, k // 4
            can_id = IDS[wheel]
            k += 1
            while True:
                t0 = time.time()
                count = drive.count(wheel, t0 - zero) if drive is not None else n
                try:
                    sock.send(CAN_FRAME.pack(can_id, 8, payload(count, n)))
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
                    lines.append(f"{can_id},{n},{t0:.9f},{t1:.9f}" + (f",{count}\n" if drive is not None else "\n"))
                    if len(lines) >= 1000:
                        record.writelines(lines)
                        lines.clear()
                break
        phase_times.append((phase_start, time.time(), sent - phase_sent))
    while next_serial_due() < math.inf and not stop:  # the NMEA lines and MTi messages due after the last frame
        wait_until(next_serial_due())
    t_last = time.time()
    next_progress = -math.inf
    progress(t_last)
    if record is not None:
        record.writelines(lines)
        record.close()
    if nmea_record is not None:
        nmea_record.writelines(nmea_lines)
        nmea_record.close()
    unread = mti_unread = 0
    if gps is not None:
        unread = gps.drain(DRAIN_S)
        gps.close()
    if imu is not None:
        mti_unread = imu.drain(DRAIN_S)
        imu.close()
    elapsed = t_last - t_first
    print(json.dumps({
        "sent": sent, "failed": failed, "retries": retries, "slots": k, "elapsed_s": elapsed,
        "rate_fps": sent / elapsed if elapsed > 0 else 0.0, "first_error": first_error,
        "fail_first_s": fail_first, "fail_last_s": fail_last, "start_s": t_first, "end_s": t_last, "zero_s": zero,
        "nmea_written": nmea_written, "nmea_dropped": gps.dropped if gps is not None else 0, "nmea_unread": unread,
        "mti_written": mti_written, "mti_dropped": imu.dropped if imu is not None else 0, "mti_unread": mti_unread,
        "phases": [{"start_s": a0, "end_s": a1, "sent": n, "rate_fps": n / (a1 - a0) if a1 > a0 else 0.0}
                   for a0, a1, n in phase_times],
    }), flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
