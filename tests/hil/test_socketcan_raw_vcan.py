"""slipdaq's direct SocketCAN read (sources/socketcan_raw.py) against python-can's recv on vcan0, frame for frame.

Two python-can SocketCAN buses listen on vcan0; the kernel gives both the same frames with the same receive stamp.
One is read with python-can's recv, the other with RawSocketCanReader: every field must agree, the stamp to the
nanosecond. The drain rates of both readers are reported (information, not asserted). Runs in the VM only.
"""

from __future__ import annotations

import subprocess
import time

import pytest
from hil_support import can_unavailable_reason, report

_reason = can_unavailable_reason()
if _reason:
    pytest.skip(_reason, allow_module_level=True)

import can  # noqa: E402

from slipdaq.records import pack_flags  # noqa: E402
from slipdaq.sources.can_bus import set_receive_buffer  # noqa: E402
from slipdaq.sources.socketcan_raw import RawSocketCanReader, frame_reader, is_socketcan  # noqa: E402

N = 4000


def _frames() -> list[can.Message]:
    out = []
    for k in range(N):
        kind = k % 5
        if kind == 0:
            out.append(can.Message(arbitration_id=0x310 + k % 4, data=k.to_bytes(4, "little") + bytes(3) + bytes([k % 256]),
                                   is_extended_id=False))
        elif kind == 1:
            out.append(can.Message(arbitration_id=0x18FF0000 | k, data=bytes([k % 256] * (k % 9)), is_extended_id=True))
        elif kind == 2:
            out.append(can.Message(arbitration_id=0x004, data=bytes([0, 0x10, 0, 0, 0, 0, 0, 0]), is_error_frame=True,
                                   is_extended_id=False))
        elif kind == 3:
            out.append(can.Message(arbitration_id=0x123, is_remote_frame=True, dlc=k % 9, is_extended_id=False))
        else:
            out.append(can.Message(arbitration_id=0x7FF, data=b"", is_extended_id=False))
    return out


def _drain(read, n: int) -> tuple[list, float]:
    got = []
    t0 = time.perf_counter()
    while len(got) < n:
        x = read()
        if x is None:
            break
        got.append(x)
    return got, time.perf_counter() - t0


def test_raw_read_equals_python_can_on_vcan() -> None:
    with can.Bus(interface="socketcan", channel="vcan0") as a, can.Bus(interface="socketcan", channel="vcan0") as b, \
            can.Bus(interface="socketcan", channel="vcan0") as tx:
        for bus in (a, b):
            set_receive_buffer(bus, 16 * 1024 * 1024)
        assert is_socketcan(a) and frame_reader(a).__self__.__class__ is RawSocketCanReader  # type: ignore[attr-defined]
        sent = _frames()
        for m in sent:
            while True:
                try:
                    tx.send(m)
                    break
                except can.CanOperationError:  # the queue is full: let the kernel catch up
                    time.sleep(0.001)
        time.sleep(0.2)
        msgs, t_py = _drain(lambda: a.recv(timeout=0), N)
        raws, t_raw = _drain(RawSocketCanReader(b.socket).recv, N)
    assert len(msgs) == len(raws) == N
    for m, raw in zip(msgs, raws):
        assert raw == (m.timestamp, m.arbitration_id, pack_flags(m), bytes(m.data), m.dlc, m.channel)
    report(f"socketcan raw read: {N} frames equal to python-can's (stamps to the ns); drain rate python-can recv "
           f"{N / t_py:,.0f} frames/s, RawSocketCanReader {N / t_raw:,.0f} frames/s ({t_py / t_raw:.1f}x)")


def test_a_down_link_raises_python_can_s_error() -> None:
    """ENETDOWN while vcan0 is down reads as python-can reports it (the daemon's outage lines rely on it)."""
    with can.Bus(interface="socketcan", channel="vcan0") as bus:
        reader = RawSocketCanReader(bus.socket)
        subprocess.run(["ip", "link", "set", "vcan0", "down"], check=True)
        try:
            with pytest.raises(can.CanOperationError, match="Error receiving: Network is down"):
                for _ in range(100):  # the error is queued on the socket when the link goes down
                    reader.recv()
                    time.sleep(0.01)
        finally:
            subprocess.run(["ip", "link", "set", "vcan0", "up"], check=True)
