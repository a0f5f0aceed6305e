"""SocketCAN frames read straight from python-can's socket: one recvmsg per frame into plain values.

python-can's `SocketcanBus.recv` costs a select() and a `can.Message` per frame, most of the receive cost at a few
thousand frames/s. `RawSocketCanReader` reads the same socket (opened, bound and filtered by python-can, with its
SO_TIMESTAMPNS) and returns what slipdaq keeps of a frame, with the values python-can would give: the kernel's
receive stamp as `seconds + nanoseconds * 1e-9`, the identifier without its flag bits, the data bytes (none for a
remote frame), and errors
as `can.CanOperationError("Error receiving: ...")`. CAN FD frames go through python-can's own dissector.
"""

from __future__ import annotations

import socket
import struct
import time
from collections.abc import Callable

import can

RawFrame = tuple[float, int, bool, bool, bytes]
"""(timestamp_s, arbitration_id, is_extended_id, is_error_frame, data): what the pipeline keeps of a frame."""

CAN_MTU = 16
"""sizeof(struct can_frame): a classic frame."""
CANFD_MTU = 72
CAN_EFF_FLAG = 0x80000000
CAN_RTR_FLAG = 0x40000000
CAN_ERR_FLAG = 0x20000000
SO_TIMESTAMPNS = getattr(socket, "SO_TIMESTAMPNS", 35)
_HEADER = struct.Struct("=IB")  # can_id (with the EFF/RTR/ERR flags), len; then flags, res0, len8_dlc, data[8]
_TIMESPEC = struct.Struct("@ll")  # struct timespec, as python-can reads it
_ANCILLARY_BYTES = socket.CMSG_SPACE(_TIMESPEC.size)


def frame_reader(bus: can.BusABC) -> Callable[[], RawFrame | None]:
    """The cheapest way to read `bus` without blocking: RawSocketCanReader for python-can's SocketCAN bus (and for
    buses that declare `raw_socketcan_frames`), else bus.recv(timeout=0). Returns None when nothing is queued."""
    if is_socketcan(bus):
        return RawSocketCanReader(bus.socket).recv  # type: ignore[attr-defined]

    def recv() -> RawFrame | None:
        m = bus.recv(timeout=0)
        return None if m is None else message_to_raw(m)

    return recv


def message_to_raw(m: can.Message) -> RawFrame:
    return m.timestamp, m.arbitration_id, m.is_extended_id, m.is_error_frame, bytes(m.data)


def is_socketcan(bus: can.BusABC) -> bool:
    """A bus whose socket delivers SocketCAN `struct can_frame`s stamped by SO_TIMESTAMPNS: python-can's SocketCAN
    bus (its filters are in the kernel), or one that declares it (`raw_socketcan_frames = True`)."""
    sock = getattr(bus, "socket", None)
    if not isinstance(sock, socket.socket):
        return False
    if getattr(bus, "raw_socketcan_frames", False):
        return True
    try:
        from can.interfaces.socketcan import SocketcanBus
    except ImportError:  # not Linux
        return False
    return isinstance(bus, SocketcanBus)


class RawSocketCanReader:
    """Reads one frame per call from a SocketCAN socket without blocking (MSG_DONTWAIT); None when it is empty."""

    def __init__(self, sock: socket.socket) -> None:
        self._recvmsg = sock.recvmsg

    def recv(self) -> RawFrame | None:
        try:
            cf, ancillary, _flags, _addr = self._recvmsg(CANFD_MTU, _ANCILLARY_BYTES, socket.MSG_DONTWAIT)
        except BlockingIOError:
            return None
        except OSError as e:  # e.g. ENETDOWN when the link goes down: python-can's error, so reports read the same
            raise can.CanOperationError(f"Error receiving: {e.strerror}", e.errno) from e
        timestamp_s = None
        for level, kind, data in ancillary:
            if level == socket.SOL_SOCKET and kind == SO_TIMESTAMPNS:
                seconds, nanoseconds = _TIMESPEC.unpack_from(data)
                timestamp_s = seconds + nanoseconds * 1e-9
        if timestamp_s is None:  # a socket without SO_TIMESTAMPNS (python-can always sets it)
            timestamp_s = time.time()
        if len(cf) == CAN_MTU:
            can_id, n = _HEADER.unpack_from(cf)
            payload = cf[8:8 + min(n, 8)]
        else:  # CAN FD: python-can's rules for the length
            from can.interfaces.socketcan.socketcan import dissect_can_frame

            can_id, _dlc, _fd_flags, payload = dissect_can_frame(cf)
        if can_id & CAN_RTR_FLAG:
            payload = b""  # a remote frame carries no data (python-can's Message drops it too)
        extended = bool(can_id & CAN_EFF_FLAG)
        return (timestamp_s, can_id & (0x1FFFFFFF if extended else 0x7FF), extended, bool(can_id & CAN_ERR_FLAG),
                payload)
