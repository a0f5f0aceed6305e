"""GPS source: NMEA lines from a serial port (pyserial), read from the asyncio loop without blocking.

The port is opened non-blocking and read when the loop says it is readable; each chunk of bytes is framed into
records (NMEA lines and UBX frames, decode/framing.py, whatever gps.velocity says) stamped with `clock`
(the host receive time; a SteadyClock in live runs, so that a step of the host clock does
not reach the records). What the car does to a GPS, and what the source does about it:

- Unplugged (the device disappears; pyserial then raises "device reports readiness to read but returned no data",
  or "read failed: [Errno 5]" on a pseudo-terminal whose other end closed): the port is closed and reopened by its
  configured name, so a stable symlink (/dev/serial/by-id/...) that points to a new device afterwards is followed.
  Retries back off from MIN_BACKOFF_S to MAX_BACKOFF_S (no busy loop while it is gone; back within MAX_BACKOFF_S of
  its return). The gap is an event (`on_event`: disconnected, then connected with the gap's length) and is in
  status() (logged with every /diagnostics record of a live run, shown in the live view).
- Silent (open, but no byte for SILENT_AFTER_S): an event and a state, not a reconnect.
- Wrong baud rate: bytes come, but over QUALITY_WINDOW_S seconds at least UNREADABLE_MIN_BYTES of them without a
  single NMEA sentence whose checksum checks out (an MTi: an Xbus message): state `unreadable`, the diagnostic "GPS
  data unreadable: wrong baud rate?" ("IMU ..." for the MTi; with the share of bytes that are not text) in the events
  and the live view, and a counter. It clears with the next valid sentence (message).
- A pipeline that raises on a line does not stop the source: the error is counted and reported, the next line goes on.
"""

from __future__ import annotations

import asyncio
import contextlib
import logging
import os
import re
import time
from collections import deque
from collections.abc import Callable
from functools import reduce
from operator import xor
from typing import Any, Protocol

import serial

from slipdaq.decode.framing import GpsFramer
from slipdaq.decode.xbus import parse_message
from slipdaq.records import EventHandler, NmeaLine, SourceEvent, XbusBytes

log = logging.getLogger(__name__)


class Framer(Protocol):
    """Bytes -> raw records (GpsFramer: UBX frames and NMEA lines)."""

    def feed(self, data: bytes, timestamp_s: float) -> list[Any]: ...

    @property
    def pending_bytes(self) -> int: ...


MIN_BACKOFF_S = 0.05
MAX_BACKOFF_S = 0.5
"""Reopen attempts while the device is gone: at most this far apart (so it is back within this of its return)."""
SILENT_AFTER_S = 2.0
CONFIRM_S = 1.0
"""An open port with no error for this long counts as connected even before it sends anything."""
QUALITY_WINDOW_S = 3.0
UNREADABLE_MIN_BYTES = 128
"""A 1 Hz receiver sends several hundred bytes a second; this many with no valid sentence is not NMEA."""
WATCH_S = 0.25

_NOT_TEXT = bytes(b for b in range(256) if b >= 0x7F or (b < 0x20 and b not in (0x09, 0x0A, 0x0D)))
_SENTENCE = re.compile(r"[$!]([^$!*]{1,120})\*([0-9A-Fa-f]{2})\s*$")


def valid_record(record: object) -> bool:
    """An NMEA line whose checksum checks out, an Xbus message (not the noise between messages the MTi's framer
    keeps), any other record a framer made (a binary frame whose framer checked it)."""
    if isinstance(record, NmeaLine):
        return valid_sentence(record.line)
    if isinstance(record, XbusBytes):
        return parse_message(record.data) is not None
    return True


def valid_sentence(line: str) -> bool:
    """The line ends with an NMEA sentence whose checksum checks out (noise before it is allowed)."""
    m = _SENTENCE.search(line)
    if m is None:
        return False
    try:
        body = m[1].encode("latin-1")
    except UnicodeEncodeError:
        return False
    return reduce(xor, body, 0) == int(m[2], 16)


class LineQuality:
    """Whether a byte stream is readable NMEA, over a sliding window of whole seconds (bounded memory)."""

    def __init__(self, window_s: float = QUALITY_WINDOW_S, min_bytes: int = UNREADABLE_MIN_BYTES) -> None:
        self.window_s = window_s
        self.min_bytes = min_bytes
        self._buckets: deque[list[int]] = deque()  # [second, bytes, not-text bytes, valid sentences]

    def _bucket(self, now: float) -> list[int]:
        sec = int(now)
        if not self._buckets or self._buckets[-1][0] != sec:
            self._buckets.append([sec, 0, 0, 0])
        while self._buckets and self._buckets[0][0] <= sec - self.window_s:
            self._buckets.popleft()
        return self._buckets[-1]

    def feed(self, data: bytes, lines: list, now: float) -> int:
        """Count a chunk of bytes and the records framed from it; returns how many were valid (valid_record)."""
        b = self._bucket(now)
        b[1] += len(data)
        b[2] += len(data) - len(data.translate(None, _NOT_TEXT))
        valid = sum(valid_record(x) for x in lines)
        b[3] += valid
        return valid

    def totals(self, now: float) -> tuple[int, int, int]:
        """(bytes, not-text bytes, valid sentences) over the window."""
        self._bucket(now)
        return (sum(b[1] for b in self._buckets), sum(b[2] for b in self._buckets), sum(b[3] for b in self._buckets))

    def unreadable(self, now: float) -> bool:
        n, _bad, valid = self.totals(now)
        return n >= self.min_bytes and valid == 0

    def reset(self) -> None:
        self._buckets.clear()


class SerialGpsSource:
    def __init__(
        self,
        port: str,
        baudrate: int,
        clock: Callable[[], float] = time.time,
        *,
        on_event: EventHandler | None = None,
        monotonic: Callable[[], float] = time.monotonic,
        framer: Callable[[], Framer] = GpsFramer,
        name: str = "gps",
    ) -> None:
        """clock stamps the lines (the log's clock); monotonic measures gaps, backoff and the quality window;
        framer makes the byte -> record framer for each connection (UBX frames and NMEA lines by default; an Xsens
        MTi's Xbus messages: decode.xbus.XbusFramer); name: the source its events name ("gps", "imu"), and the
        config section of its port."""
        self.name = name
        self.label = name.upper()
        self.expects, self.device = ("Xbus message", "sensor") if name == "imu" else ("NMEA sentence", "receiver")
        self.port = port
        self.baudrate = baudrate
        self.clock = clock
        self.on_event = on_event
        self._mono = monotonic
        self._new_framer = framer
        self.framer: Framer = framer()
        self.quality = LineQuality()
        self.connected = False
        self.state = "disconnected"
        """connected | disconnected | silent | unreadable"""
        self.bytes_read = 0
        self.lines = 0
        self.valid_sentences = 0
        self.reconnects = 0
        """Connections after the first."""
        self.open_attempts = 0
        self.gaps = 0
        """Times the port was lost after it had been open."""
        self.unreadable_periods = 0
        self.silent_periods = 0
        self.emit_errors = 0
        self.last_error: str | None = None
        self.last_gap_s: float | None = None
        self.diagnostic: str | None = None
        """One line for the live view while something is wrong (None when all is well)."""
        self._ever_connected = False
        self._confirmed = False
        self._opened_at = monotonic()
        self._lost_at: float | None = None
        self._state_since = monotonic()
        self._last_byte_at = self._state_since

    # ---- state and events ----
    def status(self) -> dict[str, object]:
        """The port's state for each /diagnostics record of a live run and the live view."""
        now = self._mono()
        return {
            "gps_connected": self.connected, "gps_state": self.state, "gps_gaps": self.gaps,
            "gps_gap_s": None if self._lost_at is None or not self._ever_connected else round(now - self._lost_at, 3),
            "gps_last_gap_s": None if self.last_gap_s is None else round(self.last_gap_s, 3),
            "gps_reconnects": self.reconnects, "gps_bytes": self.bytes_read,
            "gps_unreadable_periods": self.unreadable_periods, "gps_error": self.diagnostic,
        }

    def _counters(self) -> dict[str, int]:
        return {"gaps": self.gaps, "reconnects": self.reconnects, "open_attempts": self.open_attempts,
                "bytes": self.bytes_read, "lines": self.lines, "valid_sentences": self.valid_sentences,
                "unreadable_periods": self.unreadable_periods, "silent_periods": self.silent_periods,
                "emit_errors": self.emit_errors}

    def _event(self, event: str, detail: str, gap_s: float | None = None) -> None:
        if self.on_event is None:
            return
        try:
            self.on_event(SourceEvent(self.clock(), self.name, event, detail, gap_s, self._counters()))
        except Exception:  # a sink that fails must not stop the GPS
            log.exception("%s event handler failed", self.label)

    def _set_state(self, state: str) -> float:
        """Enter a state; returns how long the previous one lasted."""
        now = self._mono()
        lasted = now - self._state_since
        self.state, self._state_since = state, now
        return lasted

    def _port_opened(self) -> None:
        """The port opened; it counts as connected once data comes, or after CONFIRM_S without an error (so that a
        device that opens and fails at once, again and again, makes no stream of events)."""
        now = self._mono()
        self._confirmed = False
        self._opened_at = now
        self._last_byte_at = now
        self.framer = self._new_framer()  # a line cut by the unplug must not merge with the first one after it
        self.quality.reset()

    def _confirm(self) -> None:
        now = self._mono()
        self._confirmed = True
        gap = None if self._lost_at is None or not self._ever_connected else now - self._lost_at
        if self._ever_connected:
            self.reconnects += 1
        self._ever_connected = True
        self.connected = True
        self.last_error = None
        self.diagnostic = None
        self._lost_at = None
        self._set_state("connected")
        where = os.path.realpath(self.port)
        detail = f"{self.port}" + (f" -> {where}" if where != self.port else "")
        if gap is not None:
            self.last_gap_s = gap
            log.warning("%s port %s back after %.2f s", self.label, detail, gap)
            self._event("connected", f"{detail}: back after {gap:.2f} s", gap)
        else:
            self._event("connected", detail)

    def _lost(self, e: Exception) -> None:
        text = str(e) or type(e).__name__
        if self._confirmed:  # a working connection broke: a gap starts
            self.gaps += 1
            self._lost_at = self._mono()
            log.warning("%s port %s lost: %s; reopening with backoff", self.label, self.port, text)
            self._event("disconnected", text)
        elif self.last_error is None:  # the first failure since the start or since the last good connection
            if self._lost_at is None:
                self._lost_at = self._mono()
            log.warning("%s port %s: %s; retrying", self.label, self.port, text)
            self._event("disconnected", text)
        self._confirmed = False
        self.connected = False
        self.last_error = text
        self.diagnostic = f"{self.label} DISCONNECTED: {text}"
        if self.state != "disconnected":
            self._set_state("disconnected")

    def _check_quality(self, now: float, valid: int) -> None:
        if valid:
            if self.state == "unreadable":
                lasted = self._set_state("connected")
                self.diagnostic = None
                log.warning("%s data readable again after %.1f s", self.label, lasted)
                self._event("readable", f"a valid {self.expects} again after {lasted:.1f} s", lasted)
            return
        if self.state in ("connected", "silent") and self.quality.unreadable(now):
            n, bad, _ = self.quality.totals(now)
            self.unreadable_periods += 1
            self._set_state("unreadable")
            self.diagnostic = (f"{self.label} data unreadable: wrong baud rate? ({n} bytes in "
                               f"{self.quality.window_s:.0f} s without one valid {self.expects}, "
                               f"{100 * bad / max(n, 1):.0f}% of them not text; {self.name}.baudrate is {self.baudrate})")
            log.warning("%s", self.diagnostic)
            self._event("unreadable", self.diagnostic)

    def _watch(self) -> None:
        """Every WATCH_S while open: confirm a quiet connection, notice a receiver that went quiet."""
        now = self._mono()
        if not self._confirmed:
            if now - self._opened_at >= CONFIRM_S:
                self._confirm()
            return
        if self.state in ("connected", "unreadable") and now - self._last_byte_at >= SILENT_AFTER_S:
            self.silent_periods += 1
            self._set_state("silent")
            self.diagnostic = f"no data from the {self.label} for {SILENT_AFTER_S:.0f} s ({self.device} off or muted?)"
            self._event("silent", self.diagnostic)

    # ---- reading ----
    def _open(self) -> serial.Serial:
        return serial.Serial(self.port, self.baudrate, timeout=0, exclusive=True)

    async def run(self, emit: Callable[[NmeaLine], None]) -> None:
        """Read until cancelled; reopen the port with backoff (MIN_BACKOFF_S doubling to MAX_BACKOFF_S) when it fails."""
        backoff_s = MIN_BACKOFF_S
        while True:
            self.open_attempts += 1
            try:
                port = self._open()
            except (serial.SerialException, OSError, ValueError) as e:
                self._lost(e)
                await asyncio.sleep(backoff_s)
                backoff_s = min(backoff_s * 2, MAX_BACKOFF_S)
                continue
            bytes_before = self.bytes_read
            try:
                self._port_opened()
                await self._read(port, emit)
            except (serial.SerialException, OSError) as e:
                self._lost(e)
            finally:
                with contextlib.suppress(Exception):
                    port.close()
            if self.bytes_read > bytes_before:  # it worked for a while: come back quickly
                backoff_s = MIN_BACKOFF_S
            await asyncio.sleep(backoff_s)
            backoff_s = min(backoff_s * 2, MAX_BACKOFF_S)

    def feed(self, data: bytes, emit: Callable[[Any], None]) -> None:
        """One chunk of bytes from the port: frame, check, emit (public for tests and other byte sources)."""
        now = self._mono()
        if not self._confirmed:
            self._confirm()
        self.bytes_read += len(data)
        self._last_byte_at = now
        if self.state == "silent":
            lasted = self._set_state("connected")
            self.diagnostic = None
            self._event("receiving", f"data again after {lasted:.1f} s", lasted)
        lines = self.framer.feed(data, self.clock())
        self.lines += len(lines)
        valid = self.quality.feed(data, lines, now)
        self.valid_sentences += valid
        self._check_quality(now, valid)
        for line in lines:
            try:
                emit(line)
            except Exception as e:  # the pipeline failed on this line: count it, keep reading
                self.emit_errors += 1
                shown = repr(getattr(line, "line", line))[:100]
                log.exception("%s record not processed: %s", self.label, shown)
                if self.emit_errors == 1 or self.emit_errors % 1000 == 0:
                    self._event("emit_error", f"{type(e).__name__}: {e} ({shown[:60]})")

    async def _read(self, port: serial.Serial, emit: Callable[[NmeaLine], None]) -> None:
        loop = asyncio.get_running_loop()
        failed: asyncio.Future[None] = loop.create_future()
        fd = port.fileno()

        def readable() -> None:
            try:
                data = port.read(max(port.in_waiting, 1))
            except (serial.SerialException, OSError) as e:
                if not failed.done():
                    failed.set_exception(e)
                loop.remove_reader(fd)  # no busy loop on a device that stays readable while it fails
                return
            if data:
                self.feed(data, emit)

        loop.add_reader(fd, readable)
        try:
            while not failed.done():
                await asyncio.wait([failed], timeout=WATCH_S)
                if not failed.done():
                    self._watch()
            failed.result()
        finally:
            loop.remove_reader(fd)
