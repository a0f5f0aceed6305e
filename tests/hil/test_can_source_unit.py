"""CanBusSource's outage bookkeeping and the daemon's receive-buffer metadata, without SocketCAN (runs anywhere).

The same paths on a real vcan0 link going down and up are in test_daemon_socketcan.py (VM only).
"""

from __future__ import annotations

import asyncio
import socket
import struct
import time
from pathlib import Path

import can

from slipdaq.sources.can_bus import CanBusSource, receive_buffer_bytes, set_receive_buffer
from support.fd_bus import FdBus  # tests/fd_bus.py (tests/ is on sys.path through tests/conftest.py)


def _run(bus: FdBus, steps: list[object]) -> tuple[CanBusSource, list[int], list[str], list[dict[str, object]]]:
    """Start a source on bus, then per step: an int n puts frame n, "down" raises an error, "clock+2.5" advances
    the outage clock, "status" records status(), "wait" nothing; each followed by a short sleep."""
    lines: list[str] = []
    now = [0.0]
    src = CanBusSource(bus, report=lines.append, clock=lambda: now[0])  # type: ignore[arg-type]
    got: list[int] = []
    states: list[dict[str, object]] = []

    async def run() -> None:
        task = asyncio.create_task(src.run(lambda f: got.append(struct.unpack_from("<I", f.data)[0])))
        for step in steps:
            if step == "down":
                bus.link_down()
            elif step == "clock+2.5":
                now[0] += 2.5
            elif step == "status":
                states.append(src.status())
            elif step == "wait":
                pass
            else:
                bus.put(step)  # type: ignore[arg-type]
            await asyncio.sleep(0.02)
        task.cancel()

    try:
        asyncio.run(run())
    finally:
        bus.close()
    return src, got, lines, states


def test_an_outage_is_reported_counted_and_ended_by_the_next_frame() -> None:
    bus = FdBus()
    _, got, lines, (down, up) = _run(bus, [1, 2, "down", "down", "status", "clock+2.5", 3, 4, "status"])
    assert got == [1, 2, 3, 4]
    assert down["can_receiving"] is False and down["can_outages"] == 1 and down["can_reader_errors"] == 2
    assert "Network is down" in str(down["can_last_error"])
    assert up["can_receiving"] is True and up["can_outages"] == 1 and up["can_last_outage_s"] == 2.5
    assert len(lines) == 2
    assert lines[0].startswith("CAN receive error (CanOperationError: Error receiving: Network is down")
    assert "outage 1" in lines[0] and "logging continues" in lines[0]
    assert lines[1] == f"CAN receiving again after 2.50 s (outage 1; first frame stamped {bus.stamps[3]:.6f})"


def test_frames_queued_before_the_error_do_not_end_the_outage() -> None:
    """SocketCAN answers ENETDOWN before the frames still queued from before the link went down: reading those
    does not mean the link is back; the first frame stamped after the error does."""
    bus = FdBus()
    bus.put(1)
    bus.put(2)  # queued: the source starts reading only now, and the error comes first
    time.sleep(0.01)
    bus.error_pending = True
    _, got, lines, (after_backlog, back) = _run(bus, ["wait", "clock+2.5", "status", 3, "status"])
    assert got == [1, 2, 3]
    assert after_backlog["can_receiving"] is False and after_backlog["can_outages"] == 1
    assert back["can_receiving"] is True
    assert lines[1] == f"CAN receiving again after 2.50 s (outage 1; first frame stamped {bus.stamps[3]:.6f})"


def test_receive_buffer_of_a_bus_without_a_socket_is_unknown() -> None:
    with can.Bus(interface="virtual", channel=f"unit-{time.monotonic_ns()}") as bus:
        assert set_receive_buffer(bus, 8 * 1024 * 1024) is None
        assert receive_buffer_bytes(bus) is None


def test_the_log_metadata_holds_the_receive_buffer_the_kernel_gave() -> None:
    """The daemon stores what the kernel granted (SO_RCVBUF read back), beside what the config asked for."""
    from slipdaq.config import load_config
    from slipdaq.live.daemon import can_metadata

    class _SocketBus:  # python-can's SocketCAN bus keeps its socket in `.socket`; any socket shows the mechanism
        socket = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)

    cfg = load_config(Path(__file__).resolve().parents[2] / "config" / "slipdaq.toml")
    bus = _SocketBus()
    try:
        got = set_receive_buffer(bus, cfg.can.receive_buffer_bytes)  # type: ignore[arg-type]
        assert got is not None and got > 0
        assert can_metadata(cfg, bus) == {  # type: ignore[arg-type]
            "can_receive_buffer_bytes": str(got), "can_receive_buffer_requested_bytes": str(cfg.can.receive_buffer_bytes),
        }
    finally:
        bus.socket.close()
