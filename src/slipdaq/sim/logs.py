"""Simulated drives as the files `slipdaq import` reads: a CAN log (any python-can format, by suffix) and an NMEA
log of `(EPOCH_SECONDS) $SENTENCE` lines, or a receiver's raw capture (`--gps-raw`: the NMEA lines and UBX frames
as the port sent them, no stamps); the truth is returned for comparison."""

from __future__ import annotations

from collections.abc import Iterable
from pathlib import Path

import can

from slipdaq.records import CanFrame, NmeaLine, UbxFrame
from slipdaq.sim.emit import SimEvent
from slipdaq.sim.vehicle import TruthSample


def write_drive_logs(
    events: Iterable[SimEvent], can_path: Path, nmea_path: Path, nmea_header: str = "", channel: str = "can0",
    gps_raw: bool = False,
) -> list[TruthSample]:
    """Write the events' CAN frames and NMEA lines; returns the truth samples in order. gps_raw: nmea_path gets the
    raw capture instead (NMEA lines with CR LF and UBX frames, in arrival order, no stamps)."""
    truth: list[TruthSample] = []
    with can.Logger(str(can_path)) as writer, open(nmea_path, "wb") as gps:
        gps.write(nmea_header.encode())
        for ev in events:
            r = ev.record
            if ev.truth is not None:
                truth.append(ev.truth)
            elif isinstance(r, CanFrame):
                writer(can.Message(timestamp=r.timestamp_s, arbitration_id=r.arbitration_id, data=r.data,
                                   is_extended_id=r.is_extended_id, channel=channel))
            elif isinstance(r, NmeaLine):
                gps.write(f"{r.line}\r\n".encode() if gps_raw else f"({r.timestamp_s:.6f}) {r.line}\n".encode())
            elif isinstance(r, UbxFrame) and gps_raw:
                gps.write(r.data)
    return truth
