"""RawSocketCanReader against python-can's own SocketCAN receive (`capture_message`), frame for frame.

This host has no AF_CAN, but SocketCAN's receive path is a datagram socket with SO_TIMESTAMPNS delivering
`struct can_frame`s: a loopback UDP socket with the same option delivers the same bytes and ancillary data, so both
readers run on real kernel datagrams here. On vcan, tests/hil runs the daemon with this reader.
"""

from __future__ import annotations

import socket
import struct
import time

import can
import pytest
from can.interfaces.socketcan.socketcan import capture_message
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from slipdaq.sources.socketcan_raw import SO_TIMESTAMPNS, RawSocketCanReader, frame_reader, is_socketcan

CAN_EFF_FLAG, CAN_RTR_FLAG, CAN_ERR_FLAG = 0x80000000, 0x40000000, 0x20000000


@pytest.fixture
def pair():  # type: ignore[no-untyped-def]
    rx = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    rx.bind(("127.0.0.1", 0))
    rx.setsockopt(socket.SOL_SOCKET, SO_TIMESTAMPNS, 1)
    tx = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    tx.connect(rx.getsockname())
    yield rx, tx
    rx.close()
    tx.close()


def _classic(can_id: int, data: bytes) -> bytes:
    return struct.pack("=IB3x8s", can_id, len(data), data)


def _fd(can_id: int, data: bytes, fd_flags: int = 0) -> bytes:
    return struct.pack("=IBBxx64s", can_id, len(data), fd_flags, data)


FIELDS = ("arbitration_id", "is_extended_id", "is_error_frame", "is_remote_frame", "is_fd", "bitrate_switch",
          "error_state_indicator", "is_rx", "dlc", "data", "channel")


def _message_fields(msg: can.Message) -> dict:
    return {k: bytes(msg.data) if k == "data" else getattr(msg, k) for k in FIELDS}


def _raw_fields(raw: tuple) -> dict:
    """A RawFrame as python-can's Message fields (the flag bits as docs/log.md states them)."""
    _t, aid, flags, data, dlc, channel = raw
    return {"arbitration_id": aid, "is_extended_id": bool(flags & 1), "is_error_frame": bool(flags & 2),
            "is_remote_frame": bool(flags & 4), "is_fd": bool(flags & 8), "bitrate_switch": bool(flags & 16),
            "error_state_indicator": bool(flags & 32), "is_rx": not flags & 64, "dlc": dlc, "data": data,
            "channel": channel}


frames = st.one_of(
    st.tuples(st.integers(0, 0x7FF), st.just(0), st.binary(max_size=8)),  # standard
    st.tuples(st.integers(0, 0x1FFFFFFF), st.just(CAN_EFF_FLAG), st.binary(max_size=8)),  # extended
    st.tuples(st.integers(0, 0x7FF), st.just(CAN_ERR_FLAG), st.binary(min_size=8, max_size=8)),  # error frame
    st.tuples(st.integers(0, 0x7FF), st.just(CAN_RTR_FLAG), st.binary(max_size=8)),  # remote frame
)


@settings(max_examples=200, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
# one socket pair for all examples: each example reads back both datagrams it sent
@given(frame=frames)
def test_a_classic_frame_reads_as_python_can_reads_it(pair, frame) -> None:  # type: ignore[no-untyped-def]
    rx, tx = pair
    ident, flags, data = frame
    raw = _classic(ident | flags, data)
    before = time.time()
    tx.send(raw)
    tx.send(raw)
    msg = capture_message(rx, get_channel=True)
    got = RawSocketCanReader(rx).recv()
    after = time.time()
    assert msg is not None and got is not None
    assert _raw_fields(got) == _message_fields(msg)  # a remote frame: no data, its DLC kept
    assert before - 1e-3 <= msg.timestamp <= got[0] <= after + 1e-3  # the kernel's stamps of the two datagrams


@pytest.mark.parametrize("fd_flags", [0, 1, 2, 3])  # CANFD_BRS, CANFD_ESI
@pytest.mark.parametrize("length", [0, 8, 9, 18, 33, 64])  # 9, 18, 33: python-can rounds up to 12, 20, 48
def test_a_can_fd_frame_reads_as_python_can_reads_it(pair, fd_flags, length) -> None:  # type: ignore[no-untyped-def]
    rx, tx = pair
    raw = _fd(0x123 | CAN_EFF_FLAG, bytes(range(length)), fd_flags)
    tx.send(raw)
    tx.send(raw)
    msg = capture_message(rx, get_channel=True)
    got = RawSocketCanReader(rx).recv()
    assert got is not None and _raw_fields(got) == _message_fields(msg)
    assert msg.is_fd and len(got[3]) == len(msg.data) >= length and (msg.bitrate_switch, msg.error_state_indicator) == \
        (bool(fd_flags & 1), bool(fd_flags & 2))


def test_the_channel_is_the_bus_s_when_it_has_one(pair) -> None:  # type: ignore[no-untyped-def]
    """python-can's SocketcanBus names every frame by its own channel, and by the frame's interface only when it is
    bound to all of them (channel "")."""
    rx, tx = pair
    tx.send(_classic(0x310, bytes(8)))
    got = RawSocketCanReader(rx, "vcan0").recv()
    assert got is not None and got[5] == "vcan0"


def test_an_empty_socket_reads_none_without_blocking(pair) -> None:  # type: ignore[no-untyped-def]
    rx, _ = pair
    t0 = time.monotonic()
    assert RawSocketCanReader(rx).recv() is None
    assert time.monotonic() - t0 < 0.5


def test_a_receive_error_is_python_can_s_error() -> None:
    """A socket error while receiving (ENETDOWN on a CAN link going down; here ECONNREFUSED, which a loopback UDP
    socket gets after sending to a closed port) is raised as python-can raises it, so reports read the same."""
    closed = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    closed.bind(("127.0.0.1", 0))
    addr = closed.getsockname()
    closed.close()
    s = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    try:
        s.connect(addr)
        s.send(b"x")
        time.sleep(0.05)
        with pytest.raises(can.CanOperationError, match="Error receiving: Connection refused"):
            RawSocketCanReader(s).recv()
    finally:
        s.close()


def test_which_buses_are_read_raw() -> None:
    channel = f"raw-{time.monotonic_ns()}"
    with can.Bus(interface="virtual", channel=channel) as bus:
        assert not is_socketcan(bus)  # no socket: python-can's recv
        bus2 = can.Bus(interface="virtual", channel=channel)
        try:
            bus2.send(can.Message(arbitration_id=0x310, data=b"\x01\x02", is_extended_id=False))
            recv = frame_reader(bus)
            got = recv()
            assert got is not None and got[1:] == (0x310, 0, b"\x01\x02", 2, channel)
            assert recv() is None
        finally:
            bus2.shutdown()
