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

from slipdaq.sources.socketcan_raw import RawSocketCanReader, SO_TIMESTAMPNS, frame_reader, is_socketcan

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


def _fd(can_id: int, data: bytes) -> bytes:
    return struct.pack("=IBBxx64s", can_id, len(data), 0, data)


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
    msg = capture_message(rx)
    got = RawSocketCanReader(rx).recv()
    after = time.time()
    assert msg is not None and got is not None
    t, aid, ext, err, payload = got
    assert (aid, ext, err, payload) == (msg.arbitration_id, msg.is_extended_id, msg.is_error_frame, bytes(msg.data))
    assert before - 1e-3 <= msg.timestamp <= t <= after + 1e-3  # the kernel's stamps of the two datagrams


def test_a_can_fd_frame_goes_through_python_can_s_dissector(pair) -> None:  # type: ignore[no-untyped-def]
    rx, tx = pair
    raw = _fd(0x123 | CAN_EFF_FLAG, bytes(range(18)))  # len 18: python-can rounds it up to the FD length 20
    tx.send(raw)
    tx.send(raw)
    msg = capture_message(rx)
    _, aid, ext, err, payload = RawSocketCanReader(rx).recv()  # type: ignore[misc]
    assert (aid, ext, err, payload) == (msg.arbitration_id, True, False, bytes(msg.data)) and len(payload) == 20


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
            assert got is not None and got[1:] == (0x310, False, False, b"\x01\x02")
            assert recv() is None
        finally:
            bus2.shutdown()
