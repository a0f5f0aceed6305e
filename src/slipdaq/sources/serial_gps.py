"""GPS source: NMEA lines from a serial port (pyserial), read from the asyncio loop without blocking.

The port is opened non-blocking and read when the loop says it is readable; each chunk of bytes is framed
into lines stamped with the host receive time. If the device goes away it is reopened with backoff.
"""

from __future__ import annotations

import asyncio
import logging
import time
from collections.abc import Callable

import serial

from slipdaq.decode.nmea import NmeaFramer
from slipdaq.records import NmeaLine

log = logging.getLogger(__name__)


class SerialGpsSource:
    def __init__(self, port: str, baudrate: int, clock: Callable[[], float] = time.time) -> None:
        self.port = port
        self.baudrate = baudrate
        self.clock = clock
        self.framer = NmeaFramer()
        self.connected = False
        self.bytes_read = 0
        self.reconnects = 0
        self.last_error: str | None = None

    def _open(self) -> serial.Serial:
        return serial.Serial(self.port, self.baudrate, timeout=0, exclusive=True)

    async def run(self, emit: Callable[[NmeaLine], None]) -> None:
        """Read until cancelled; reopen the port with backoff (0.1 s doubling to 1 s) when it fails."""
        backoff_s = 0.1
        while True:
            try:
                port = self._open()
            except (serial.SerialException, OSError) as e:
                self._lost(e)
                await asyncio.sleep(backoff_s)
                backoff_s = min(backoff_s * 2, 1.0)
                continue
            backoff_s = 0.1
            try:
                await self._read(port, emit)
            except (serial.SerialException, OSError) as e:
                self._lost(e)
            finally:
                port.close()
            self.reconnects += 1
            await asyncio.sleep(0.1)

    def _lost(self, e: Exception) -> None:
        if self.connected or self.last_error is None:
            log.warning("GPS port %s: %s", self.port, e)
        self.connected = False
        self.last_error = str(e)

    async def _read(self, port: serial.Serial, emit: Callable[[NmeaLine], None]) -> None:
        loop = asyncio.get_running_loop()
        failed: asyncio.Future[None] = loop.create_future()
        self.connected = True
        self.last_error = None

        def readable() -> None:
            try:
                data = port.read(max(port.in_waiting, 1))
            except (serial.SerialException, OSError) as e:
                if not failed.done():
                    failed.set_exception(e)
                return
            if data:
                self.bytes_read += len(data)
                for line in self.framer.feed(data, self.clock()):
                    emit(line)

        loop.add_reader(port.fileno(), readable)
        try:
            await failed
        finally:
            loop.remove_reader(port.fileno())
