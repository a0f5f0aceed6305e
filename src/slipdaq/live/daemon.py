"""The live daemon: CAN and GPS sources -> pipeline -> MCAP log and status view, under one TaskGroup.

SIGINT/SIGTERM (or the duration) stop it; the log is always finished, whatever ended the run.
"""

from __future__ import annotations

import asyncio
import contextlib
import datetime as dt
import os
import signal
import sys
import threading
from collections.abc import Callable
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any, TextIO

import can

from slipdaq import compiled
from slipdaq.allocator import RELEASE_EVERY_S, release_free_memory
from slipdaq.config import Config, ConfigError
from slipdaq.config.calibration import Calibration, Learned, to_toml
from slipdaq.decode.xbus import XbusFramer
from slipdaq.logformat.rotation import RotationPolicy, later_segments_glob
from slipdaq.maneuver.record import Maneuver
from slipdaq.pipeline import Pipeline
from slipdaq.records import RawRecord, SourceEvent, channel_name
from slipdaq.sinks import EventFanout, Sink
from slipdaq.sinks.mcap_log import McapLogSink
from slipdaq.sinks.status import SourceStatus, StatusSink, imu_name, print_maneuvers, show
from slipdaq.sources.can_bus import CanBusSource, receive_buffer_bytes, set_receive_buffer
from slipdaq.sources.clock import SteadyClock, watch_steps
from slipdaq.sources.serial_gps import SerialGpsSource

if TYPE_CHECKING:
    from slipdaq.sinks.foxglove_live import FoxgloveLive


class _Stop(Exception):
    """Raised inside the TaskGroup to end the run cleanly."""


SUMMARY_NICE = 10
"""The nice value of the thread that computes each maneuver's summary (its fits), beside the reading loop."""


@dataclass
class RunResult:
    log_path: Path
    can_frames: int
    nmea_lines: int
    estimates: int
    lost_frames: int
    bad_sentences: int
    duration_s: float
    log_segments: list[Path] = field(default_factory=list)
    """Every file the log was written to, in order (more than one when it rotated)."""
    log_error: str | None = None
    """Set when the log could not be written to the end (disk full): what failed."""
    learned: Learned = field(default_factory=Learned)
    """What the estimator measured in this run (for the calibration file)."""
    maneuvers: list[Maneuver] = field(default_factory=list)
    """The run's latest maneuvers (/maneuver; status.MANEUVERS_KEPT at most), in order."""
    maneuver_count: int = 0
    """How many maneuvers the run decided (every one is in the log)."""
    test_sets: list[dict[str, Any]] = field(default_factory=list)
    """The last /test_set record of each set the run filled."""


def _lower_priority() -> None:
    """The maneuver summaries' thread below the readers (Linux: a thread's own nice value; elsewhere nothing)."""
    with contextlib.suppress(AttributeError, OSError):
        os.setpriority(os.PRIO_PROCESS, threading.get_native_id(), SUMMARY_NICE)


def open_bus(config: Config, **overrides: object) -> can.BusABC:
    """The configured python-can bus; ConfigError (exit 2) when the interface is unknown, OSError when it fails."""
    kwargs: dict[str, object] = {
        "interface": config.can.interface, "channel": config.can.channel, "bitrate": config.can.bitrate,
    } | overrides
    try:
        bus = can.Bus(**kwargs)  # type: ignore[arg-type]  # python-can's Bus takes each interface's own keyword arguments
    except (can.CanInterfaceNotImplementedError, ValueError) as e:
        raise ConfigError(f"{config.source_path or '<config>'}: can.interface: {e}") from None
    except (can.CanError, OSError) as e:
        raise OSError(f"cannot open CAN {kwargs['interface']} channel {kwargs['channel']}: {e}") from None
    set_receive_buffer(bus, config.can.receive_buffer_bytes)
    return bus


class _LiveLogSink(McapLogSink):
    """The MCAP sink of a live run: every diagnostics record also carries the sources' and the log's state; it never
    writes over a file that is there."""

    new_files_only = True

    def __init__(
        self, path: Path, config: Config, metadata: dict[str, str], *,
        clock: SteadyClock, on_event: Callable[[SourceEvent], None], tap: Callable[[str, float, bytes], None] | None = None,
    ) -> None:
        super().__init__(
            path, config, mode="live", metadata=metadata, flush_every_s=1.0, clock=clock, on_event=on_event,
            rotation=RotationPolicy(config.log.rotate_size_bytes, config.log.rotate_duration_s),
            can_channels=[channel_name(config.can.channel)], tap=tap,
        )
        self.extra: list[Callable[[], dict[str, object]]] = []
        """The sources' status() functions, merged into each diagnostics record."""

    def on_diagnostics(self, diagnostics: dict[str, object], log_time_s: float) -> None:
        merged = dict(diagnostics)
        for status in self.extra:
            merged |= status()
        super().on_diagnostics(merged | self.log_status(), log_time_s)


def can_metadata(config: Config, bus: can.BusABC) -> dict[str, str]:
    """The receive buffer the kernel gave the daemon's CAN socket (SocketCAN), for the log's metadata."""
    got = receive_buffer_bytes(bus)
    if got is None:
        return {}
    return {"can_receive_buffer_bytes": str(got),
            "can_receive_buffer_requested_bytes": str(config.can.receive_buffer_bytes)}


async def release_memory_every(period_s: float) -> None:
    """The allocator's free pages back to the system every period_s, until cancelled (slipdaq/allocator.py)."""
    while True:
        await asyncio.sleep(period_s)
        release_free_memory()


class _ReleaseAfterSummary(Sink):
    """A maneuver's summary frees megabytes of arrays on its thread as it ends: those pages go back to the system as
    the maneuver arrives (on the loop's thread), not at the next period."""

    def on_maneuver(self, maneuver: Maneuver, log_time_s: float) -> None:
        release_free_memory()


def new_log_path(log_dir: Path, prefix: str = "slipdaq") -> Path:
    """PREFIX-STAMP.mcap in log_dir, a name that neither a file nor a segment of one (NAME_002.mcap, ...) has."""
    stamp = dt.datetime.now(dt.UTC).strftime("%Y%m%d-%H%M%S")
    path = log_dir / f"{prefix}-{stamp}.mcap"
    n = 1
    while path.exists() or any(log_dir.glob(later_segments_glob(path))):
        n += 1
        path = log_dir / f"{prefix}-{stamp}-{n}.mcap"
    return path


def start_live(config: Config, stream: TextIO) -> FoxgloveLive | None:
    """The Foxglove live server of `live.foxglove`, if set (OSError when it cannot listen); its address printed."""
    if config.live.foxglove is None:
        return None
    from slipdaq.sinks.foxglove_live import FoxgloveLive

    try:
        live = FoxgloveLive(config.live.foxglove)
    except ValueError as e:  # an address that skipped the config's check (Config.with_overrides)
        raise ConfigError(f"{config.source_path or '<config>'}: live.foxglove: {e}") from None
    print(f"slipdaq: Foxglove live view on {live.url} (Foxglove: Open connection, Foxglove WebSocket)", file=stream,
          flush=True)
    return live


async def run_daemon(
    config: Config,
    bus: can.BusABC,
    log_path: Path,
    *,
    duration_s: float | None = None,
    status_stream: TextIO | None = None,
    status_every_s: float = 5.0,
    metadata: dict[str, str] | None = None,
    stop: asyncio.Event | None = None,
    calibration: Calibration | None = None,
) -> RunResult:
    """Acquire until the duration ends, `stop` is set, or SIGINT/SIGTERM; the MCAP log is finished in every case.
    calibration: the stored calibration to start from (kept in the log's metadata, so that replay starts from it)."""
    loop = asyncio.get_running_loop()
    stop = stop or asyncio.Event()
    can_name = f"{config.can.interface}:{config.can.channel}"

    def report(text: str) -> None:  # events between status lines (sys.stdout looked up now: a live view wraps it)
        print(f"slipdaq: {can_name}: {text}", file=status_stream or sys.stdout, flush=True)

    compiled.prepare()  # the kernels now (numba: 0.5 s; 3-6 s the first time on a machine), before the log exists
    clock = SteadyClock()  # one clock for both sources and the log: windows never see a host clock step
    can_meta = can_metadata(config, bus)
    if can_meta and int(can_meta["can_receive_buffer_bytes"]) < config.can.receive_buffer_bytes:
        print(f"slipdaq: warning: the CAN socket's receive buffer is {can_meta['can_receive_buffer_bytes']} bytes, "
              f"can.receive_buffer_bytes asks {config.can.receive_buffer_bytes} (SO_RCVBUFFORCE needs "
              f"CAP_NET_ADMIN, else net.core.rmem_max caps it): bursts may be dropped", file=sys.stderr, flush=True)
    # the view's callables are looked up when it draws, after the sources below exist
    serial_gps = config.gps.source == "serial"  # else the reference speed comes on CAN: no serial port to read
    status = StatusSink(SourceStatus(
        can=can_name,
        gps_port=config.gps.port if serial_gps else f"CAN {config.gps.message}.{config.gps.signal}",
        gps_connected=lambda: gps_source.connected if gps_source is not None else True,
        log_path=lambda: str(sink.path),
        log_size_bytes=lambda: sink.size_bytes,
        can_reader_errors=lambda: can_source.reader_errors,
        gps_status=(lambda: gps_source.status() if gps_source is not None else {}) if serial_gps else None,
        log_status=lambda: sink.log_status(),
        imu=imu_name(config.imu),
        imu_connected=lambda: imu_source.connected if imu_source is not None else True,
    ))
    meta = can_meta | (metadata or {}) | {"calibration_toml": to_toml(calibration) if calibration is not None else ""}
    live = start_live(config, status_stream or sys.stdout)
    try:
        sink = _LiveLogSink(log_path, config, meta, clock=clock, on_event=status.on_source_event,
                            tap=live.publish if live is not None else None)
    except BaseException:  # no log (a file is there, the disk): no server either
        if live is not None:
            live.close()
        raise
    events = EventFanout([sink, status])  # source events -> /diagnostics/events and the view
    can_source = CanBusSource(bus, report=report, stamp=clock, on_event=events,
                              read_interval_s=config.can.read_interval_s,
                              keep_reading=lambda: pipeline.waiting_for_wheels())
    # the port may carry UBX frames among NMEA lines whatever gps.velocity says: they are framed, logged and decoded
    import pyubx2  # noqa: F401  (now, not on the loop with the first UBX frame: UbxDecoder imports it lazily)
    gps_source = SerialGpsSource(config.gps.port, config.gps.baudrate, clock=clock, on_event=events) \
        if serial_gps else None
    imu_source = SerialGpsSource(config.imu.port, config.imu.baudrate, clock=clock, on_event=events,
                                 framer=XbusFramer, name="imu") \
        if config.imu.source == "serial" and config.imu.port is not None else None
    sink.extra += [can_source.status] + ([gps_source.status] if gps_source is not None else []) + \
        ([live.status] if live is not None else [])
    summaries = ThreadPoolExecutor(max_workers=1, thread_name_prefix="slipdaq-maneuvers", initializer=_lower_priority)
    pipeline = Pipeline(config, [sink, status, _ReleaseAfterSummary()], calibration=calibration,
                        maneuver_executor=summaries)
    installed: list[signal.Signals] = []
    for sig in (signal.SIGINT, signal.SIGTERM):
        with contextlib.suppress(NotImplementedError, RuntimeError, ValueError):
            loop.add_signal_handler(sig, stop.set)
            installed.append(sig)
    started = loop.time()

    def process_gps(record: RawRecord) -> None:
        pipeline.process(record)
        if pipeline.waiting_for_wheels():  # the fix that closes a window: read the wheels' frames now
            can_source.read_now()

    async def stopper() -> None:
        if duration_s is not None:
            with contextlib.suppress(TimeoutError):
                await asyncio.wait_for(stop.wait(), duration_s)
        else:
            await stop.wait()
        raise _Stop

    try:
        async with asyncio.TaskGroup() as tg:
            tg.create_task(can_source.run(pipeline.process, pipeline.process_can_batch), name="can")
            if gps_source is not None:
                tg.create_task(gps_source.run(process_gps), name="gps")
            if imu_source is not None:  # an Xsens MTi: its records as the GPS's, beside them on the loop
                tg.create_task(imu_source.run(pipeline.process), name="imu")
            tg.create_task(show(status, status_stream or sys.stdout, status_every_s), name="status")
            tg.create_task(stopper(), name="stop")
            tg.create_task(watch_steps(clock, events), name="clock")
            tg.create_task(release_memory_every(RELEASE_EVERY_S), name="memory")
    except* _Stop:
        pass
    finally:
        for sig in installed:
            loop.remove_signal_handler(sig)
        pipeline.finish()
        summaries.shutdown(wait=True)
        sink.close()
        if live is not None:  # after the log's last message; a client that stopped reading is not waited for
            live.close()
        stream = status_stream or sys.stdout
        if not stream.isatty():  # the maneuvers decided since the view's last look (the last one at the end)
            print_maneuvers(status, stream)
    d = pipeline.diagnostics()
    return RunResult(
        log_path, d.can_frames, d.nmea_lines, d.estimates, sum(d.lost_frames.values()), d.bad_sentences,
        loop.time() - started, log_segments=list(sink.segments), log_error=sink.error,
        learned=pipeline.estimator.learned(), maneuvers=list(status.maneuvers),
        test_sets=list(status.test_sets.values()),
        maneuver_count=pipeline.maneuver_count,
    )
