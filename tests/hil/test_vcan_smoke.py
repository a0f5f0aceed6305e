"""SocketCAN smoke tests on vcan0; run inside the VM by tests/hil/run_vm.sh.

Skipped where the kernel has no AF_CAN (errno 97) or no vcan0, e.g. on the host.
"""
import socket
import struct
import threading
import time

import pytest
from hil_support import can_unavailable_reason

_reason = can_unavailable_reason()
if _reason:
    pytest.skip(_reason, allow_module_level=True)

import can  # noqa: E402  (must be installed where the VM runs the tests)

from slipdaq.sources.can_bus import SO_RCVBUFFORCE  # noqa: E402  (Linux value; root only)

BIG_RCVBUF = 8 * 1024 * 1024
IDS = (0x310, 0x311, 0x312, 0x313)


def _bus():
    return can.Bus(interface="socketcan", channel="vcan0")


def _grow_rcvbuf(bus):
    """Ask for an 8 MiB receive buffer; return (before, after) as read back."""
    sock = bus.socket
    before = sock.getsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF)
    try:
        sock.setsockopt(socket.SOL_SOCKET, SO_RCVBUFFORCE, BIG_RCVBUF)
    except PermissionError:  # not root: capped by net.core.rmem_max
        sock.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, BIG_RCVBUF)
    return before, sock.getsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF)


def _send(bus, msg):
    while True:  # a full tx queue answers ENOBUFS: wait and retry
        try:
            bus.send(msg)
            return
        except can.CanOperationError:
            time.sleep(0.001)


class _Reader(threading.Thread):
    """Reads frames until `stop` is set and no frame came for `idle` seconds."""

    def __init__(self, bus, limit=None, idle=2.0):
        super().__init__(daemon=True)
        self.bus, self.limit, self.idle = bus, limit, idle
        self.msgs, self.count = [], 0
        self.stop = threading.Event()

    def run(self):
        while self.limit is None or self.count < self.limit:
            msg = self.bus.recv(timeout=self.idle)
            if msg is None:
                if self.stop.is_set():
                    return
                continue
            self.count += 1
            if self.limit is not None:
                self.msgs.append((msg, time.time()))


def test_so_rcvbuf_grows(capsys):
    with _bus() as bus:
        before, after = _grow_rcvbuf(bus)
    with capsys.disabled():
        print(f"\nhil SO_RCVBUF: asked {BIG_RCVBUF}, before {before}, after {after}")
    assert after > before


def test_2000_frames_in_order():
    n = 2000
    with _bus() as rx, _bus() as tx:
        _grow_rcvbuf(rx)
        reader = _Reader(rx, limit=n)
        reader.start()
        for i in range(n):
            data = struct.pack("<IHH", i, IDS[i % 4], 0xA55A)
            _send(tx, can.Message(arbitration_id=IDS[i % 4], data=data, is_extended_id=False))
        reader.stop.set()
        reader.join(timeout=60)
        assert not reader.is_alive(), f"reader stuck after {reader.count} frames"

    assert len(reader.msgs) == n
    for i, (msg, seen_at) in enumerate(reader.msgs):
        assert msg.arbitration_id == IDS[i % 4]
        assert not msg.is_extended_id and msg.dlc == 8
        assert struct.unpack("<IHH", msg.data) == (i, IDS[i % 4], 0xA55A)
        # A kernel timestamp (epoch seconds), not zero or a monotonic clock.
        assert abs(msg.timestamp - seen_at) < 5.0


def test_throughput_probe(capsys):
    """Prints frames/s through vcan0 with a concurrent reader; asserts no rate."""
    seconds = 5.0
    with _bus() as rx, _bus() as tx:
        _grow_rcvbuf(rx)
        reader = _Reader(rx)
        reader.start()
        msg = can.Message(arbitration_id=0x310, data=bytes(8), is_extended_id=False)
        sent, start = 0, time.perf_counter()
        while time.perf_counter() - start < seconds:
            _send(tx, msg)
            sent += 1
        elapsed = time.perf_counter() - start
        reader.stop.set()
        reader.join(timeout=60)
    with capsys.disabled():
        print(f"\nhil throughput: sent {sent} in {elapsed:.1f} s ({sent / elapsed:.0f} frames/s),"
              f" received {reader.count} ({sent - reader.count} lost)")
    assert 0 < reader.count <= sent
