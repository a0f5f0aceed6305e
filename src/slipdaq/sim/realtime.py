"""Plays generated simulator events in real time: CAN frames on a python-can bus, NMEA lines on a byte writer, an
MTi's messages on another.

Sim time 0 maps to the event loop's monotonic time when play() starts. Events closer than BATCH_S to "now" are
sent without sleeping, so 400+ frames/s do not cost one sleep each.
"""

from __future__ import annotations

import asyncio
import errno
import time
from collections.abc import Callable, Iterator

import can

from slipdaq.records import CanFrame, NmeaLine, UbxFrame, XbusBytes
from slipdaq.sim.emit import SimEvent
from slipdaq.sim.vehicle import TruthSample
from slipdaq.sources.can_bus import to_message

BATCH_S = 0.002
"""Sleep only when the next event is more than this far ahead."""
MAX_EVENTS_WITHOUT_YIELD = 200
"""Give the loop a turn (sleep(0)) at least this often when running behind."""
RETRY_S = 0.001
"""Pause before retrying a write that would block (EAGAIN) or a full CAN transmit queue."""
CAN_RETRY_LIMIT_S = 0.5
"""How long a full CAN transmit queue is retried before its error is raised."""
LINK_DOWN_ERRNOS = (errno.ENETDOWN, errno.ENODEV, errno.ENXIO)
"""Send errors that retrying cannot cure (the interface is down or gone): raised at once."""


async def _write_line(nmea_write: Callable[[bytes], object], data: bytes) -> None:
    """Write all of data, retrying after RETRY_S on BlockingIOError and continuing after partial writes."""
    while data:
        try:
            written = nmea_write(data)
        except BlockingIOError:
            await asyncio.sleep(RETRY_S)
            continue
        if not isinstance(written, int) or written >= len(data):
            return
        if written > 0:
            data = data[written:]
        else:
            await asyncio.sleep(RETRY_S)


async def _send_frame(bus: can.BusABC, frame: CanFrame, timestamp_s: float = 0.0) -> None:
    """bus.send without blocking the loop; a CanOperationError (e.g. transmit buffer full) is retried briefly."""
    msg = to_message(frame, timestamp_s)
    waited_s = 0.0
    while True:
        try:
            bus.send(msg)
            return
        except can.CanOperationError as e:
            if waited_s >= CAN_RETRY_LIMIT_S or getattr(e, "error_code", None) in LINK_DOWN_ERRNOS:
                raise
            await asyncio.sleep(RETRY_S)
            waited_s += RETRY_S


async def play(
    events: Iterator[SimEvent],
    *,
    bus: can.BusABC,
    nmea_write: Callable[[bytes], object],
    duration_s: float | None = None,
    on_truth: Callable[[TruthSample], None] | None = None,
    start_wall_s: float | None = None,
    stamp_frames: bool = False,
    on_refused: Callable[[can.CanError], None] | None = None,
    imu_write: Callable[[bytes], object] | None = None,
) -> int:
    """Send each event at its time_s after the start; stop at duration_s (sim time) or when events run out.

    NMEA lines are written as line + CRLF, one write per line. Cancellation propagates. Returns the CAN frames sent.
    With start_wall_s, sim time 0 is that wall-clock time (time.time()), else the moment play() starts.
    stamp_frames (with start_wall_s) gives each CAN message its nominal wall-clock time as its timestamp, as a CAN
    adapter's hardware timestamp would; a bus that keeps it (python-can's virtual bus with preserve_timestamps=True)
    then carries it to the reader however late the event loop sends it.
    on_refused: a frame the bus refuses (link down, transmit queue full for CAN_RETRY_LIMIT_S) goes to it and the
    play goes on; without it the error is raised.
    imu_write: where the MTi's messages go ([imu] source = "serial"), each in one write; without it they are dropped.
    """
    loop = asyncio.get_running_loop()
    start = loop.time()
    if start_wall_s is not None:  # sim time 0 at this wall-clock time (so truth and records share one clock)
        start += max(0.0, start_wall_s - time.time())
    frames_sent = 0
    since_yield = 0
    for event in events:
        if duration_s is not None and event.time_s >= duration_s:
            await asyncio.sleep(max(0.0, start + duration_s - loop.time()))
            break
        ahead_s = start + event.time_s - loop.time()
        if ahead_s > BATCH_S:
            await asyncio.sleep(ahead_s)
            since_yield = 0
        elif since_yield >= MAX_EVENTS_WITHOUT_YIELD:
            await asyncio.sleep(0)
            since_yield = 0
        since_yield += 1
        record = event.record
        if isinstance(record, CanFrame):
            stamp = start_wall_s + event.time_s if stamp_frames and start_wall_s is not None else 0.0
            try:
                await _send_frame(bus, record, stamp)
            except can.CanOperationError as e:
                if on_refused is None:
                    raise
                on_refused(e)
                continue
            frames_sent += 1
        elif isinstance(record, NmeaLine):
            await _write_line(nmea_write, (record.line + "\r\n").encode("ascii"))
        elif isinstance(record, UbxFrame):
            await _write_line(nmea_write, record.data)
        elif isinstance(record, XbusBytes):
            if imu_write is not None:
                await _write_line(imu_write, record.data)
        elif event.truth is not None and on_truth is not None:
            on_truth(event.truth)
    return frames_sent
