"""gpsd's regression captures: their bytes played gpsfake-style through a real pseudo-terminal into SerialGpsSource
(as in a live run), and gpsd's expected output (.chk)."""

from __future__ import annotations

import asyncio
import calendar
import datetime as dt
import json
import os
import random
import time
import tty
from dataclasses import dataclass, field
from pathlib import Path

from slipdaq.records import NmeaLine, UbxFrame
from slipdaq.sources.serial_gps import SerialGpsSource

STALL_S = 30.0
"""Liveness bound for one capture through the pty (they take well under a second): a stall, not a performance test."""


@dataclass
class Played:
    records: list[NmeaLine | UbxFrame] = field(default_factory=list)
    seconds: float = 0.0
    reconnects: int = 0
    last_error: str | None = None


async def play_through_pty(data: bytes, n_records: int, seed: int, max_chunk: int = 200) -> Played:
    """Write data to a pty master in seeded chunks of 1 to max_chunk bytes while SerialGpsSource reads the slave;
    returns once n_records records came (and a moment more, so that an extra one would be seen)."""
    played = Played()
    master, slave = os.openpty()
    task: asyncio.Task[None] | None = None
    t0 = time.monotonic()
    deadline = t0 + STALL_S
    try:
        tty.setraw(slave)
        os.set_blocking(master, False)
        source = SerialGpsSource(os.ttyname(slave), 115200)
        task = asyncio.create_task(source.run(played.records.append))
        while not source.connected:  # pyserial flushes input at open: write only once the reader has the port
            assert not task.done(), "reader task ended before opening the pty"
            assert time.monotonic() < deadline, "stall: the reader never opened the pty"
            await asyncio.sleep(0.001)
        rng = random.Random(seed)
        view = memoryview(data)
        pos = 0
        while pos < len(data):
            try:
                pos += os.write(master, view[pos : pos + rng.randint(1, max_chunk)])
            except BlockingIOError:  # pty buffer full: the reader drains it on the next loop turn
                pass
            await asyncio.sleep(0.001 if rng.random() < 0.05 else 0)
            assert not task.done(), "reader task ended while the capture was played"
            assert time.monotonic() < deadline, f"stall: {pos} of {len(data)} bytes written in {STALL_S} s"
        while len(played.records) < n_records:
            assert not task.done(), "reader task ended while the capture was played"
            assert time.monotonic() < deadline, f"stall: {len(played.records)} of {n_records} records in {STALL_S} s"
            await asyncio.sleep(0.002)
        played.seconds = time.monotonic() - t0
        await asyncio.sleep(0.02)  # nothing more may come
        played.reconnects, played.last_error = source.reconnects, source.last_error
    finally:
        if task is not None:
            task.cancel()
            await asyncio.gather(task, return_exceptions=True)
        os.close(master)
        os.close(slave)
    return played


# ---- gpsd's expected output ----


def ms(t: float) -> int:
    return round(t * 1000)


def tpv_speeds(chk: Path) -> dict[int, float]:
    """TPV time (ms since the epoch) -> speed of the last TPV with that time and a speed.

    gpsd prints several TPVs per epoch; when a GGA comes before the RMC of the same time (SiRF, Quectel EG25-G), the
    first carries a speed gpsd computed from position changes, and the RMC's speed replaces it in the last one.
    """
    out: dict[int, float] = {}
    with open(chk, encoding="latin-1") as f:
        for text in f:
            if not text.startswith('{"class":"TPV"'):
                continue
            tpv = json.loads(text)
            if "time" in tpv and "speed" in tpv:
                t = dt.datetime.fromisoformat(tpv["time"].replace("Z", "+00:00"))
                out[calendar.timegm(t.utctimetuple()) * 1000 + t.microsecond // 1000] = float(tpv["speed"])
    return out
