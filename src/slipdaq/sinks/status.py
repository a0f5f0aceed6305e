"""The live status view: per wheel speed, slip and Re; GPS; frame rates, losses, bad sentences; the log.

On a terminal it is a rich table redrawn a few times a second; otherwise one plain line every few seconds.
"""

from __future__ import annotations

import asyncio
import sys
import time
from collections import deque
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any, TextIO

import numpy as np
from rich.console import Console, Group
from rich.live import Live
from rich.table import Table
from rich.text import Text

from slipdaq import WHEELS
from slipdaq.config import ImuConfig
from slipdaq.decode.can_errors import error_classes
from slipdaq.maneuver.record import Maneuver
from slipdaq.records import (
    FLAG_ERROR,
    FLAG_EXTENDED,
    CanFrame,
    CanFrameBatch,
    Estimate,
    GpsFix,
    NmeaLine,
    RawRecord,
    SensorSample,
    SourceEvent,
    UbxFrame,
    WheelSample,
    WheelSampleBatch,
)
from slipdaq.sinks import Sink
from slipdaq.sinks.maneuver_text import maneuver_line, maneuver_table, test_set_line


@dataclass
class SourceStatus:
    """What the live runner knows beyond the records: ports, connections, the log file."""

    can: str = ""
    gps_port: str = ""
    gps_connected: Callable[[], bool] = lambda: True
    log_path: str | Callable[[], str] = ""
    """The log file being written (a callable: it changes when the log rotates)."""
    log_size_bytes: Callable[[], int] = lambda: 0
    can_reader_errors: Callable[[], int] = lambda: 0
    gps_status: Callable[[], dict[str, object]] | None = None
    """SerialGpsSource.status: state, gaps, the diagnostic line (unplugged, wrong baud rate?, silent)."""
    log_status: Callable[[], dict[str, object]] | None = None
    """McapLogSink.log_status: segments, write failures (disk full), dropped messages."""
    imu: str = ""
    """The IMU: its serial port, or its CAN signal; empty without one."""
    imu_connected: Callable[[], bool] = lambda: True

    def log_path_now(self) -> str:
        return self.log_path() if callable(self.log_path) else self.log_path


EVENTS_SHOWN = 3
MANEUVERS_KEPT = 100
"""The live view keeps the latest this many maneuvers (its table shows 8): a day's run decides thousands, and every
one is in the log (/maneuver)."""


def imu_name(imu: ImuConfig) -> str:
    """The IMU as the view names it: its serial port, or its CAN message and signal; empty without one."""
    if imu.source == "serial":
        return f"{imu.port} (MTi)"
    return f"CAN {imu.message}.{imu.signal}" if imu.message is not None else ""


@dataclass
class StatusSink(Sink):
    """A Sink that keeps the latest of everything for the view (cheap per record)."""

    sources: SourceStatus = field(default_factory=SourceStatus)
    estimate: Estimate | None = None
    fix: GpsFix | None = None
    can_frames: int = 0
    nmea_lines: int = 0
    ubx_frames: int = 0
    imu_samples: int = 0
    """The IMU's forward accelerations taken (an MTi's MTData2 packets, a CAN IMU's frames)."""
    imu_accel_mps2: float | None = None
    """The latest of them."""
    wheel_frames: dict[str, int] = field(default_factory=lambda: {w: 0 for w in WHEELS})
    diagnostics: dict[str, object] = field(default_factory=dict)
    can_errors: dict[str, int] = field(default_factory=dict)
    """Error frames by class (bus_off, restarted, controller, rx_overflow, ...)."""
    events: list[SourceEvent] = field(default_factory=list)
    """The latest source and log events (GPS unplugged and back, disk full, ...), newest last."""
    maneuvers: deque[Maneuver] = field(default_factory=lambda: deque(maxlen=MANEUVERS_KEPT))
    """The latest MANEUVERS_KEPT maneuvers (/maneuver), oldest first."""
    maneuvers_seen: int = 0
    """How many maneuvers the run has decided so far."""
    maneuvers_printed: int = 0
    """How many of them the status stream has printed (one line each)."""
    test_sets: dict[str, dict[str, Any]] = field(default_factory=dict)
    """The latest /test_set record of each procedure's set."""
    test_sets_unprinted: list[str] = field(default_factory=list)
    """The sets updated since the status stream's last line of them."""

    def on_raw(self, record: RawRecord) -> None:
        if isinstance(record, CanFrame):
            self.can_frames += 1
            if record.is_error_frame:
                for c in error_classes(record):
                    self.can_errors[c] = self.can_errors.get(c, 0) + 1
        elif isinstance(record, NmeaLine):
            self.nmea_lines += 1
        elif isinstance(record, UbxFrame):
            self.ubx_frames += 1

    def on_can_batch(self, batch: CanFrameBatch) -> None:
        """on_raw for each frame of a batch (Pipeline.process_can_batch)."""
        self.can_frames += len(batch)
        for i in np.flatnonzero(batch.flags & FLAG_ERROR).tolist():
            frame = CanFrame(float(batch.timestamp_s[i]), int(batch.arbitration_id[i]), batch.payload(i),
                             bool(batch.flags[i] & FLAG_EXTENDED), True)
            for c in error_classes(frame):
                self.can_errors[c] = self.can_errors.get(c, 0) + 1

    def on_wheel_batch(self, samples: WheelSampleBatch) -> None:
        for w, n in enumerate(np.bincount(samples.wheel, minlength=len(WHEELS)).tolist()):
            if n:
                self.wheel_frames[WHEELS[w]] += n

    def on_source_event(self, event: SourceEvent) -> None:
        self.events.append(event)
        del self.events[:-EVENTS_SHOWN]

    def on_wheel(self, sample: WheelSample) -> None:
        self.wheel_frames[sample.wheel] += 1

    def on_fix(self, fix: GpsFix) -> None:
        self.fix = fix

    def on_sensor(self, sample: SensorSample) -> None:
        if sample.kind == "imu_accel":
            self.imu_samples += 1
            self.imu_accel_mps2 = sample.value

    def on_estimate(self, estimate: Estimate, log_time_s: float) -> None:
        self.estimate = estimate

    def on_maneuver(self, maneuver: Maneuver, log_time_s: float) -> None:
        self.maneuvers.append(maneuver)
        self.maneuvers_seen += 1

    def on_test_set(self, record: dict[str, Any], log_time_s: float) -> None:
        self.test_sets[record["procedure"]] = record
        if record["procedure"] not in self.test_sets_unprinted:
            self.test_sets_unprinted.append(record["procedure"])

    def on_diagnostics(self, diagnostics: dict[str, object], log_time_s: float) -> None:
        self.diagnostics = diagnostics


def _fmt(v: float | None, spec: str, scale: float = 1.0) -> str:
    return "—" if v is None else format(v * scale, spec)


def _size(n_bytes: int) -> str:
    n = float(n_bytes)
    for unit in ("B", "kB", "MB", "GB"):
        if n < 1000 or unit == "GB":
            return f"{n:.0f} {unit}" if unit == "B" else f"{n:.1f} {unit}"
        n /= 1000
    return ""


class _Rates:
    """Frames per second from counters sampled at each redraw."""

    def __init__(self) -> None:
        self._last: tuple[float, int, int, int] | None = None
        self.can_fps = 0.0
        self.nmea_lps = 0.0
        self.imu_sps = 0.0

    def update(self, s: StatusSink) -> None:
        now = time.monotonic()
        if self._last is not None and now - self._last[0] >= 0.5:
            dt = now - self._last[0]
            self.can_fps = (s.can_frames - self._last[1]) / dt
            self.nmea_lps = (s.nmea_lines - self._last[2]) / dt
            self.imu_sps = (s.imu_samples - self._last[3]) / dt
            self._last = (now, s.can_frames, s.nmea_lines, s.imu_samples)
        elif self._last is None:
            self._last = (now, s.can_frames, s.nmea_lines, s.imu_samples)


def render(s: StatusSink, rates: _Rates) -> Group:
    d = s.diagnostics
    lost = d.get("lost_frames", {}) if d else {}
    wheels = Table(title="slipdaq — live", expand=False)
    for col in ("wheel", "speed km/h", "slip %", "Re mm", "r0 mm", "Cx kN", "frames", "lost"):
        wheels.add_column(col, justify="right")
    e = s.estimate
    for w in WHEELS:
        we = e.wheels[w] if e else None
        wheels.add_row(
            w,
            _fmt(we.speed_mps if we else None, ".1f", 3.6),
            _fmt(we.slip if we else None, "+.2f", 100),
            _fmt(we.re_m if we else None, ".1f", 1000),
            _fmt(we.r0_m if we else None, ".1f", 1000),
            _fmt(we.cx_n if we else None, ".1f", 1e-3),
            str(s.wheel_frames[w]),
            str(lost.get(w, 0)) if isinstance(lost, dict) else "0",
        )
    f = s.fix
    gps = "no fix yet" if f is None else (
        f"{f.speed_mps * 3.6:6.1f} km/h  {'valid' if f.valid else 'INVALID'}  "
        f"quality {f.fix_quality if f.fix_quality is not None else '—'}  sats {f.satellites if f.satellites is not None else '—'}"
    )
    connected = s.sources.gps_connected()
    gps_problem, log_problem = gps_diagnostic(s), log_diagnostic(s)
    lines = [
        Text(f"GPS   {s.sources.gps_port}: {gps}" + ("" if connected else "  [DISCONNECTED]") + gps_gaps(s),
             style="" if connected else "bold red"),
    ]
    if gps_problem:
        lines.append(Text(f"      {gps_problem}", style="bold red"))
    lines += [
        Text(f"accel {_fmt(e.accel_mps2 if e else None, '+.2f')} m/s²   Fx {_fmt(e.force_n if e else None, '+.0f')} N"
             f"   {estimate_quality(e)}", style="" if e is None or e.quality == "ok" else "yellow"),
        Text(f"CAN   {s.sources.can}: {rates.can_fps:7.0f} frames/s, {s.can_frames} frames, "
             f"unknown {d.get('unknown_frames', 0)}, errors {d.get('error_frames', 0)}{can_error_text(s)}, "
             f"reader errors {s.sources.can_reader_errors()}",
             style="bold red" if s.can_errors.get("bus_off") else ""),
        Text(f"NMEA  {rates.nmea_lps:5.1f} lines/s, {s.nmea_lines} lines, bad sentences {d.get('bad_sentences', 0)}"
             + (f", UBX {s.ubx_frames} frames" if s.ubx_frames else "")),
        *([imu_text(s, rates)] if s.sources.imu else []),
        Text(f"log   {s.sources.log_path_now()} ({_size(s.sources.log_size_bytes())})"
             + (f"  {log_problem}" if log_problem else ""), style="bold red" if log_problem else ""),
    ]
    lines += [Text(f"event {_event_text(ev)}", style="dim") for ev in s.events]
    return Group(wheels, *lines, *([maneuver_table(s.maneuvers)] if s.maneuvers else []),
                 *(Text(f"set   {test_set_line(r)}", style="" if r["ok"] or not r["complete"] else "yellow")
                   for r in s.test_sets.values()))


def imu_text(s: StatusSink, rates: _Rates) -> Text:
    connected = s.sources.imu_connected()
    return Text(f"IMU   {s.sources.imu}: {rates.imu_sps:5.1f} samples/s, {s.imu_samples} samples, "
                f"a {_fmt(s.imu_accel_mps2, '+.2f')} m/s²" + ("" if connected else "  [DISCONNECTED]"),
                style="" if connected else "bold red")


def estimate_quality(e: Estimate | None) -> str:
    """The estimate's quality and what it rests on: the GPS latency and its source."""
    if e is None:
        return "no estimate yet"
    latency = "unknown" if e.latency_source == "none" else f"{e.gps_latency_s * 1000:.0f} ms ({e.latency_source})"
    return f"quality {e.quality}, GPS latency {latency}"


def gps_diagnostic(s: StatusSink) -> str | None:
    """The GPS problem in one line (unplugged, wrong baud rate?, silent), or None."""
    st = s.sources.gps_status() if s.sources.gps_status else {}
    text = st.get("gps_error")
    return str(text) if text else None


def gps_gaps(s: StatusSink) -> str:
    st = s.sources.gps_status() if s.sources.gps_status else {}
    gap, gaps, last = st.get("gps_gap_s"), st.get("gps_gaps", 0), st.get("gps_last_gap_s")
    if gap is not None:
        return f"  gap {gap:.1f} s (gap {gaps})"
    if gaps:
        return f"  ({gaps} gap{'s' if gaps != 1 else ''}, last {last:.1f} s)" if last is not None else f"  ({gaps} gaps)"
    return ""


def log_diagnostic(s: StatusSink) -> str | None:
    st = s.sources.log_status() if s.sources.log_status else {}
    err = st.get("log_error")
    if err:
        return f"{err}; estimating goes on; {st.get('log_dropped_messages', 0)} messages not logged"
    if st.get("log_dropped_messages"):
        return f"{st.get('log_dropped_messages')} messages not logged after {st.get('log_write_failures')} write failure(s)"
    return None


def can_error_text(s: StatusSink) -> str:
    shown = [f"{k.replace('_', '-')} {v}" for k, v in s.can_errors.items()
             if k in ("bus_off", "restarted", "rx_overflow", "tx_passive", "rx_passive")]
    return f" ({', '.join(shown)})" if shown else ""


def reader_errors(s: StatusSink) -> str:
    n = s.sources.can_reader_errors()
    return f", reader errors {n}" if n else ""


def _event_text(ev: SourceEvent) -> str:
    t = time.strftime("%H:%M:%S", time.gmtime(ev.time_s))
    return f"{t} {ev.source} {ev.event}: {ev.detail}"


def status_line(s: StatusSink, rates: _Rates) -> str:
    e = s.estimate
    d = s.diagnostics
    slips = " ".join(
        f"{w}={_fmt(e.wheels[w].slip if e else None, '+.2f', 100)}%" for w in WHEELS
    )
    lost_frames = d.get("lost_frames")
    lost = sum(lost_frames.values()) if isinstance(lost_frames, dict) else 0
    gps = "—" if s.fix is None else f"{s.fix.speed_mps:.2f}"
    gps_problem, log_problem = gps_diagnostic(s), log_diagnostic(s)
    imu = f"imu {s.imu_samples} samples{'' if s.sources.imu_connected() else ' DISCONNECTED'} | " \
        if s.sources.imu else ""
    return (
        f"slipdaq: gps {gps} m/s{'' if s.sources.gps_connected() else ' DISCONNECTED'}{gps_gaps(s)}"
        f"{f' [{gps_problem}]' if gps_problem else ''} | slip {slips} ({estimate_quality(e)}) | "
        f"can {rates.can_fps:.0f} fr/s ({s.can_frames} frames, lost {lost}{can_error_text(s)}{reader_errors(s)}) | "
        f"nmea {s.nmea_lines} lines, bad {d.get('bad_sentences', 0)}"
        f"{f', ubx {s.ubx_frames} frames' if s.ubx_frames else ''} | {imu}"
        f"log {s.sources.log_path_now()} {_size(s.sources.log_size_bytes())}"
        f"{f' [{log_problem}]' if log_problem else ''}"
    )


async def show(s: StatusSink, stream: TextIO | None = None, line_every_s: float = 5.0) -> None:
    """Run the view until cancelled: a live table on a terminal, else a status line every line_every_s."""
    stream = stream or sys.stdout
    rates = _Rates()
    rates.update(s)
    if stream.isatty():
        console = Console(file=stream)
        with Live(render(s, rates), console=console, refresh_per_second=4, transient=False) as live:
            while True:
                await asyncio.sleep(0.25)
                rates.update(s)
                live.update(render(s, rates))
    else:
        next_line = time.monotonic() + line_every_s
        while True:
            await asyncio.sleep(0.25)
            print_maneuvers(s, stream)
            if time.monotonic() >= next_line:
                next_line += line_every_s
                rates.update(s)
                print(status_line(s, rates), file=stream, flush=True)


def print_maneuvers(s: StatusSink, stream: TextIO) -> None:
    """One line for each maneuver not printed yet (of those kept), then one for each test set updated since."""
    new = min(s.maneuvers_seen - s.maneuvers_printed, len(s.maneuvers))
    for m in list(s.maneuvers)[len(s.maneuvers) - new:]:
        print(maneuver_line(m), file=stream, flush=True)
    s.maneuvers_printed = s.maneuvers_seen
    for name in s.test_sets_unprinted:
        print(f"test set {test_set_line(s.test_sets[name])}", file=stream, flush=True)
    s.test_sets_unprinted.clear()
