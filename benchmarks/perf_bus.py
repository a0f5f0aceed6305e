"""Cross-process live rig for benchmarks/perf.py: a SocketCAN-like python-can bus over loopback UDP, a paced sender
process and the `slipdaq run` child. Nothing here is imported by src/.

Why: python-can's virtual bus only works inside one process, so the sender's CPU would count as the daemon's, and
there is no vcan on this machine (no kernel module). This bus carries one CAN frame per UDP datagram on 127.0.0.1
(nothing leaves the host), as SocketCAN's `struct can_frame` (16 bytes: can_id with the EFF/ERR flag bits, len, data),
and the socket has SO_TIMESTAMPNS, so the kernel stamps each datagram on arrival as SocketCAN stamps a frame. The bus
exposes the socket's fileno() and a `socket` attribute and declares `raw_socketcan_frames`, so slipdaq's CanBusSource
reads it exactly as it reads python-can's SocketCAN bus: from the asyncio loop (loop.add_reader, paced by
can.read_interval_s), one recvmsg per frame straight from the socket (slipdaq.sources.socketcan_raw), and
daemon.open_bus asks it for the large SO_RCVBUF as on a car.

    python -m benchmarks.perf_bus daemon --config CFG --duration S --log-dir D [--probe OUT.json]
        registers the interface name `slipdaq_bench_udp`, then runs `slipdaq run` through the command's own entry
        (slipdaq.__main__.main: python-can without asammdf, the allocator's thresholds, the imports frozen out of the
        garbage collector's reach, OpenBLAS on one thread), so that the process is the one `slipdaq run` makes; with
        --probe it also records time.time() after each estimate is handed to the MCAP writer (20 calls/s:
        negligible).
    python -m benchmarks.perf_bus sender --port P --nmea-fd FD --wpt-rate-hz R --gps-rate-hz G --duration S
        generates the simulated drive (sim time 0 = --start-wall), waits for that time, then sends the CAN frames to
        127.0.0.1:P and writes the NMEA lines to the pseudo-terminal's master FD at their times; prints its counts.
"""

from __future__ import annotations

import argparse
import json
import os
import select
import socket
import struct
import sys
import time
from pathlib import Path

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")  # as slipdaq.__main__ sets it, before numpy is imported here
from slipdaq.__main__ import import_python_can  # noqa: E402

import_python_can(with_mf4=False)  # python-can as `slipdaq run` has it (slipdaq.__main__)
import can  # noqa: E402

INTERFACE = "slipdaq_bench_udp"
FRAME = struct.Struct("=IB3x8s")
"""SocketCAN's struct can_frame: can_id (| CAN_EFF_FLAG 0x80000000, | CAN_ERR_FLAG 0x20000000), len, pad, data[8]."""
SO_TIMESTAMPNS = getattr(socket, "SO_TIMESTAMPNS", 35)
TIMESPEC = struct.Struct("@ll")


def parse_channel(channel: str) -> tuple[str, int]:
    host, _, port = str(channel).rpartition(":")
    if host not in ("127.0.0.1", "localhost"):
        raise ValueError(f"{INTERFACE}: channel must be 127.0.0.1:PORT (loopback only), got {channel!r}")
    return "127.0.0.1", int(port)


class LoopbackUdpBus(can.BusABC):
    """Receive-only python-can bus: one SocketCAN frame per datagram on 127.0.0.1:PORT (channel "127.0.0.1:PORT"),
    stamped by the kernel on arrival (SO_TIMESTAMPNS)."""

    raw_socketcan_frames = os.environ.get("SLIPDAQ_BENCH_PYTHON_CAN_RECV") != "1"
    """slipdaq reads the socket directly, as python-can's SocketCAN bus; with SLIPDAQ_BENCH_PYTHON_CAN_RECV=1 through
    python-can's recv() (a can.Message per frame), for comparison."""

    def __init__(self, channel: str, can_filters=None, **kwargs: object) -> None:
        self._addr = parse_channel(channel)
        self.socket = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        self.socket.bind(self._addr)
        self.socket.setsockopt(socket.SOL_SOCKET, SO_TIMESTAMPNS, 1)
        self.socket.setblocking(False)
        self.channel_info = f"loopback udp {channel}"
        self._channel = str(channel)
        super().__init__(channel=channel, can_filters=can_filters, **kwargs)

    def _recv_internal(self, timeout: float | None) -> tuple[can.Message | None, bool]:
        try:
            data, anc, _, _ = self.socket.recvmsg(64, socket.CMSG_SPACE(TIMESPEC.size))
        except BlockingIOError:
            if timeout == 0:
                return None, False
            ready, _, _ = select.select([self.socket], [], [], timeout)
            if not ready:
                return None, False
            data, anc, _, _ = self.socket.recvmsg(64, socket.CMSG_SPACE(TIMESPEC.size))
        sec, ns = TIMESPEC.unpack_from(anc[0][2])
        can_id, dlc, payload = FRAME.unpack(data)
        ext = bool(can_id & 0x80000000)
        msg = can.Message(timestamp=sec + ns * 1e-9, arbitration_id=can_id & (0x1FFFFFFF if ext else 0x7FF),
                          is_extended_id=ext, is_error_frame=bool(can_id & 0x20000000), dlc=dlc,
                          data=payload[:dlc], channel=self._channel)
        return msg, False

    def send(self, msg: can.Message, timeout: float | None = None) -> None:
        raise can.CanOperationError(f"{INTERFACE} is receive-only")

    def fileno(self) -> int:
        return self.socket.fileno()

    def shutdown(self) -> None:
        super().shutdown()
        self.socket.close()


def register() -> None:
    """Make `interface = "slipdaq_bench_udp"` known to can.Bus (python-can looks interfaces up in BACKENDS)."""
    import can.interfaces
    import can.util

    can.interfaces.BACKENDS[INTERFACE] = ("benchmarks.perf_bus", "LoopbackUdpBus")
    valid = frozenset(can.interfaces.BACKENDS)
    can.interfaces.VALID_INTERFACES = valid
    can.util.VALID_INTERFACES = valid  # load_config checks this copy


# ---- the daemon child -------------------------------------------------------------------------------------------
def daemon_main(args: argparse.Namespace) -> int:
    register()
    probe: list[list[float]] = []
    if args.probe:
        from slipdaq.sinks.mcap_log import McapLogSink

        original = McapLogSink.on_estimate

        def on_estimate(self, estimate, log_time_s):  # type: ignore[no-untyped-def]
            original(self, estimate, log_time_s)
            probe.append([time.time(), estimate.time_s])

        McapLogSink.on_estimate = on_estimate  # type: ignore[method-assign]
    from slipdaq.__main__ import main

    argv = ["run", "--config", args.config, "--log-dir", args.log_dir]
    if args.duration:
        argv += ["--duration", str(args.duration)]
    sys.argv = ["slipdaq", *argv]
    try:
        return main()
    finally:
        if args.probe:
            Path(args.probe).write_text(json.dumps(probe))


# ---- the sender -------------------------------------------------------------------------------------------------
def build_schedule(wpt_rate_hz: float, gps_rate_hz: float, duration_s: float, gps_latency_s: float,
                   start_utc_s: float) -> tuple[list[float], list[object]]:
    """(times since start, payloads): (SocketCAN can_id with flags, dlc, data8) for CAN, bytes for an NMEA line."""
    from dataclasses import replace

    from slipdaq.config import load_config, packaged_config_path
    from slipdaq.records import CanFrame, NmeaLine
    from slipdaq.sim.emit import SimSettings, generate

    cfg = load_config(packaged_config_path())
    settings = replace(SimSettings(), wpt_rate_hz=wpt_rate_hz, gps_rate_hz=gps_rate_hz, gps_latency_s=gps_latency_s,
                       start_utc_s=start_utc_s)
    times: list[float] = []
    payloads: list[object] = []
    for ev in generate(cfg, "cycle", "paved", settings, duration_s=duration_s):  # type: ignore[arg-type]
        r = ev.record
        if isinstance(r, CanFrame):
            times.append(ev.time_s)
            can_id = r.arbitration_id | (0x80000000 if r.is_extended_id else 0) | (0x20000000 if r.is_error_frame else 0)
            payloads.append((can_id, len(r.data), bytes(r.data).ljust(8, b"\0")))
        elif isinstance(r, NmeaLine):
            times.append(ev.time_s)
            payloads.append((r.line + "\r\n").encode("ascii"))
    return times, payloads


def sender_main(args: argparse.Namespace) -> int:
    # sim time 0 = --start-wall (the parent rounds it to 10 ms, so the NMEA UTC fields, in hundredths, are exact)
    start = args.start_wall
    times, payloads = build_schedule(args.wpt_rate_hz, args.gps_rate_hz, args.duration, args.gps_latency_s, start)
    sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    addr = ("127.0.0.1", args.port)
    nmea_fd = args.nmea_fd
    ready_margin_s = start - time.time()  # < 0: generating took longer than the lead; the run is late by that much
    if ready_margin_s < 0:
        start = time.time() + 0.5
    print(f"start {start!r}", flush=True)  # the parent times its CPU samples from this
    pack = FRAME.pack
    now = time.time
    sleep = time.sleep
    n = len(times)
    i = 0
    frames = lines = 0
    max_late_s = 0.0
    late_over_1ms = 0
    while i < n:
        t_due = start + times[i]
        t = now()
        if t_due > t + 0.0003:
            sleep(min(t_due - t, 0.002) - 0.0001)
            continue
        late = t - t_due
        if late > max_late_s:
            max_late_s = late
        if late > 0.001:
            late_over_1ms += 1
        p = payloads[i]
        if isinstance(p, tuple):
            can_id, dlc, data = p
            sock.sendto(pack(can_id, dlc, data), addr)
            frames += 1
        else:
            data = p
            while data:
                try:
                    k = os.write(nmea_fd, data)
                    data = data[k:]
                except BlockingIOError:
                    sleep(0.0005)
            lines += 1
        i += 1
    print(json.dumps({"frames": frames, "nmea_lines": lines, "max_late_s": max_late_s,
                      "late_over_1ms": late_over_1ms, "ready_margin_s": ready_margin_s,
                      "start_wall": start}), flush=True)
    return 0


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    sub = ap.add_subparsers(dest="cmd", required=True)
    d = sub.add_parser("daemon")
    d.add_argument("--config", required=True)
    d.add_argument("--log-dir", required=True)
    d.add_argument("--duration", type=float)
    d.add_argument("--probe")
    s = sub.add_parser("sender")
    s.add_argument("--port", type=int, required=True)
    s.add_argument("--nmea-fd", type=int, required=True)
    s.add_argument("--wpt-rate-hz", type=float, required=True)
    s.add_argument("--gps-rate-hz", type=float, default=20.0)
    s.add_argument("--gps-latency-s", type=float, default=0.0)
    s.add_argument("--duration", type=float, required=True)
    s.add_argument("--start-wall", type=float, required=True, help="time.time() of sim time 0")
    args = ap.parse_args()
    return {"daemon": daemon_main, "sender": sender_main}[args.cmd](args)


if __name__ == "__main__":
    sys.exit(main())
