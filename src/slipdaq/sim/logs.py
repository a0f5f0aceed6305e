"""Simulated drives as the files `slipdaq import` reads: a CAN log (any python-can format, by suffix) and an NMEA
log of `(EPOCH_SECONDS) $SENTENCE` lines; the truth is returned for comparison."""

from __future__ import annotations

from collections.abc import Iterable
from pathlib import Path

import can

from slipdaq.records import CanFrame, NmeaLine
from slipdaq.sim.emit import SimEvent
from slipdaq.sim.vehicle import TruthSample


def write_drive_logs(
    events: Iterable[SimEvent], can_path: Path, nmea_path: Path, nmea_header: str = "", channel: str = "can0",
) -> list[TruthSample]:
    """Write the events' CAN frames and NMEA lines; returns the truth samples in order."""
    truth: list[TruthSample] = []
    with can.Logger(str(can_path)) as writer, open(nmea_path, "w") as nmea:
        nmea.write(nmea_header)
        for ev in events:
            r = ev.record
            if ev.truth is not None:
                truth.append(ev.truth)
            elif isinstance(r, CanFrame):
                writer(can.Message(timestamp=r.timestamp_s, arbitration_id=r.arbitration_id, data=r.data,
                                   is_extended_id=r.is_extended_id, channel=channel))
            elif isinstance(r, NmeaLine):
                nmea.write(f"({r.timestamp_s:.6f}) {r.line}\n")
    return truth
