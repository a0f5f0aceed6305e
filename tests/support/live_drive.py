"""A simulated drive played in real time into a live daemon: wheel frames on python-can's virtual bus, the GPS's
bytes on a real pseudo-terminal (the live tests of the GPS port share it)."""

from __future__ import annotations

import asyncio
import os
import time
from dataclasses import replace
from pathlib import Path

import can

from slipdaq.config import Config
from slipdaq.live.daemon import run_daemon
from slipdaq.live.simulate import PtyGps
from slipdaq.sim.emit import SimSettings, generate
from slipdaq.sim.realtime import play


def drive_live(cfg: Config, gps: PtyGps, channel: str, log: Path, scenario: str, settings: SimSettings,
               drive_s: float, run_s: float) -> SimSettings:
    """`run_daemon` for run_s into log, and the scenario's first drive_s played into it once the log exists (its
    UTC the wall clock then); the pseudo-terminal closed at the end. The settings the drive was played with."""
    played = [settings]

    async def main() -> None:
        with can.Bus(interface="virtual", channel=channel) as daemon_bus, \
                can.Bus(interface="virtual", channel=channel, preserve_timestamps=True) as sim_bus:
            async def drive() -> None:
                while not log.exists():
                    await asyncio.sleep(0.02)
                await asyncio.sleep(0.3)
                run = replace(settings, start_utc_s=time.time() + 0.1)
                played.append(run)
                await play(generate(cfg, scenario, "paved", run, drive_s), bus=sim_bus, nmea_write=gps.write,
                           start_wall_s=run.start_utc_s, stamp_frames=True)

            async with asyncio.TaskGroup() as tg:
                sim = tg.create_task(drive())
                with open(os.devnull, "w") as status:
                    await run_daemon(cfg, daemon_bus, log, duration_s=run_s, status_stream=status)
                sim.cancel()

    try:
        asyncio.run(main())
    finally:
        gps.close()
    return played[-1]
