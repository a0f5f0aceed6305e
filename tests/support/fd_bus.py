"""A python-can bus with a file descriptor, for tests of CanBusSource's loop reader without SocketCAN (host and VM)."""

from __future__ import annotations

import socket
import struct
import time

import can


class FdBus:
    """A bus with a file descriptor (so CanBusSource reads it on the loop, as SocketCAN): frames are stamped when
    put (as the kernel stamps them when sent); an error (python-can's for ENETDOWN) is raised by the next recv,
    before the frames still queued, as SocketCAN does."""

    def __init__(self) -> None:
        self.a, self.b = socket.socketpair()
        self.a.setblocking(False)
        self.error_pending = False
        self.stamps: dict[int, float] = {}

    def fileno(self) -> int:
        return self.a.fileno()

    def put(self, n: int) -> None:
        self.stamps[n] = time.time()
        self.b.send(struct.pack("<id", n, self.stamps[n]))

    def link_down(self) -> None:
        self.error_pending = True
        self.b.send(struct.pack("<id", -1, 0.0))  # wakes the reader; read (and skipped) after the error

    def recv(self, timeout: float | None = None) -> can.Message | None:
        if self.error_pending:
            self.error_pending = False
            raise can.CanOperationError("Error receiving: Network is down", 100)
        while True:
            try:
                n, t = struct.unpack("<id", self.a.recv(struct.calcsize("<id")))
            except BlockingIOError:
                return None
            if n >= 0:
                return can.Message(timestamp=t, arbitration_id=0x310, data=struct.pack("<I3xB", n, n % 256))

    def close(self) -> None:
        self.a.close()
        self.b.close()
