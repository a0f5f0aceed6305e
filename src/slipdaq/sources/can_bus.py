"""CAN source: python-can bus -> CanFrame, on the asyncio loop without blocking it.

A bus with a file descriptor (SocketCAN) is read from the loop itself (loop.add_reader, no thread);
any other bus is read by one thread that hands frames to the loop in batches and is joined on exit.
A reader that raises is reported and restarted, never silently stopped.
"""

from __future__ import annotations

import asyncio
import logging
import socket
import threading
from collections.abc import Callable

import can

from slipdaq.records import CanFrame, CanFrameBatch

log = logging.getLogger(__name__)

BATCH = 256


BATCH_COLUMNS_FROM = 48
"""A wake-up with at least this many frames goes to the pipeline as one CanFrameBatch (numpy columns, no CanFrame
per frame); fewer go as CanFrames (numpy's fixed cost would dominate). Pipeline.SCALAR_MAX_FRAMES is the same."""


def to_frame(msg: can.Message) -> CanFrame:
    return CanFrame(msg.timestamp, msg.arbitration_id, bytes(msg.data), msg.is_extended_id, msg.is_error_frame)


def to_frames(msgs: list[can.Message]) -> CanFrameBatch | list[CanFrame]:
    """One reader wake-up's messages as the pipeline takes them (Pipeline.process_can_batch)."""
    if len(msgs) < BATCH_COLUMNS_FROM:
        return [to_frame(m) for m in msgs]
    return CanFrameBatch.from_columns([m.timestamp for m in msgs], [m.arbitration_id for m in msgs],
                                      [m.is_extended_id | (m.is_error_frame << 1) for m in msgs],
                                      [m.data for m in msgs])


def set_receive_buffer(bus: can.BusABC, size_bytes: int) -> int | None:
    """Ask for a large SO_RCVBUF on a socket-based bus (bursts are not dropped); returns what the kernel gave."""
    sock = getattr(bus, "socket", None)
    if not isinstance(sock, socket.socket) or size_bytes <= 0:
        return None
    for opt in (getattr(socket, "SO_RCVBUFFORCE", None), socket.SO_RCVBUF):
        if opt is None:
            continue
        try:
            sock.setsockopt(socket.SOL_SOCKET, opt, size_bytes)
            break
        except OSError:
            continue
    return sock.getsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF)


class CanBusSource:
    """Reads a python-can bus until cancelled; `emit` gets each CanFrame on the loop, in arrival order."""

    def __init__(self, bus: can.BusABC) -> None:
        self.bus = bus
        self.frames = 0
        self.reader_errors = 0
        self.last_error: str | None = None

    def _fileno(self) -> int | None:
        try:
            fd = self.bus.fileno()
        except (NotImplementedError, OSError, AttributeError):
            return None
        return fd if isinstance(fd, int) and fd >= 0 else None

    async def run(
        self, emit: Callable[[CanFrame], None],
        emit_batch: Callable[[CanFrameBatch | list[CanFrame]], None] | None = None,
    ) -> None:
        """emit_batch (e.g. Pipeline.process_can_batch), when given, gets each wake-up's frames at once (to_frames)."""
        if emit_batch is None:
            def emit_batch(frames: CanFrameBatch | list[CanFrame]) -> None:
                for f in frames if isinstance(frames, list) else frames.frames():
                    emit(f)
        fd = self._fileno()
        if fd is not None:
            await self._run_on_loop(fd, emit_batch)
        else:
            await self._run_in_thread(emit_batch)

    def _error(self, e: Exception) -> None:
        self.reader_errors += 1
        self.last_error = f"{type(e).__name__}: {e}"
        log.warning("CAN reader error (%s), continuing", self.last_error)

    async def _run_on_loop(self, fd: int, emit_batch: Callable[[CanFrameBatch | list[CanFrame]], None]) -> None:
        loop = asyncio.get_running_loop()

        def readable() -> None:
            msgs: list[can.Message] = []
            try:
                for _ in range(BATCH):
                    msg = self.bus.recv(timeout=0)
                    if msg is None:
                        break
                    msgs.append(msg)
            except can.CanError as e:
                self._error(e)
            finally:
                if msgs:
                    self.frames += len(msgs)
                    emit_batch(to_frames(msgs))

        loop.add_reader(fd, readable)
        try:
            await asyncio.Event().wait()
        finally:
            loop.remove_reader(fd)

    async def _run_in_thread(self, emit_batch: Callable[[CanFrameBatch | list[CanFrame]], None]) -> None:
        loop = asyncio.get_running_loop()
        stop = threading.Event()

        def deliver(batch: list[can.Message]) -> None:
            self.frames += len(batch)
            emit_batch(to_frames(batch))

        def reader() -> None:
            while not stop.is_set():
                try:
                    msg = self.bus.recv(timeout=0.05)
                    if msg is None:
                        continue
                    batch = [msg]
                    while len(batch) < BATCH and (msg := self.bus.recv(timeout=0)) is not None:
                        batch.append(msg)
                    loop.call_soon_threadsafe(deliver, batch)
                except Exception as e:  # keep reading: a raising reader must not stop the source
                    loop.call_soon_threadsafe(self._error, e)
                    stop.wait(0.1)

        thread = threading.Thread(target=reader, name="slipdaq-can-reader", daemon=True)
        thread.start()
        try:
            await asyncio.Event().wait()
        finally:
            stop.set()
            await asyncio.to_thread(thread.join)
