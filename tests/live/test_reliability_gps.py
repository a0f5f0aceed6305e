"""Reliability of the GPS input: unplugged and plugged back (at a new pseudo-terminal behind a stable
symlink), the pyserial "readiness to read but returned no data" error, no busy loop, the gap marked in the log and the
live view, a receiver at the wrong baud rate, arbitrary bytes."""

from __future__ import annotations

import asyncio
import io
import os
import time
from dataclasses import replace
from pathlib import Path

import can
import pytest
import serial
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from slipdaq.decode.framing import MAX_FRAME_BYTES
from slipdaq.decode.nmea import NmeaDecoder
from slipdaq.live.daemon import new_log_path, open_bus, run_daemon
from slipdaq.live.demo import demo_config
from slipdaq.logformat.reader import iter_estimates, iter_raw_records, iter_topic
from slipdaq.logformat.topics import TOPIC_DIAGNOSTICS, TOPIC_EVENTS
from slipdaq.records import NmeaLine, SourceEvent
from slipdaq.sim.emit import SimSettings, generate
from slipdaq.sim.realtime import play
from slipdaq.sinks.status import SourceStatus, StatusSink, _Rates, status_line
from slipdaq.sources import serial_gps
from slipdaq.sources.serial_gps import LineQuality, SerialGpsSource, valid_sentence
from support.reliability_support import ReplugGps, gps_lines, nmea, uart_misread

RMC = nmea("GPRMC,120000.00,A,5200.00000,N,01000.00000,E,20.000,90.0,010126,,,A")


async def _write_for(gps: ReplugGps, lines: list[str], seconds: float, rate_hz: float = 20.0) -> list[float]:
    """Write lines (cycling) for `seconds`; returns the write times (time.monotonic)."""
    times = []
    end = time.monotonic() + seconds
    i = 0
    while time.monotonic() < end:
        gps.write((lines[i % len(lines)] + "\r\n").encode())
        times.append(time.monotonic())
        i += 1
        await asyncio.sleep(1.0 / rate_hz)
    return times


def test_gps_unplugged_and_back_at_a_new_pty_behind_a_symlink(tmp_path: Path) -> None:
    """The configured port is a symlink; the pty behind it goes away for 1.5 s and comes back at another path: the
    source reconnects within 1 s of its return (by the symlink), marks the gap (events, status, live view), and
    retries with backoff meanwhile (a handful of open attempts, little CPU)."""
    link = tmp_path / "gps0"
    gps = ReplugGps(link)
    events: list[SourceEvent] = []
    lines: list[tuple[float, NmeaLine]] = []
    src = SerialGpsSource(str(link), 115200, on_event=events.append)
    view = StatusSink(SourceStatus(gps_port=str(link), gps_connected=lambda: src.connected, gps_status=src.status))
    sentences = gps_lines(1.0)

    async def run() -> dict[str, float]:
        task = asyncio.create_task(src.run(lambda line: lines.append((time.monotonic(), line))))
        await asyncio.sleep(0.3)
        await _write_for(gps, sentences, 1.0)
        spare = gps.prepare()
        gps.unplug()
        attempts0, cpu0, t0 = src.open_attempts, time.process_time(), time.monotonic()
        await asyncio.sleep(1.5)
        gone = {"attempts": src.open_attempts - attempts0, "cpu": time.process_time() - cpu0,
                "gap_seen": src.status()["gps_gap_s"] or 0.0}
        gone["line_during_gap"] = status_line(view, _Rates())
        plugged = time.monotonic()
        gps.plug(spare)
        await _write_for(gps, sentences, 1.2)
        task.cancel()
        with pytest.raises(asyncio.CancelledError):
            await task
        gone["plugged"] = plugged
        gone["gap_s"] = plugged - t0
        return gone

    try:
        r = asyncio.run(run())
    finally:
        gps.close()
    assert gps.paths[0] != gps.paths[1]  # a new pseudo-terminal
    first_after = min(t for t, _ in lines if t > r["plugged"])
    assert first_after - r["plugged"] < 1.0, f"back {first_after - r['plugged']:.2f} s after the device returned"
    assert 2 <= r["attempts"] <= 10 and r["cpu"] < 0.3  # backoff, no busy loop
    assert r["gap_seen"] > 1.0 and "DISCONNECTED" in r["line_during_gap"]
    kinds = [e.event for e in events]
    assert kinds == ["connected", "disconnected", "connected"], kinds
    back = events[-1]
    assert back.gap_s is not None and 1.4 < back.gap_s < 2.6 and gps.paths[1] in back.detail
    assert src.gaps == 1 and src.reconnects == 1 and src.status()["gps_last_gap_s"] == pytest.approx(back.gap_s, abs=1e-3)
    good = [line.line for _, line in lines]
    assert all(valid_sentence(x) for x in good)  # no line half from before the unplug, half after


class _DeadPort:
    """A serial port that reports readiness to read and then has nothing: an unplugged USB adapter, as pyserial
    sees it."""

    def __init__(self) -> None:
        self.r, self.w = os.pipe()
        os.write(self.w, b"x")  # always readable
        self.in_waiting = 0
        self.closed = False

    def fileno(self) -> int:
        return self.r

    def read(self, n: int) -> bytes:
        raise serial.SerialException("device reports readiness to read but returned no data "
                                     "(device disconnected or multiple access on port?)")

    def close(self) -> None:
        if not self.closed:
            self.closed = True
            os.close(self.r)
            os.close(self.w)


def test_device_readiness_but_no_data_is_handled_without_a_busy_loop() -> None:
    """pyserial's error for an unplugged device, on a port that opens but fails at every read: no exception escapes,
    one event (not one per retry), retries back off to MAX_BACKOFF_S, little CPU."""
    events: list[SourceEvent] = []
    src = SerialGpsSource("/dev/ttyFAKE", 115200, on_event=events.append)
    ports: list[_DeadPort] = []

    def open_dead() -> _DeadPort:
        ports.append(_DeadPort())
        return ports[-1]

    src._open = open_dead  # type: ignore[method-assign]

    async def run() -> float:
        cpu0 = time.process_time()
        task = asyncio.create_task(src.run(lambda line: None))
        await asyncio.sleep(1.3)
        task.cancel()
        with pytest.raises(asyncio.CancelledError):
            await task
        return time.process_time() - cpu0

    cpu = asyncio.run(run())
    assert 3 <= src.open_attempts <= 8  # 0.05, 0.1, 0.2, 0.4, 0.5, ...
    assert cpu < 0.3
    assert all(p.closed for p in ports)
    assert [e.event for e in events] == ["disconnected"]
    assert "readiness to read" in events[0].detail and not src.connected and src.gaps == 0


def test_gps_gap_during_a_live_run(tmp_path: Path) -> None:
    """The daemon with the simulator (virtual bus, pty behind a symlink): the GPS is unplugged for 1.5 s mid-run.
    CAN goes on (no frame lost), estimates go on from the wheels during the gap, the GPS is back within 1 s of its
    return and GPS estimates resume; the live view says DISCONNECTED meanwhile."""
    link = tmp_path / "gps-link"
    gps = ReplugGps(link)
    channel = f"slipdaq-rel-gps-{os.getpid()}"
    cfg = demo_config(str(link), channel)
    settings_ = replace(SimSettings(), start_utc_s=time.time() + 0.5)
    status = io.StringIO()
    marks: dict[str, float] = {}

    async def faults() -> None:
        await asyncio.sleep(2.5)
        spare = gps.prepare()
        gps.unplug()
        marks["unplug"] = time.time()
        await asyncio.sleep(1.5)
        marks["plug"] = time.time()
        gps.plug(spare)

    async def run():  # type: ignore[no-untyped-def]
        with open_bus(cfg) as daemon_bus, can.Bus(interface="virtual", channel=channel) as sim_bus:
            events = generate(cfg, "cycle", "paved", settings_, duration_s=6.0)
            async with asyncio.TaskGroup() as tg:
                sim = tg.create_task(play(events, bus=sim_bus, nmea_write=gps.write,
                                          start_wall_s=settings_.start_utc_s))
                tg.create_task(faults())
                result = await run_daemon(cfg, daemon_bus, new_log_path(tmp_path, "gps"), duration_s=6.3,
                                          status_stream=status, status_every_s=0.5)
                sim.cancel()
            return result

    try:
        result = asyncio.run(run())
    finally:
        gps.close()
    log = result.log_path
    assert result.lost_frames == 0
    raw = list(iter_raw_records(log))
    frames = [r for r in raw if hasattr(r, "arbitration_id")]
    assert len(frames) >= 4 * 100 * 5.5
    nmea_t = [r.timestamp_s for r in raw if isinstance(r, NmeaLine)]
    during = [t for t in nmea_t if marks["unplug"] + 0.05 < t < marks["plug"]]
    assert not during
    back = min(t for t in nmea_t if t > marks["plug"])
    assert back - marks["plug"] < 1.0
    est = list(iter_estimates(log))
    in_gap = [e for e in est if marks["unplug"] + 1.2 < e["time_s"] < marks["plug"]]
    assert in_gap and all(e["source"] == "wheels" for e in in_gap)  # the wheels carry on while the GPS is gone
    assert any(e["source"] == "gps" and e["time_s"] > marks["plug"] + 0.5 for e in est)
    assert "DISCONNECTED" in status.getvalue()


def test_gps_gap_on_the_diagnostics_topics_and_in_the_live_view(tmp_path: Path) -> None:
    """A live run whose GPS port does not exist for its first second, then appears: /diagnostics carries the GPS
    state (gps_connected, gps_state, gps_error), /diagnostics/events the disconnection and the connection, and the
    live view the diagnostic line."""
    link = tmp_path / "gps-late"
    channel = f"slipdaq-rel-gap-{os.getpid()}"
    cfg = demo_config(str(link), channel)
    status = io.StringIO()
    holder: dict[str, ReplugGps] = {}

    async def run():  # type: ignore[no-untyped-def]
        async def feed() -> None:
            await asyncio.sleep(0.8)
            holder["gps"] = gps = ReplugGps(link)
            await _write_for(gps, gps_lines(1.0), 1.0)

        async def can_traffic(bus: can.BusABC) -> None:
            for _i in range(220):  # keeps the pipeline's diagnostics ticking
                bus.send(can.Message(arbitration_id=0x123, data=bytes(8), is_extended_id=False))
                await asyncio.sleep(0.01)

        with open_bus(cfg) as daemon_bus, can.Bus(interface="virtual", channel=channel) as sender:
            async with asyncio.TaskGroup() as tg:
                tg.create_task(feed())
                tg.create_task(can_traffic(sender))
                return await run_daemon(cfg, daemon_bus, new_log_path(tmp_path, "gap"), duration_s=2.2,
                                        status_stream=status, status_every_s=0.4)

    try:
        result = asyncio.run(run())
    finally:
        if "gps" in holder:
            holder["gps"].close()
    diags = [d for _, _, d in iter_topic(result.log_path, (TOPIC_DIAGNOSTICS,))]
    assert any(d.get("gps_connected") is False and d.get("gps_state") == "disconnected" for d in diags)
    assert diags[-1]["gps_connected"] is True
    events = [d for _, _, d in iter_topic(result.log_path, (TOPIC_EVENTS,)) if d["source"] == "gps"]
    assert [e["event"] for e in events][:2] == ["disconnected", "connected"]
    assert "GPS DISCONNECTED" in status.getvalue()


# ---- wrong baud rate ----

def _feed_seconds(src: SerialGpsSource, clock: list[float], chunks: list[bytes], seconds: float,
                  out: list[NmeaLine]) -> None:
    """Feed chunks spread evenly over `seconds` of the fake monotonic clock."""
    for c in chunks:
        clock[0] += seconds / len(chunks)
        src.feed(c, out.append)


@pytest.mark.parametrize("tx, rx", [(9600, 115200), (115200, 9600), (38400, 115200)])
def test_wrong_baud_rate_gives_a_clear_diagnostic(tx: int, rx: int) -> None:
    """NMEA sent at `tx` baud and read at `rx` (bytes as a UART reads them, framing errors as NUL): within a few
    seconds the state is `unreadable`, the live view and an event say "GPS data unreadable: wrong baud rate?", a
    counter counts it; the right baud rate clears it."""
    text = "".join(line + "\r\n" for line in gps_lines(3.0, rate_hz=1.0)).encode()
    garbage = uart_misread(text, tx, rx, idle_bits=30)
    assert garbage and not any(valid_sentence(x) for x in garbage.decode("latin-1").split("\n"))
    clock = [100.0]
    events: list[SourceEvent] = []
    src = SerialGpsSource("/dev/ttyUSB0", rx, on_event=events.append, monotonic=lambda: clock[0])
    src._port_opened()
    view = StatusSink(SourceStatus(gps_port="/dev/ttyUSB0", gps_status=src.status))
    lines: list[NmeaLine] = []
    chunks = [garbage[i: i + 64] for i in range(0, len(garbage), 64)] * (3 if len(garbage) < 600 else 1)
    _feed_seconds(src, clock, chunks, 4.0, lines)
    assert src.state == "unreadable" and src.unreadable_periods == 1
    assert src.status()["gps_state"] == "unreadable"
    assert "GPS data unreadable: wrong baud rate?" in status_line(view, _Rates())
    assert f"gps.baudrate is {rx}" in (src.diagnostic or "")
    assert [e.event for e in events] == ["connected", "unreadable"]
    # the receiver set to the right rate: readable again with the first valid sentence
    _feed_seconds(src, clock, [text], 0.5, lines)
    assert src.state == "connected" and src.diagnostic is None and events[-1].event == "readable"
    assert "wrong baud" not in status_line(view, _Rates())


def test_right_baud_rate_with_noise_is_not_called_unreadable() -> None:
    """Some noise among good sentences (a noisy line, a few bad checksums) is not a wrong baud rate."""
    clock = [0.0]
    src = SerialGpsSource("/dev/ttyUSB0", 115200, monotonic=lambda: clock[0])
    src._port_opened()
    good = "".join(line + "\r\n" for line in gps_lines(2.0, rate_hz=5.0)).encode()
    noise = bytes(range(256)) * 2
    out: list[NmeaLine] = []
    _feed_seconds(src, clock, [good[i: i + 100] + noise[:40] for i in range(0, len(good), 100)], 6.0, out)
    assert src.state == "connected" and src.unreadable_periods == 0


def test_silent_receiver_is_reported() -> None:
    clock = [0.0]
    events: list[SourceEvent] = []
    src = SerialGpsSource("/dev/ttyUSB0", 115200, on_event=events.append, monotonic=lambda: clock[0])
    src._port_opened()
    src.feed((RMC + "\r\n").encode(), lambda line: None)
    clock[0] += serial_gps.SILENT_AFTER_S + 0.1
    src._watch()
    assert src.state == "silent" and "no data from the GPS" in (src.diagnostic or "")
    src.feed((RMC + "\r\n").encode(), lambda line: None)
    assert src.state == "connected" and [e.event for e in events] == ["connected", "silent", "receiving"]


def test_a_pipeline_that_raises_does_not_stop_the_gps() -> None:
    src = SerialGpsSource("/dev/ttyUSB0", 115200)
    src._port_opened()
    got: list[str] = []

    def emit(line: NmeaLine) -> None:
        if "GGA" in line.line:
            raise ValueError("boom")
        got.append(line.line)

    src.feed(("$GPGGA,bad*00\r\n" + RMC + "\r\n").encode(), emit)
    assert got == [RMC] and src.emit_errors == 1


# ---- arbitrary bytes: nothing escapes, memory stays bounded ----

@settings(max_examples=100, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(st.lists(st.tuples(st.binary(max_size=700), st.floats(0.0, 2.0)), max_size=40))
def test_any_bytes_through_the_serial_source(chunks: list[tuple[bytes, float]]) -> None:
    """The source's whole byte path (framing, sentence check, baud-rate monitor, decoder) takes any bytes at any
    pace: no exception, the framer holds at most MAX_FRAME_BYTES, the monitor a few seconds of buckets."""
    clock = [0.0]
    src = SerialGpsSource("/dev/ttyUSB0", 115200, monotonic=lambda: clock[0])
    src._port_opened()
    decoder = NmeaDecoder()
    for data, dt in chunks:
        clock[0] += dt
        src.feed(data, lambda r: decoder.decode(r) if isinstance(r, NmeaLine) else None)
        if dt > 1.5:
            src._watch()
        assert src.framer.pending_bytes <= MAX_FRAME_BYTES
        assert len(src.quality._buckets) <= src.quality.window_s + 1
        assert src.state in ("connected", "silent", "unreadable")
    assert decoder.lines == decoder.ignored_lines + decoder.bad_sentences + decoder.sentences


def test_line_quality_window_is_bounded_and_slides() -> None:
    q = LineQuality(window_s=3.0, min_bytes=100)
    for k in range(100):
        q.feed(b"\xff" * 50, [], float(k))
    assert len(q._buckets) <= 4 and q.unreadable(99.0)
    q.feed((RMC + "\r\n").encode(), [NmeaLine(0.0, RMC)], 99.5)
    assert not q.unreadable(99.6)
    for k in range(100, 104):
        q.feed(b"\xff" * 50, [], float(k))
    assert q.unreadable(103.0)  # the valid sentence slid out of the window
