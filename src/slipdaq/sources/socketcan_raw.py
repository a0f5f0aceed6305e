"""SocketCAN frames read straight from python-can's socket: one recvmsg per frame into plain values.

python-can's `SocketcanBus.recv` costs a select() and a `can.Message` per frame, most of the receive cost at a few
thousand frames/s. `RawSocketCanReader` reads the same socket (opened, bound and filtered by python-can, with its
SO_TIMESTAMPNS) and returns what python-can's Message would hold, as plain values: the kernel's receive stamp as
`seconds + nanoseconds * 1e-9`, the identifier without its flag bits, the flags (extended, error, remote; CAN FD,
bit rate switch, error state indicator; transmitted by this host: MSG_DONTROUTE), the data bytes (none for a remote
frame, whose DLC is kept), the channel (the bus's, or the interface the frame came from on a bus bound to all), and
errors as `can.CanOperationError("Error receiving: ...")`. Frames are read as linux/can.h lays them out
(`struct can_frame`, `struct canfd_frame`), the same values python-can's SocketCAN bus gives (tested against it).
"""

from __future__ import annotations

import socket
import struct
import time
from collections.abc import Callable

import can

from slipdaq.records import (
    FLAG_BRS,
    FLAG_DLC,
    FLAG_ERROR,
    FLAG_ESI,
    FLAG_EXTENDED,
    FLAG_FD,
    FLAG_REMOTE,
    FLAG_TX,
    channel_name,
    pack_flags,
)

RawFrame = tuple[float, int, int, bytes, int, str | None]
"""(timestamp_s, arbitration_id, flags (records.FLAG_*), data, dlc, channel): what the pipeline keeps of a frame;
dlc is python-can's (records.CanFrameBatch.dlc: the data's length, a remote frame's requested one, or with FLAG_DLC
the DLC of an 8-byte payload)."""

CAN_MTU = 16
"""sizeof(struct can_frame): a classic frame."""
CANFD_MTU = 72
CAN_EFF_FLAG = 0x80000000
CAN_RTR_FLAG = 0x40000000
CAN_ERR_FLAG = 0x20000000
SO_TIMESTAMPNS = getattr(socket, "SO_TIMESTAMPNS", 35)
_HEADER = struct.Struct("=IBxxB")  # can_id (with the EFF/RTR/ERR flags), len, pad, res0, len8_dlc; then data[8]
_FD_HEADER = struct.Struct("=IBBxx")  # canfd_frame: can_id, len, flags, res0, res1; then data[64]
_FD_LENGTHS = (0, 1, 2, 3, 4, 5, 6, 7, 8, 12, 16, 20, 24, 32, 48, 64)
"""The payload lengths a CAN FD frame can have (ISO 11898-1; linux/can.h's canfd_frame.len)."""
_FD_FLAGS = ((0x01, FLAG_BRS), (0x02, FLAG_ESI))  # canfd_frame.flags: CANFD_BRS, CANFD_ESI
_TIMESPEC = struct.Struct("@ll")  # struct timespec, as python-can reads it
_ANCILLARY_BYTES = socket.CMSG_SPACE(_TIMESPEC.size)


def frame_reader(bus: can.BusABC) -> Callable[[], RawFrame | None]:
    """The cheapest way to read `bus` without blocking: RawSocketCanReader for python-can's SocketCAN bus (and for
    buses that declare `raw_socketcan_frames`), else bus.recv(timeout=0). Returns None when nothing is queued."""
    if is_socketcan(bus):
        return RawSocketCanReader(bus.socket, getattr(bus, "channel", None)).recv  # type: ignore[attr-defined]  # is_socketcan() checked that the bus has its socket

    def recv() -> RawFrame | None:
        m = bus.recv(timeout=0)
        return None if m is None else message_to_raw(m)

    return recv


def message_to_raw(m: can.Message) -> RawFrame:
    flags = pack_flags(m)
    return (m.timestamp, m.arbitration_id, flags, b"" if flags & FLAG_REMOTE else bytes(m.data),
            m.dlc if flags & (FLAG_REMOTE | FLAG_DLC) else len(m.data), channel_name(m.channel))


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
    """Reads one frame per call from a SocketCAN socket without blocking (MSG_DONTWAIT); None when it is empty.

    channel: the bus's (python-can's `SocketcanBus.channel`); without one ("" or None: bound to every interface)
    each frame's own interface, as python-can gives it."""

    def __init__(self, sock: socket.socket, channel: str | None = None) -> None:
        self._recvmsg = sock.recvmsg
        self._channel = channel or None

    def recv(self) -> RawFrame | None:
        try:
            cf, ancillary, msg_flags, addr = self._recvmsg(CANFD_MTU, _ANCILLARY_BYTES, socket.MSG_DONTWAIT)
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
        flags = FLAG_TX if msg_flags & socket.MSG_DONTROUTE else 0  # python-can: created on this host
        if len(cf) == CAN_MTU:
            can_id, n, len8_dlc = _HEADER.unpack_from(cf)
            payload = cf[8:8 + min(n, 8)]
            if n == 8 and 8 < len8_dlc <= 15:  # python-can: a classic frame's DLC 9..15 (CAN_CTRLMODE_CC_LEN8_DLC)
                n = len8_dlc
        else:  # CAN FD: a length between two valid ones is read as the next valid one (as python-can does)
            can_id, n, fd_flags = _FD_HEADER.unpack_from(cf)
            n = next((k for k in _FD_LENGTHS if k >= n), 64)
            payload = cf[8:8 + n]
            flags |= FLAG_FD
            for bit, flag in _FD_FLAGS:
                if fd_flags & bit:
                    flags |= flag
        if can_id & CAN_EFF_FLAG:
            flags |= FLAG_EXTENDED
        if can_id & CAN_ERR_FLAG:
            flags |= FLAG_ERROR
        if can_id & CAN_RTR_FLAG:
            flags |= FLAG_REMOTE
            payload = b""  # a remote frame carries no data (python-can's Message drops it too), only its DLC
        elif n != len(payload):
            flags |= FLAG_DLC
        channel = self._channel
        if channel is None:
            channel = channel_name(addr[0] if isinstance(addr, tuple) else addr)
        return timestamp_s, can_id & (0x1FFFFFFF if flags & FLAG_EXTENDED else 0x7FF), flags, payload, n, channel
