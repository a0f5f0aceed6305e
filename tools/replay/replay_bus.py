#!/usr/bin/env python3
"""Play a slipdaq log's raw CAN frames onto a python-can bus and its NMEA onto a serial port or pseudo-terminal.

The gpsfake idea for both streams: the recorded traffic, with its original timing (or N times faster), goes back
out through real interfaces so that `slipdaq run` can be tested hardware-in-the-loop. Each frame is sent as it was
logged: remote, CAN FD, bit rate switch, error state indicator, error frame, DLC and its logged channel name (a bus
on one channel sends it there; python-can's multi-channel interfaces pick the channel by it).

    python tools/replay/replay_bus.py LOG.mcap --interface socketcan --channel vcan0 --gps-port /dev/ttyUSB1
    python tools/replay/replay_bus.py LOG.mcap --interface socketcan --channel vcan0 --gps-link /tmp/gps --speed 4
    python tools/replay/replay_bus.py LOG.mcap --interface socketcan --channel 0=vcan0 --channel 1=vcan1 --fd
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

from slipdaq.live.simulate import PtyGps, serial_writer
from slipdaq.logformat.reader import iter_raw_records
from slipdaq.sim.emit import SimEvent
from slipdaq.sim.realtime import play


def timed_events(log: Path, speed: float) -> Iterator[SimEvent]:
    """The log's raw records as events at (t - t_first) / speed seconds after the start."""
    t_first: float | None = None
    for record in iter_raw_records(log):
        if t_first is None:
            t_first = record.timestamp_s
        yield SimEvent(max(record.timestamp_s - t_first, 0.0) / speed, record, None)


class ChannelRouter:
    """Sends each message on the bus of its logged channel (`--channel LOGGED=CH`), else on the default bus (a
    plain `--channel CH`); a message of a channel with neither is not sent, and counted."""

    def __init__(self, buses: dict[str | None, can.BusABC], default: can.BusABC | None) -> None:
        self.buses = buses
        self.default = default
        self.unrouted: dict[str | None, int] = {}

    def send(self, msg: can.Message, timeout: float | None = None) -> None:
        bus = self.buses.get(msg.channel, self.default)
        if bus is None:
            self.unrouted[msg.channel] = self.unrouted.get(msg.channel, 0) + 1
            return
        bus.send(msg, timeout)


def parse_channels(values: list[str]) -> tuple[str | None, dict[str, str]]:
    """--channel values: (the default bus channel or None, {logged channel name: bus channel})."""
    default: str | None = None
    mapped: dict[str, str] = {}
    for v in values:
        logged, sep, channel = v.partition("=")
        if sep:
            mapped[logged] = channel
        else:
            default = v
    return default, mapped


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("log", type=Path, help="a slipdaq MCAP log (live, import or replay)")
    ap.add_argument("--interface", default="socketcan", help="python-can interface (default socketcan)")
    ap.add_argument("--channel", action="append", metavar="[LOGGED=]CH",
                    help="python-can channel for every frame (default vcan0); LOGGED=CH: the frames logged on channel "
                         "LOGGED (a name in the log's can_channels) go to a bus on CH (repeatable)")
    ap.add_argument("--fd", action="store_true", help="open the buses for CAN FD frames")
    ap.add_argument("--gps-port", help="serial device to write the NMEA to (default: a new pseudo-terminal)")
    ap.add_argument("--gps-link", help="with a pseudo-terminal: make this path a symlink to it")
    ap.add_argument("--baudrate", type=int, default=115200)
    ap.add_argument("--speed", type=float, default=1.0, help="N times faster than recorded (default 1: real time)")
    a = ap.parse_args(argv)
    if a.speed <= 0:
        ap.error("--speed must be > 0")
    default, mapped = parse_channels(a.channel or ["vcan0"])
    if a.gps_port:
        write, close = serial_writer(a.gps_port, a.baudrate)
        where = a.gps_port
    else:
        gps = PtyGps(a.gps_link)
        write, close, where = gps.write, gps.close, gps.path
    targets = ([default] if default is not None else []) + [f"{k}={v}" for k, v in mapped.items()]
    print(f"replay_bus: {a.log} -> CAN {a.interface}:{','.join(targets)}, NMEA {where}, {a.speed:g}x", flush=True)

    async def run(bus: ChannelRouter) -> int:
        task = asyncio.current_task()
        assert task is not None
        for sig in (signal.SIGINT, signal.SIGTERM):
            asyncio.get_running_loop().add_signal_handler(sig, task.cancel)
        events = timed_events(a.log, a.speed)
        first = next(events, None)  # opened and its first chunk read before play() starts the clock: no late burst
        try:
            return await play(itertools.chain([first] if first else [], events), bus=bus,  # type: ignore[arg-type]
                              nmea_write=write)
        except asyncio.CancelledError:
            return -1

    kwargs = {"fd": True} if a.fd else {}
    buses: dict[str, can.BusABC] = {}
    try:
        for channel in dict.fromkeys(([default] if default is not None else []) + list(mapped.values())):
            buses[channel] = can.Bus(interface=a.interface, channel=channel, **kwargs)
        router = ChannelRouter({k: buses[v] for k, v in mapped.items()},
                               buses[default] if default is not None else None)
        sent = asyncio.run(run(router))
    finally:
        for bus in buses.values():
            bus.shutdown()
        close()
    unrouted = sum(router.unrouted.values())
    if sent >= 0:
        sent -= unrouted
    print(f"replay_bus: sent {sent} CAN frames" if sent >= 0 else "replay_bus: stopped", flush=True)
    if unrouted:
        print(f"replay_bus: {unrouted} frames of channels with no --channel not sent: "
              f"{', '.join(f'{k}: {n}' for k, n in router.unrouted.items())}", flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
