"""CAN source: python-can bus -> CanFrame, on the asyncio loop without blocking it.

A bus with a file descriptor (SocketCAN) is read from the loop itself (loop.add_reader, no thread), SocketCAN straight
from its socket (socketcan_raw: no can.Message per frame), at most every `read_interval_s` (the frames wait in the
kernel's buffer with their receive stamps and come as one batch) unless `keep_reading()` says an estimate waits for
wheel frames; `read_now()` ends a pause. Any other bus is read by one thread that hands frames to the loop in
batches and is joined on exit.
A reader that raises is reported and restarted, never silently stopped. A receive error (e.g. ENETDOWN when the
SocketCAN link goes down) starts an outage, which ends with the next frame received; both are reported (`report`)
and counted (`status()`, logged with the diagnostics).
"""

from __future__ import annotations

import asyncio
import logging
import platform
import socket
import sys
import threading
import time
from collections.abc import Callable

import can

from slipdaq.records import FLAG_DLC, FLAG_REMOTE, CanFrame, CanFrameBatch, EventHandler, SourceEvent, channel_name, pack_flags
from slipdaq.sources.clock import SteadyClock
from slipdaq.sources.socketcan_raw import RawFrame, frame_reader

log = logging.getLogger(__name__)

BATCH = 256
"""Most frames read per wake-up of the loop."""
BATCH_BUDGET_S = 0.01
"""Longest a wake-up reads frames (SocketCAN) before it hands them to the pipeline and the loop serves its other
readers: the GPS port's lines are stamped when they are read, so a CAN backlog being drained must not hold them
back (reading is the slow part in the emulated test VM)."""

SO_RCVBUFFORCE: int | None = getattr(socket, "SO_RCVBUFFORCE", None) or (
    33 if sys.platform == "linux" and not platform.machine().startswith(("alpha", "parisc", "sparc")) else None
)
"""Python's socket module does not define SO_RCVBUFFORCE (Linux, root or CAP_NET_ADMIN: SO_RCVBUF above
net.core.rmem_max); 33 is its value in Linux's asm-generic/socket.h, used by every architecture but these three."""


def to_frame(msg: can.Message, timestamp_s: float | None = None) -> CanFrame:
    """python-can's Message as a CanFrame, every field kept; timestamp_s replaces its own stamp (the log's clock)."""
    remote = msg.is_remote_frame
    data = b"" if remote else bytes(msg.data)
    dlc = msg.dlc
    channel = msg.channel
    return CanFrame(msg.timestamp if timestamp_s is None else timestamp_s, msg.arbitration_id, data,
                    msg.is_extended_id, msg.is_error_frame, remote, msg.is_fd, msg.bitrate_switch,
                    msg.error_state_indicator, msg.is_rx, channel if type(channel) is str else channel_name(channel),
                    None if dlc == len(data) and not remote else
                    dlc if pack_flags(msg) & (FLAG_REMOTE | FLAG_DLC) else None)


def to_message(frame: CanFrame, timestamp_s: float = 0.0) -> can.Message:
    """A CanFrame as python-can's Message (to send it), every field as it was received."""
    return can.Message(timestamp=timestamp_s, arbitration_id=frame.arbitration_id,
                       is_extended_id=frame.is_extended_id, is_remote_frame=frame.is_remote_frame,
                       is_error_frame=frame.is_error_frame, channel=frame.channel, dlc=frame.length,
                       data=frame.data, is_fd=frame.is_fd, is_rx=frame.is_rx, bitrate_switch=frame.bitrate_switch,
                       error_state_indicator=frame.error_state_indicator)


def to_frames(msgs: list[can.Message], timestamps_s: list[float] | None = None) -> CanFrameBatch:
    """One reader wake-up's messages as the pipeline takes them (Pipeline.process_can_batch); timestamps_s replaces
    their own stamps (the log's clock)."""
    return CanFrameBatch.from_frames(msgs, [m.timestamp for m in msgs] if timestamps_s is None else timestamps_s)


def raw_to_frames(raws: list[RawFrame], timestamps_s: list[float]) -> CanFrameBatch:
    """to_frames for frames read as RawFrame tuples (socketcan_raw.frame_reader), stamped timestamps_s."""
    _, ids, flags, payloads, dlc, channels = zip(*raws)
    return CanFrameBatch.from_columns(timestamps_s, ids, flags, payloads, dlc, channels)


def set_receive_buffer(bus: can.BusABC, size_bytes: int) -> int | None:
    """Ask for a large SO_RCVBUF on a socket-based bus (bursts are not dropped); returns what the kernel gave."""
    sock = getattr(bus, "socket", None)
    if not isinstance(sock, socket.socket) or size_bytes <= 0:
        return None
    for opt in (SO_RCVBUFFORCE, socket.SO_RCVBUF):
        if opt is None:
            continue
        try:
            sock.setsockopt(socket.SOL_SOCKET, opt, size_bytes)
            break
        except OSError:
            continue
    return sock.getsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF)


def receive_buffer_bytes(bus: can.BusABC) -> int | None:
    """The SO_RCVBUF the kernel holds for a socket-based bus (Linux reports twice the size asked for), else None."""
    sock = getattr(bus, "socket", None)
    if not isinstance(sock, socket.socket):
        return None
    try:
        return sock.getsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF)
    except OSError:
        return None


class CanBusSource:
    """Reads a python-can bus until cancelled; `emit` gets each CanFrame on the loop, in arrival order.

    `report` gets one line when an outage starts (the first receive error after a frame) and one when it ends, on
    the loop, and `on_event` a SourceEvent ("down", then "up" with the gap); `clock` measures the outage (monotonic
    seconds). The outage ends with the first frame received after the error: stamped after it (python-can stamps
    are epoch seconds), or read after the socket was found empty (SocketCAN reports ENETDOWN before the frames still
    queued from before the link went down).

    `stamp` (the run's SteadyClock) brings the frames' wall-clock stamps (the kernel's receive time on SocketCAN)
    into the log's clock, which a host clock step does not move; the frames are kept in order (a frame stamped
    before a step and read after it gets the previous frame's time). Without it the bus's stamps are kept as they are.
    """

    def __init__(
        self,
        bus: can.BusABC,
        report: Callable[[str], None] | None = None,
        clock: Callable[[], float] = time.monotonic,
        *,
        stamp: SteadyClock | None = None,
        on_event: EventHandler | None = None,
        read_interval_s: float = 0.0,
        keep_reading: Callable[[], bool] | None = None,
    ) -> None:
        self.bus = bus
        self.read_interval_s = read_interval_s
        self.keep_reading = keep_reading
        self.reads = 0
        """Wake-ups that read the bus (a socket bus read on the loop)."""
        self._read_now: Callable[[], None] | None = None
        self.stamp = stamp
        self.on_event = on_event
        self._last_t = float("-inf")
        self.frames = 0
        self.reader_errors = 0
        self.last_error: str | None = None
        self.outages = 0
        self.outage_since: float | None = None
        """clock() at the error that started the current outage; None while frames arrive."""
        self.last_outage_s: float | None = None
        """Error to next frame, of the last outage that ended."""
        self._outage_wall_s = 0.0
        self._drained = False
        self._report = report
        self._clock = clock

    def read_now(self) -> None:
        """End a pause between reads (read_interval_s) now: e.g. an estimate waits for wheel frames."""
        if self._read_now is not None:
            self._read_now()

    def status(self) -> dict[str, object]:
        """The reader's state for the diagnostics record."""
        return {
            "can_reader_errors": self.reader_errors, "can_outages": self.outages,
            "can_receiving": self.outage_since is None, "can_last_error": self.last_error,
            "can_last_outage_s": self.last_outage_s,
        }

    def _fileno(self) -> int | None:
        try:
            fd = self.bus.fileno()
        except (NotImplementedError, OSError, AttributeError):
            return None
        return fd if isinstance(fd, int) and fd >= 0 else None

    async def run(
        self, emit: Callable[[CanFrame], None],
        emit_batch: Callable[[CanFrameBatch], None] | None = None,
    ) -> None:
        """emit_batch (e.g. Pipeline.process_can_batch), when given, gets each wake-up's frames at once (to_frames)."""
        if emit_batch is None:
            def emit_batch(frames: CanFrameBatch) -> None:
                for f in frames.frames():
                    emit(f)
        fd = self._fileno()
        if fd is not None:
            await self._run_on_loop(fd, emit_batch)
        else:
            await self._run_in_thread(emit_batch)

    def _stamps(self, bus_stamps_s: list[float]) -> list[float]:
        """The frames' bus timestamps in the log's clock, in order (see the class's docstring)."""
        if self.stamp is None:
            return bus_stamps_s
        out = self.stamp.from_wall_many(bus_stamps_s, self._last_t)
        self._last_t = out[-1]
        return out

    def _source_event(self, event: str, detail: str, gap_s: float | None = None) -> None:
        if self.on_event is None:
            return
        t = self.stamp() if self.stamp is not None else time.time()
        try:
            self.on_event(SourceEvent(t, "can", event, detail, gap_s,
                                      {"reader_errors": self.reader_errors, "outages": self.outages}))
        except Exception:  # a sink that fails must not stop the CAN source
            log.exception("CAN event handler failed")

    def _error(self, e: Exception) -> None:
        self.reader_errors += 1
        self.last_error = f"{type(e).__name__}: {e}"
        log.warning("CAN reader error (%s), continuing", self.last_error)
        self._drained = False
        if self.outage_since is None:
            self.outage_since = self._clock()
            self._outage_wall_s = time.time()
            self.outages += 1
            if self._report is not None:
                self._report(f"CAN receive error ({self.last_error}): no CAN frames until it clears, "
                             f"logging continues (outage {self.outages})")
            self._source_event("down", self.last_error)
        else:
            self._source_event("reader_error", self.last_error)

    def _during_outage(self, timestamp_s: float) -> None:
        """A frame (its bus stamp) during an outage: the outage ends if the frame came after the error."""
        assert self.outage_since is not None
        if not self._drained and timestamp_s < self._outage_wall_s:
            return  # queued before the error
        self.last_outage_s = self._clock() - self.outage_since
        self.outage_since = None
        if self._report is not None:
            self._report(f"CAN receiving again after {self.last_outage_s:.2f} s "
                         f"(outage {self.outages}; first frame stamped {timestamp_s:.6f})")
        self._source_event("up", f"receiving again (outage {self.outages})", self.last_outage_s)

    def _deliver(self, raws: list[RawFrame], emit_batch: Callable[[CanFrameBatch], None]) -> None:
        if not raws:
            return
        self.frames += len(raws)
        emit_batch(raw_to_frames(raws, self._stamps([r[0] for r in raws])))

    async def _run_on_loop(self, fd: int, emit_batch: Callable[[CanFrameBatch], None]) -> None:
        loop = asyncio.get_running_loop()
        interval_s = self.read_interval_s
        keep_reading = self.keep_reading
        recv = frame_reader(self.bus)  # SocketCAN: straight from the socket, no can.Message per frame
        resume: asyncio.TimerHandle | None = None

        def resume_reading() -> None:  # the pause's end (its timer) or read_now()
            nonlocal resume
            if resume is not None:
                resume.cancel()
                resume = None
                loop.add_reader(fd, readable)

        def readable() -> None:
            nonlocal resume
            woke_s = loop.time()
            self.reads += 1
            deadline = time.monotonic() + BATCH_BUDGET_S
            raws: list[RawFrame] = []
            drained = False
            try:
                for _ in range(BATCH):
                    raw = recv()
                    if raw is None:
                        self._drained = drained = True
                        break
                    if self.outage_since is not None:
                        self._during_outage(raw[0])
                    raws.append(raw)
                    if time.monotonic() > deadline:
                        break  # the rest on the next wake-up (level-triggered: the socket is still readable)
            except Exception as e:  # any error: counted, reading goes on, the frames read before it delivered
                self._error(e)
            self._deliver(raws, emit_batch)
            if drained and interval_s > 0 and not (keep_reading is not None and keep_reading()):
                # pause: the next frames wait in the kernel's buffer, with their receive stamps, and come as a batch
                loop.remove_reader(fd)
                resume = loop.call_at(woke_s + interval_s, resume_reading)

        loop.add_reader(fd, readable)
        self._read_now = resume_reading
        try:
            await asyncio.Event().wait()
        finally:
            self._read_now = None
            if resume is not None:
                resume.cancel()
            loop.remove_reader(fd)

    async def _run_in_thread(self, emit_batch: Callable[[CanFrameBatch], None]) -> None:
        loop = asyncio.get_running_loop()
        stop = threading.Event()

        def deliver(batch: list[can.Message]) -> None:
            stamps = [m.timestamp for m in batch]
            for t in stamps:
                if self.outage_since is not None:
                    self._during_outage(t)
            self.frames += len(batch)
            emit_batch(to_frames(batch, self._stamps(stamps)))

        def reader() -> None:
            while not stop.is_set():
                batch: list[can.Message] = []
                error: Exception | None = None
                try:
                    msg = self.bus.recv(timeout=0.05)
                    if msg is None:
                        self._drained = True
                        continue
                    batch.append(msg)
                    while len(batch) < BATCH and (msg := self.bus.recv(timeout=0)) is not None:
                        batch.append(msg)
                except Exception as e:  # keep reading: a raising reader must not stop the source
                    error = e
                if batch:  # what was read before an error is delivered, in order, before the error
                    loop.call_soon_threadsafe(deliver, batch)
                if error is not None:
                    loop.call_soon_threadsafe(self._error, error)
                    stop.wait(0.1)

        thread = threading.Thread(target=reader, name="slipdaq-can-reader", daemon=True)
        thread.start()
        try:
            await asyncio.Event().wait()
        finally:
            stop.set()
            await asyncio.to_thread(thread.join)
