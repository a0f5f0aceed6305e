"""Reliability of the CAN input: error frames and bus-off, unknown IDs, wrong DLC, Seq gaps, a counter
node reset (a new segment, not a huge negative slip), counts wrapping at 2^32 — through the decoder and the pipeline
(simulated drives) and on a live bus through the daemon; a python-can reader that raises does not stop the source.
(The SocketCAN link going down and up is tested in tests/hil.)"""

from __future__ import annotations

import asyncio
import io
import os
import socket
import struct
import time

import can
import pytest

from slipdaq import WHEELS
from slipdaq.config import load_config
from slipdaq.decode.can_errors import CAN_ERR_BUSOFF, CAN_ERR_CRTL, CAN_ERR_RESTARTED, error_classes
from slipdaq.live.daemon import new_log_path, open_bus, run_daemon
from slipdaq.live.demo import demo_config
from slipdaq.logformat.reader import iter_topic
from slipdaq.logformat.topics import TOPIC_DIAGNOSTICS
from slipdaq.pipeline import Pipeline
from slipdaq.records import CanFrame, RawRecord
from slipdaq.sinks import CollectingSink
from slipdaq.sinks.status import StatusSink, _Rates, status_line
from slipdaq.sources.can_bus import CanBusSource
from support.paths import CONFIG
from support.reliability_support import sim_records

WHEEL_IDS = {0x310 + i: w for i, w in enumerate(WHEELS)}


def _run(records: list[RawRecord]) -> tuple[Pipeline, list[dict], StatusSink]:
    collect, status = CollectingSink(), StatusSink()
    p = Pipeline(load_config(CONFIG), [collect, status])
    p.run(records)
    return p, [e.as_row() for e in collect.estimates], status


@pytest.fixture(scope="module")
def drive() -> tuple[list[RawRecord], Pipeline, list[dict]]:
    records = sim_records(12.0)
    p, est, _ = _run(records)
    assert len(est) > 80
    return records, p, est


def _slips(est: list[dict], w: str) -> list[float | None]:
    return [e[f"slip_{w}"] for e in est]


def _close(a: list[dict], b: list[dict], tol: float) -> None:
    """Same estimates (times) and slips within tol."""
    assert [e["time_s"] for e in a] == [e["time_s"] for e in b]
    for w in WHEELS:
        for x, y in zip(_slips(a, w), _slips(b, w)):
            assert (x is None) == (y is None) and (x is None or abs(x - y) <= tol), (w, x, y)


def test_error_frames_and_bus_off_change_nothing_but_counters(drive) -> None:  # type: ignore[no-untyped-def]
    """Error frames of every kind (bus-off, restarted, controller passive/overflow) among the data: the estimates are
    exactly those without them; the frames are counted, and the live view shows the bus-off."""
    records, _, clean = drive
    errors = [
        CanFrame(0.0, CAN_ERR_BUSOFF, bytes(8), is_error_frame=True),
        CanFrame(0.0, CAN_ERR_RESTARTED, bytes(8), is_error_frame=True),
        CanFrame(0.0, CAN_ERR_CRTL, bytes([0, 0x30, 0, 0, 0, 0, 0, 0]), is_error_frame=True),  # rx+tx passive
        CanFrame(0.0, CAN_ERR_CRTL, bytes([0, 0x01, 0, 0, 0, 0, 0, 0]), is_error_frame=True),  # rx overflow
    ]
    mixed: list[RawRecord] = []
    n = 0
    for i, r in enumerate(records):
        mixed.append(r)
        if i % 97 == 0:
            e = errors[n % len(errors)]
            mixed.append(CanFrame(r.timestamp_s, e.arbitration_id, e.data, False, True))
            n += 1
    p, est, status = _run(mixed)
    assert est == clean
    assert p.error_frames == n and p.unknown_frames == 0 and p.wheels.bad_frames == 0
    assert status.can_errors["bus_off"] == (n + 3) // 4
    assert "bus-off" in status_line(status, _Rates())
    assert error_classes(errors[2]) == ("controller", "rx_passive", "tx_passive")


def test_unknown_ids_and_extended_frames_change_nothing_but_counters(drive) -> None:  # type: ignore[no-untyped-def]
    records, _, clean = drive
    mixed: list[RawRecord] = []
    n = 0
    for i, r in enumerate(records):
        mixed.append(r)
        if i % 13 == 0:
            mixed.append(CanFrame(r.timestamp_s, 0x7FF - i % 200, bytes(i % 9)))
            mixed.append(CanFrame(r.timestamp_s, 0x310, bytes(8), is_extended_id=True))  # a wheel's ID, 29-bit
            n += 2
    p, est, _ = _run(mixed)
    assert est == clean
    assert p.unknown_frames == n


def test_wrong_dlc_frames_are_counted_and_cost_one_sample(drive) -> None:  # type: ignore[no-untyped-def]
    """Wheel frames cut short (DLC < 8) or too long: counted as bad, never raised; the wheel loses that sample (a
    Seq gap of one) and the estimates stay within a hundredth of slip of the clean run."""
    records, _, clean = drive
    bad: list[RawRecord] = []
    n = 0
    for i, r in enumerate(records):
        if isinstance(r, CanFrame) and i % 211 == 0:
            data = r.data[: i % 8] if i % 2 else r.data + b"\x00\x00\x00\x00"
            bad.append(CanFrame(r.timestamp_s, r.arbitration_id, data))
            n += 1 if len(data) < 8 else 0
        else:
            bad.append(r)
    p, est, _ = _run(bad)
    assert p.wheels.bad_frames == n and n > 5
    assert sum(p.wheels.lost_frames.values()) >= n
    _close(est, clean, 0.01)


def test_seq_gaps_are_lost_frames_and_estimates_go_on(drive) -> None:  # type: ignore[no-untyped-def]
    records, _, clean = drive
    dropped = {w: 0 for w in WHEELS}
    kept: list[RawRecord] = []
    for i, r in enumerate(records):
        if isinstance(r, CanFrame) and i % 37 == 36:  # (not a wheel's first frame: that one has no Seq before it)
            dropped[WHEEL_IDS[r.arbitration_id]] += 1
            continue
        kept.append(r)
    p, est, _ = _run(kept)
    assert p.wheels.lost_frames == dropped
    _close(est, clean, 0.01)


def test_counts_wrapping_at_2_pow_32_give_the_same_estimates(drive) -> None:  # type: ignore[no-untyped-def]
    """The simulated counters start 20000 pulses below 2^32 and wrap early in the drive: once per wheel, and the
    estimates are bit for bit those of the same drive with counters starting at 5000 (no wrap)."""
    _, p, wrapped = drive
    assert all(n == 1 for n in p.wheels.count_wraps.values())
    p2, unwrapped, _ = _run(sim_records(12.0, start_count=5000))
    assert all(n == 0 for n in p2.wheels.count_wraps.values())
    assert wrapped == unwrapped


def _reset(records: list[RawRecord], wheel_id: int, at_s: float, restart_seq: bool) -> list[RawRecord]:
    """The wheel's counter node resets at `at_s` (after the first frame): its counts (and Seq) start again at 0."""
    out: list[RawRecord] = []
    base: tuple[int, int] | None = None
    t0 = records[0].timestamp_s
    for r in records:
        if isinstance(r, CanFrame) and r.arbitration_id == wheel_id and r.timestamp_s - t0 >= at_s:
            count, seq = struct.unpack_from("<I", r.data)[0], r.data[7]
            if base is None:
                base = (count, seq)
            new_count = (count - base[0]) % 2**32
            new_seq = (seq - base[1]) % 256 if restart_seq else seq
            r = CanFrame(r.timestamp_s, wheel_id, struct.pack("<I3xB", new_count, new_seq))
        out.append(r)
    return out


@pytest.mark.parametrize("at_s", [3.0, 7.0])  # while accelerating / cruising fast
def test_counter_node_reset_is_a_new_segment_not_a_huge_slip(drive, at_s: float) -> None:  # type: ignore[no-untyped-def]
    """The FL node resets mid-drive (count back to 0): one counter reset counted, FL's slip stays within a hundredth of
    the clean run everywhere (the decoder continues at the wheel's last rate), the other wheels are untouched."""
    records, _, clean = drive
    p, est, _ = _run(_reset(records, 0x310, at_s, restart_seq=False))
    assert p.wheels.counter_resets == {"FL": 1, "FR": 0, "RL": 0, "RR": 0}
    assert all(s is None or s > -0.2 for s in _slips(est, "FL"))
    _close(est, clean, 0.01)


def test_counter_node_reset_with_seq_restart_loses_no_frame(drive) -> None:  # type: ignore[no-untyped-def]
    """A node that resets restarts its Seq too: that is not a gap of lost frames (the reset frame is the first of a
    new segment: its Seq is not compared with the old segment's)."""
    records, _, _ = drive
    p, _, _ = _run(_reset(records, 0x310, 3.0, restart_seq=True))
    assert p.wheels.counter_resets["FL"] == 1
    assert p.wheels.lost_frames["FL"] == 0


# ---- a python-can reader that raises ----

class _RaisingBus:
    """A python-can bus (no fileno: read by a thread) whose recv raises now and then, then goes on."""

    def __init__(self, frames: int, raise_at: dict[int, Exception]) -> None:
        self.n = 0
        self.frames = frames
        self.raise_at = dict(raise_at)
        self.calls = 0

    def fileno(self) -> int:
        raise NotImplementedError

    def recv(self, timeout: float | None = None) -> can.Message | None:
        self.calls += 1
        if self.calls in self.raise_at:
            raise self.raise_at.pop(self.calls)
        if self.n >= self.frames:
            time.sleep(timeout or 0)
            return None
        self.n += 1
        return can.Message(timestamp=time.time(), arbitration_id=0x310, data=struct.pack("<I3xB", self.n, self.n % 256))


def test_a_raising_reader_does_not_stop_the_can_source() -> None:
    """python-can's Notifier stops for good when a reader raises; CanBusSource goes on: every frame arrives, in
    order, and each error is counted (and starts an outage that the next frame ends)."""
    errors = {5: can.CanOperationError("bus error"), 50: OSError(100, "Network is down"), 120: RuntimeError("driver")}
    bus = _RaisingBus(400, errors)
    src = CanBusSource(bus)  # type: ignore[arg-type]
    got: list[int] = []

    async def run() -> None:
        task = asyncio.create_task(src.run(lambda f: got.append(struct.unpack_from("<I", f.data)[0])))
        t_end = time.monotonic() + 1.0
        while len(got) < 400 and time.monotonic() < t_end:
            await asyncio.sleep(0.05)
        task.cancel()
        with pytest.raises(asyncio.CancelledError):
            await task

    asyncio.run(run())
    assert got == list(range(1, 401))
    assert src.reader_errors == 3
    status = src.status() if hasattr(src, "status") else {}
    assert status.get("can_outages", 3) == 3 and status.get("can_receiving", True) is True


class _SocketBus:
    """A bus with a file descriptor (read on the loop, like SocketCAN) whose recv raises a non-CAN error once."""

    def __init__(self) -> None:
        self.a, self.b = socket.socketpair()
        self.a.setblocking(False)
        self.raised = False

    def fileno(self) -> int:
        return self.a.fileno()

    def recv(self, timeout: float | None = None) -> can.Message | None:
        try:
            data = self.a.recv(8)
        except BlockingIOError:
            return None
        n = struct.unpack("<I4x", data)[0]
        if n == 10 and not self.raised:
            self.raised = True
            raise OSError(19, "No such device")
        return can.Message(timestamp=time.time(), arbitration_id=0x310, data=struct.pack("<I3xB", n, n % 256))


def test_a_reader_raising_any_error_on_the_loop_is_counted() -> None:
    bus = _SocketBus()
    src = CanBusSource(bus)  # type: ignore[arg-type]
    got: list[int] = []

    async def run() -> None:
        loop = asyncio.get_running_loop()
        loop.set_exception_handler(lambda loop, ctx: None)
        task = asyncio.create_task(src.run(lambda f: got.append(struct.unpack_from("<I", f.data)[0])))
        for n in range(1, 31):
            bus.b.send(struct.pack("<I4x", n))
            await asyncio.sleep(0.005)
        await asyncio.sleep(0.1)
        task.cancel()
        with pytest.raises(asyncio.CancelledError):
            await task

    try:
        asyncio.run(run())
    finally:
        bus.a.close()
        bus.b.close()
    assert got == [n for n in range(1, 31) if n != 10]
    assert src.reader_errors == 1


# ---- on a live bus, through the daemon ----

def test_can_faults_on_a_live_bus(tmp_path) -> None:  # type: ignore[no-untyped-def]
    """The daemon on a virtual bus gets 1.6 s of wheel frames at 100 Hz with faults mixed in: error frames and a
    bus-off, unknown IDs, short frames, a Seq gap per wheel. It keeps running; its counters in /diagnostics say
    exactly what was injected; the live view shows the bus-off. (No GPS: the port does not exist.)"""
    channel = f"slipdaq-rel-can-{os.getpid()}"
    cfg = demo_config(str(tmp_path / "no-gps"), channel)
    status = io.StringIO()
    injected = {"error": 0, "unknown": 0, "short": 0, "gaps": {w: 0 for w in WHEELS}}
    sent = asyncio.Event()

    async def send(bus: can.BusABC) -> None:
        for k in range(160):
            for i, w in enumerate(WHEELS):
                if k % 60 == 30:  # a lost frame per wheel now and then
                    injected["gaps"][w] += 1
                    continue
                bus.send(can.Message(arbitration_id=0x310 + i, data=struct.pack("<I3xB", 20 * k, k % 256),
                                     is_extended_id=False))
            if k % 25 == 0:
                bus.send(can.Message(arbitration_id=CAN_ERR_BUSOFF if k == 100 else CAN_ERR_CRTL,
                                     data=bytes([0, 0x10, 0, 0, 0, 0, 0, 0]), is_error_frame=True))
                bus.send(can.Message(arbitration_id=0x5A5, data=b"\x01\x02", is_extended_id=False))
                bus.send(can.Message(arbitration_id=0x311, data=b"\x01\x02\x03", is_extended_id=False))
                injected["error"] += 1
                injected["unknown"] += 1
                injected["short"] += 1
            await asyncio.sleep(0.01)
        await asyncio.sleep(0.5)  # what was sent read and decided, however busy the host
        sent.set()

    async def run():  # type: ignore[no-untyped-def]
        with open_bus(cfg) as daemon_bus, can.Bus(interface="virtual", channel=channel) as sender:
            async with asyncio.TaskGroup() as tg:
                tg.create_task(send(sender))
                return await run_daemon(cfg, daemon_bus, new_log_path(tmp_path, "can"), duration_s=60.0,
                                        status_stream=status, status_every_s=0.5, stop=sent)

    result = asyncio.run(run())
    d = [d for _, _, d in iter_topic(result.log_path, (TOPIC_DIAGNOSTICS,))][-1]
    assert d["error_frames"] == injected["error"] and d["unknown_frames"] == injected["unknown"]
    assert d["bad_frames"] == injected["short"]
    assert d["lost_frames"] == injected["gaps"]  # the short frames came on top of the wheel's own
    assert result.can_frames == 4 * 160 - sum(injected["gaps"].values()) + 3 * injected["error"]
    assert "bus-off 1" in status.getvalue()
