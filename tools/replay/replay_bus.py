#!/usr/bin/env python3
"""Play a slipdaq log's raw CAN frames onto a python-can bus and its NMEA onto a serial port or pseudo-terminal.

The gpsfake idea for both streams: the recorded traffic, with its original timing (or N times faster), goes back
out through real interfaces so that `slipdaq run` can be tested hardware-in-the-loop.

    python tools/replay/replay_bus.py LOG.mcap --interface socketcan --channel vcan0 --gps-port /dev/ttyUSB1
    python tools/replay/replay_bus.py LOG.mcap --interface socketcan --channel vcan0 --gps-link /tmp/gps --speed 4
"""

from __future__ import annotations

import argparse
import asyncio
import itertools
import signal
import sys
from collections.abc import Iterator
from pathlib import Path

import can

from slipdaq.sim.emit import SimEvent
from slipdaq.sim.realtime import play
from slipdaq.simulate import PtyGps, serial_writer
from slipdaq.sources.mcap_log import iter_raw_records


def timed_events(log: Path, speed: float) -> Iterator[SimEvent]:
    """The log's raw records as events at (t - t_first) / speed seconds after the start."""
    t_first: float | None = None
    for record in iter_raw_records(log):
        if t_first is None:
            t_first = record.timestamp_s
        yield SimEvent(max(record.timestamp_s - t_first, 0.0) / speed, record, None)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("log", type=Path, help="a slipdaq MCAP log (live, import or replay)")
    ap.add_argument("--interface", default="socketcan", help="python-can interface (default socketcan)")
    ap.add_argument("--channel", default="vcan0", help="python-can channel (default vcan0)")
    ap.add_argument("--gps-port", help="serial device to write the NMEA to (default: a new pseudo-terminal)")
    ap.add_argument("--gps-link", help="with a pseudo-terminal: make this path a symlink to it")
    ap.add_argument("--baudrate", type=int, default=115200)
    ap.add_argument("--speed", type=float, default=1.0, help="N times faster than recorded (default 1: real time)")
    a = ap.parse_args(argv)
    if a.speed <= 0:
        ap.error("--speed must be > 0")
    if a.gps_port:
        write, close = serial_writer(a.gps_port, a.baudrate)
        where = a.gps_port
    else:
        gps = PtyGps(a.gps_link)
        write, close, where = gps.write, gps.close, gps.path
    print(f"replay_bus: {a.log} -> CAN {a.interface}:{a.channel}, NMEA {where}, {a.speed:g}x", flush=True)

    async def run(bus: can.BusABC) -> int:
        task = asyncio.current_task()
        assert task is not None
        for sig in (signal.SIGINT, signal.SIGTERM):
            asyncio.get_running_loop().add_signal_handler(sig, task.cancel)
        events = timed_events(a.log, a.speed)
        first = next(events, None)  # opened and its first chunk read before play() starts the clock: no late burst
        try:
            return await play(itertools.chain([first] if first else [], events), bus=bus, nmea_write=write)
        except asyncio.CancelledError:
            return -1

    try:
        with can.Bus(interface=a.interface, channel=a.channel) as bus:
            sent = asyncio.run(run(bus))
    finally:
        close()
    print(f"replay_bus: sent {sent} CAN frames" if sent >= 0 else "replay_bus: stopped", flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
