"""`slipdaq simulate`: the vehicle model's WPT frames onto a python-can bus and its NMEA onto a serial port; the IMU,
brake switch and reference speed on CAN too when the config names them ([imu], [brake], [gps] message/signal), the
IMU as an Xsens MTi's MTData2 messages on a second serial port with [imu] source = "serial"."""

from __future__ import annotations

import argparse
import asyncio
import contextlib
import fcntl
import os
import pty
import signal
import struct
import sys
import termios
import time
import tty
from collections.abc import Callable
from dataclasses import dataclass, replace
from pathlib import Path

import serial

from slipdaq.config import Config
from slipdaq.live.daemon import open_bus
from slipdaq.sim.emit import SimSettings, generate
from slipdaq.sim.realtime import play

IMU_RATE_HZ, BRAKE_RATE_HZ = 100.0, 50.0
"""Frame rates of the simulated IMU and brake switch (sent only when the config names their signals)."""


@dataclass(frozen=True)
class SimOptions:
    scenario: str = "cycle"
    road: str = "paved"
    gps_port: str | None = None
    gps_link: str | None = None
    duration_s: float | None = None
    settings: SimSettings = SimSettings()
    imu_port: str | None = None
    """[imu] source = "serial": the serial device to write the MTi's messages to (None: a new pseudo-terminal)."""
    imu_link: str | None = None

    @classmethod
    def from_args(cls, a: argparse.Namespace) -> SimOptions:
        return cls(a.scenario, a.road, a.gps_port, a.gps_link, a.duration, SimSettings(
            wpt_rate_hz=a.wpt_rate_hz, gps_rate_hz=a.gps_rate_hz, gps_latency_s=a.gps_latency_s,
            gps_noise_mps=a.gps_noise_mps, seed=a.seed, imu_rate_hz=IMU_RATE_HZ, brake_rate_hz=BRAKE_RATE_HZ,
            ref_speed_rate_hz=a.gps_rate_hz, ref_speed_latency_s=a.gps_latency_s, ref_speed_noise_mps=a.gps_noise_mps,
        ), a.imu_port, a.imu_link)


class PtyGps:
    """A pseudo-terminal standing in for a GPS receiver's (or an MTi's) serial port: write to it, read its `path`."""

    def __init__(self, link: str | None = None) -> None:
        self.master_fd, self.slave_fd = pty.openpty()
        tty.setraw(self.slave_fd)
        os.set_blocking(self.master_fd, False)
        self.path = os.ttyname(self.slave_fd)
        self.link = Path(link) if link else None
        self.dropped_lines = 0
        if self.link is not None:
            with contextlib.suppress(FileNotFoundError):
                self.link.unlink()
            self.link.symlink_to(self.path)

    def write(self, data: bytes) -> None:
        """Write a line; when nobody reads and the buffer is full, the line is dropped (as a UART would)."""
        try:
            os.write(self.master_fd, data)
        except BlockingIOError:
            self.dropped_lines += 1

    def unread_bytes(self) -> int:
        """Bytes written that the reader has not read yet (the slave's input queue)."""
        return int(struct.unpack("i", fcntl.ioctl(self.slave_fd, termios.FIONREAD, b"\0" * 4))[0])

    def close(self) -> None:
        if self.link is not None:
            with contextlib.suppress(FileNotFoundError):
                self.link.unlink()
        os.close(self.master_fd)
        os.close(self.slave_fd)


def serial_writer(port: str, baudrate: int) -> tuple[Callable[[bytes], object], Callable[[], None]]:
    s = serial.Serial(port, baudrate, write_timeout=0)

    def write(data: bytes) -> None:
        with contextlib.suppress(serial.SerialTimeoutException):
            s.write(data)

    return write, s.close


def _port(port: str | None, link: str | None, baudrate: int) -> tuple[Callable[[bytes], object], Callable[[], None], str]:
    """A writer to the serial device `port`, else to a new pseudo-terminal (linked at `link`): write, close, where."""
    if port:
        write, close = serial_writer(port, baudrate)
        return write, close, port
    pty_port = PtyGps(link)
    return pty_port.write, pty_port.close, pty_port.path + (f" (linked at {link})" if link else "")


def run_simulate(cfg: Config, opts: SimOptions, out=sys.stdout) -> int:
    with contextlib.ExitStack() as ports:
        write, close, where = _port(opts.gps_port, opts.gps_link, cfg.gps.baudrate)
        ports.callback(close)
        imu_write: Callable[[bytes], object] | None = None
        if cfg.imu.source == "serial":
            imu_write, imu_close, imu_where = _port(opts.imu_port, opts.imu_link, cfg.imu.baudrate)
            ports.callback(imu_close)
            where += f", MTi (Xbus MTData2, {IMU_RATE_HZ:.0f} Hz) on {imu_where}"
        print(f"simulate: {opts.scenario} on {opts.road}; WPT frames on {cfg.can.interface}:{cfg.can.channel}, "
              f"NMEA on {where}", file=out, flush=True)
        refused = Refused(out)
        with open_bus(cfg) as bus:
            # the drive's UTC starts now, after the bus is open: the NMEA's UTC is its send time (GPS latency 0)
            settings = replace(opts.settings, start_utc_s=time.time())
            frames = asyncio.run(_play(cfg, opts, settings, bus, write, refused, imu_write))
    print(f"simulate: sent {frames} CAN frames" + (f", {refused.count} refused by the bus" if refused.count else ""),
          file=out, flush=True)
    return 0


class Refused:
    """Counts the frames the bus refused (its link down); the first refusal is printed."""

    def __init__(self, out) -> None:
        self.out = out
        self.count = 0

    def __call__(self, e: Exception) -> None:
        self.count += 1
        if self.count == 1:
            print(f"simulate: the bus refused a frame ({e}); going on, refused frames are counted",
                  file=self.out, flush=True)


async def _play(cfg: Config, opts: SimOptions, settings: SimSettings, bus, write, on_refused, imu_write=None) -> int:
    loop = asyncio.get_running_loop()
    task = asyncio.current_task()
    assert task is not None
    for sig in (signal.SIGINT, signal.SIGTERM):
        loop.add_signal_handler(sig, task.cancel)
    events = generate(cfg, opts.scenario, opts.road, settings, duration_s=opts.duration_s)  # type: ignore[arg-type]  # argparse's choices= admits only the Literal's values
    sent = 0
    try:
        sent = await play(events, bus=bus, nmea_write=write, duration_s=opts.duration_s,
                          start_wall_s=settings.start_utc_s, on_refused=on_refused, imu_write=imu_write)
    except asyncio.CancelledError:
        pass
    return sent
