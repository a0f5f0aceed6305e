"""The live daemon: CAN and GPS sources -> pipeline -> MCAP log and status view, under one TaskGroup.

SIGINT/SIGTERM (or the duration) stop it; the log is always finished, whatever ended the run.
"""

from __future__ import annotations

import asyncio
import contextlib
import datetime as dt
import signal
import sys
from dataclasses import dataclass
from pathlib import Path
from typing import TextIO

import can

from slipdaq.config import Config, ConfigError
from slipdaq.decode.nmea import NmeaFramer
from slipdaq.decode.ubx import GpsFramer
from slipdaq.pipeline import Pipeline
from slipdaq.sinks.mcap_log import McapLogSink
from slipdaq.sinks.status import SourceStatus, StatusSink, show
from slipdaq.sources.can_bus import CanBusSource, set_receive_buffer
from slipdaq.sources.serial_gps import SerialGpsSource


class _Stop(Exception):
    """Raised inside the TaskGroup to end the run cleanly."""


@dataclass
class RunResult:
    log_path: Path
    can_frames: int
    nmea_lines: int
    estimates: int
    lost_frames: int
    bad_sentences: int
    duration_s: float


def open_bus(config: Config, **overrides: object) -> can.BusABC:
    """The configured python-can bus; ConfigError (exit 2) when the interface is unknown, OSError when it fails."""
    kwargs: dict[str, object] = {
        "interface": config.can.interface, "channel": config.can.channel, "bitrate": config.can.bitrate,
    } | overrides
    try:
        bus = can.Bus(**kwargs)  # type: ignore[arg-type]
    except (can.CanInterfaceNotImplementedError, ValueError) as e:
        raise ConfigError(f"{config.source_path or '<config>'}: can.interface: {e}") from None
    except (can.CanError, OSError) as e:
        raise OSError(f"cannot open CAN {kwargs['interface']} channel {kwargs['channel']}: {e}") from None
    set_receive_buffer(bus, config.can.receive_buffer_bytes)
    return bus


def new_log_path(log_dir: Path, prefix: str = "slipdaq") -> Path:
    stamp = dt.datetime.now(dt.timezone.utc).strftime("%Y%m%d-%H%M%S")
    path = log_dir / f"{prefix}-{stamp}.mcap"
    n = 1
    while path.exists():
        n += 1
        path = log_dir / f"{prefix}-{stamp}-{n}.mcap"
    return path


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
) -> RunResult:
    """Acquire until the duration ends, `stop` is set, or SIGINT/SIGTERM; the MCAP log is finished in every case."""
    loop = asyncio.get_running_loop()
    stop = stop or asyncio.Event()
    sink = McapLogSink(log_path, config, mode="live", metadata=metadata, flush_every_s=1.0)
    can_source = CanBusSource(bus)
    # u-blox velocity: the port carries UBX frames among NMEA lines
    framer = GpsFramer if config.gps.velocity == "ubx" else NmeaFramer
    gps_source = SerialGpsSource(config.gps.port, config.gps.baudrate, framer=framer)
    status = StatusSink(SourceStatus(
        can=f"{config.can.interface}:{config.can.channel}",
        gps_port=config.gps.port,
        gps_connected=lambda: gps_source.connected,
        log_path=str(log_path),
        log_size_bytes=lambda: sink.size_bytes,
        can_reader_errors=lambda: can_source.reader_errors,
    ))
    pipeline = Pipeline(config, [sink, status])
    installed: list[int] = []
    for sig in (signal.SIGINT, signal.SIGTERM):
        with contextlib.suppress(NotImplementedError, RuntimeError, ValueError):
            loop.add_signal_handler(sig, stop.set)
            installed.append(sig)
    started = loop.time()

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
            tg.create_task(gps_source.run(pipeline.process), name="gps")
            tg.create_task(show(status, status_stream or sys.stdout, status_every_s), name="status")
            tg.create_task(stopper(), name="stop")
    except* _Stop:
        pass
    finally:
        for sig in installed:
            loop.remove_signal_handler(sig)
        pipeline.finish()
        sink.close()
    d = pipeline.diagnostics()
    return RunResult(
        log_path, d.can_frames, d.nmea_lines, d.estimates, sum(d.lost_frames.values()), d.bad_sentences,
        loop.time() - started,
    )
